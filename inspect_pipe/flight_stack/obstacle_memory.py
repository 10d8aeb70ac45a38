"""Short-term memory of the surfaces the horizontal sonars have heard, so that a clearance does not
depend on which way the vehicle happens to point right now.

Each sonar reports one number: the nearest echo in its beam. Yawed by 40 deg at a wall, the front
sonar hears the wall at d / cos(25 deg), and a stop line held on that reading ends 0.1-0.2 m
inside the perpendicular 1 m (safety campaign: pushes while yawing). Remembered, the same wall
heard a moment earlier face-on still says d.

Frame: heading from the autopilot's attitude estimate (gyro-integrated; only changes of heading
over a few seconds matter, so a slow drift does no harm), position integrated from the speed
estimate. Each fresh echo becomes a plane facing the sensor's axis at the echo's range; planes
are binned by the direction of their normal (10 deg bins, the newest echo of a bin wins) and
forgotten after ``keep_s`` or ``keep_travel_m`` of travel (odometry drift). The clearance along a
body axis is the smallest perpendicular distance to a remembered plane whose normal is within
``max_angle_deg`` of that axis: conservative for an oblique plane (the vehicle closes it at
cos(angle) of its speed along the axis).
"""

from __future__ import annotations

import math

__all__ = ["ObstacleMemory"]


class ObstacleMemory:
    def __init__(self, *, keep_s: float = 3.0, keep_travel_m: float = 2.0, bin_deg: float = 10.0, max_angle_deg: float = 60.0) -> None:
        self.keep_s, self.keep_travel_m = keep_s, keep_travel_m
        self.bin_rad = math.radians(bin_deg)
        self.cos_max = math.cos(math.radians(max_angle_deg))
        self.x = self.y = 0.0  # odometry position (m)
        self.travel_m = 0.0  # path length so far
        self._t: float | None = None
        # bin -> (stamp, nx, ny, offset along n, travel when stored)
        self.planes: dict[int, tuple[float, float, float, float, float]] = {}

    def reset(self) -> None:
        self.planes.clear()

    def advance(self, now: float, vx_m_s: float, vy_m_s: float, yaw_rad: float) -> None:
        """Integrate the heading-frame speed estimate to ``now``."""
        if self._t is not None and now > self._t:
            dt = now - self._t
            c, s = math.cos(yaw_rad), math.sin(yaw_rad)
            dx, dy = (c * vx_m_s - s * vy_m_s) * dt, (s * vx_m_s + c * vy_m_s) * dt
            self.x += dx
            self.y += dy
            self.travel_m += math.hypot(dx, dy)
        self._t = now

    def add(self, stamp_s: float, axis_rad: float, range_m: float, yaw_rad: float) -> None:
        """A fresh echo at ``range_m`` from the sensor whose axis is ``axis_rad`` in the body
        frame (0 front, +pi/2 left), the vehicle heading ``yaw_rad``."""
        a = yaw_rad + axis_rad
        nx, ny = math.cos(a), math.sin(a)
        key = int(round(math.atan2(ny, nx) / self.bin_rad))
        self.planes[key] = (stamp_s, nx, ny, self.x * nx + self.y * ny + range_m, self.travel_m)

    def clearance(self, now: float, axis_rad: float, yaw_rad: float) -> float | None:
        """Smallest perpendicular distance to a remembered surface facing this body axis."""
        a = yaw_rad + axis_rad
        ux, uy = math.cos(a), math.sin(a)
        best = None
        stale = []
        for key, (t, nx, ny, off, trav) in self.planes.items():
            if now - t > self.keep_s or self.travel_m - trav > self.keep_travel_m:
                stale.append(key)
                continue
            if ux * nx + uy * ny < self.cos_max:
                continue
            d = off - (self.x * nx + self.y * ny)
            if best is None or d < best:
                best = d
        for key in stale:
            del self.planes[key]
        return best
