"""Short-term memory of the surfaces the horizontal sonars have heard, so that a clearance does not
depend on which way the vehicle happens to point right now.

Each sonar reports one number: the nearest echo in its beam. Yawed by 40 deg at a wall, the front
sonar hears the wall at d / cos(25 deg), and a stop line held on that reading ends 0.1-0.2 m
inside the perpendicular 1 m (safety campaign: pushes while yawing). Remembered, the same wall
heard a moment earlier face-on still says d.

Frame: heading from the autopilot's attitude estimate (gyro-integrated; only changes of heading
over a few seconds matter, so a slow drift does no harm), position integrated from the speed
estimate. Each fresh echo becomes a plane facing the sensor's axis at the echo's range; planes
are binned by the direction of their normal (10 deg bins, the newest echo of a bin wins, but see the next sentence) and
forgotten after ``keep_travel_m`` of travel (odometry drift), after ``keep_s`` of flight without a
measured horizontal speed (the alarm modes, where the odometry drifts with the IMU's errors), or
once the altitude has changed by more than ``body_radius_m`` since the echo (the horizontal beams
say nothing about how far up or down a surface reaches: a floor box heard during the climb is
not in the way of the flight above it, and the sonars at the new height hear what is). Forgotten
after a fixed 8 s instead, a corner pillar heard 3 m ahead while hovering was gone by the time
an inspection sweep slid sideways past it, inside the blind diagonal between two beams; a low box
heard during the climb and kept in the front sonar's bin hid the same kind of pillar. A heard surface is not
replaced by a farther echo of its bin (by more than ``jump_m``) until the vehicle has moved sideways
of it by the beam's half-width at its range plus ``body_radius_m``: a farther echo then means that
the nearer surface left the beam's edge (the beam narrows as the vehicle closes in, or a gust moved it
a few centimetres), not that it is gone, and where it was heard it can still be in the vehicle's
path (a box heard 1.03 m ahead for 4 s left the beam when the vehicle drifted 3 cm, the
far wall's 2.45 m replaced it and the vehicle flew into the box). The clearance along a
body axis is the smallest perpendicular distance to a remembered plane whose normal is within
``max_angle_deg`` of that axis: conservative for an oblique plane (the vehicle closes it at
cos(angle) of its speed along the axis).
"""

from __future__ import annotations

import math
from typing import NamedTuple

__all__ = ["ObstacleMemory", "oblique_wall"]


def oblique_wall(r1: float, r2: float, half_beam_rad: float) -> tuple[float, float] | None:
    """One flat wall that explains two sonars at right angles, or None.

    ``r1``, ``r2``: nearest echoes of two beams whose axes are 90 deg apart, each beam
    +-``half_beam_rad`` wide. A wall whose normal lies at ``phi`` from beam 1 towards beam 2,
    outside both beams, is heard by beam 1 at d / cos(phi - h) and by beam 2 at
    d / cos(90 deg - phi - h); solved for phi: tan(phi) = (r1 cos h - r2 sin h) / (r2 cos h - r1 sin h).
    Returns (phi, d) when phi lies outside both beams (h < phi < 90 deg - h), i.e. when each
    reading alone overstates the perpendicular distance d. Yawed 45 deg at a wall 0.86 m away,
    both sonars read about 1.02 m: a stop line held on either ends 0.14 m inside.

    Two numbers cannot tell that wall from an inside corner (walls at r1 and r2 face-on): there
    the answer is a wall across the corner, nearer than both, so the error is on the safe side
    (a corner push holds about 0.15 m further out)."""
    h = half_beam_rad
    ch, sh = math.cos(h), math.sin(h)
    num, den = r1 * ch - r2 * sh, r2 * ch - r1 * sh
    if num <= 0.0 or den <= 0.0:
        return None
    phi = math.atan2(num, den)
    if not h < phi < math.pi / 2 - h:
        return None
    return phi, r1 * math.cos(phi - h)


class _Plane(NamedTuple):
    stamp_s: float
    nx: float  # unit normal, towards the surface (odometry frame)
    ny: float
    offset_m: float  # the plane is {p : p . n = offset_m}
    travel_m: float  # the path length when it was stored
    keep_s: float
    release_m: float | None  # sideways motion that lets a farther echo replace it (None: an inferred surface)
    x: float  # the odometry position when it was stored
    y: float
    blind_s: float  # the memory's time without a measured speed when it was stored
    z: float | None  # the altitude it was heard at


class ObstacleMemory:
    def __init__(self, *, keep_s: float = 3.0, keep_travel_m: float = 2.0, bin_deg: float = 10.0, max_angle_deg: float = 60.0,
                 jump_m: float = math.inf, beam_half_rad: float = 0.0, body_radius_m: float = 0.0) -> None:
        self.keep_s, self.keep_travel_m = keep_s, keep_travel_m
        self.jump_m, self.sin_beam, self.body_radius_m = jump_m, math.sin(beam_half_rad), body_radius_m
        self.bin_rad = math.radians(bin_deg)
        self.cos_max = math.cos(math.radians(max_angle_deg))
        self.x = self.y = 0.0  # odometry position (m)
        self.travel_m = 0.0  # path length so far
        self.blind_s = 0.0  # time so far without a measured horizontal speed
        self.z: float | None = None  # altitude (m), when known
        self._t: float | None = None
        self.planes: dict[int, _Plane] = {}  # by the direction of the normal

    def reset(self) -> None:
        self.planes.clear()

    def advance(
        self, now: float, vx_m_s: float, vy_m_s: float, yaw_rad: float, *, altitude_m: float | None = None, measured: bool = True
    ) -> None:
        """Integrate the heading-frame speed estimate to ``now``; ``measured``: a sensor measured
        that speed (not the IMU alone); ``altitude_m``: the altitude now, when known."""
        self.z = altitude_m
        if self._t is not None and now > self._t:
            dt = now - self._t
            if not measured:
                self.blind_s += dt
            c, s = math.cos(yaw_rad), math.sin(yaw_rad)
            dx, dy = (c * vx_m_s - s * vy_m_s) * dt, (s * vx_m_s + c * vy_m_s) * dt
            self.x += dx
            self.y += dy
            self.travel_m += math.hypot(dx, dy)
        self._t = now

    def add(self, stamp_s: float, axis_rad: float, range_m: float, yaw_rad: float, keep_s: float | None = None) -> None:
        """A fresh echo at ``range_m`` from the sensor whose axis is ``axis_rad`` in the body
        frame (0 front, +pi/2 left), the vehicle heading ``yaw_rad``; ``keep_s`` shortens how
        long this one is kept (an inferred surface rather than a heard one)."""
        a = yaw_rad + axis_rad
        nx, ny = math.cos(a), math.sin(a)
        key = int(round(math.atan2(ny, nx) / self.bin_rad))
        off = self.x * nx + self.y * ny + range_m
        old = self.planes.get(key)
        if old is not None and old.release_m is not None and off > old.offset_m + self.jump_m and not self._stale(old, stamp_s):
            sideways = -(self.x - old.x) * old.ny + (self.y - old.y) * old.nx
            if abs(sideways) < old.release_m:
                return  # the nearer surface left the beam's edge: still there
        keep = self.keep_s if keep_s is None else min(keep_s, self.keep_s)
        release = range_m * self.sin_beam + self.body_radius_m if keep_s is None else None  # heard, not inferred
        self.planes[key] = _Plane(stamp_s, nx, ny, off, self.travel_m, keep, release, self.x, self.y, self.blind_s, self.z)

    def _stale(self, plane: _Plane, now: float) -> bool:
        if self.travel_m - plane.travel_m > self.keep_travel_m or self.blind_s - plane.blind_s > plane.keep_s:
            return True
        if plane.release_m is None:
            return now - plane.stamp_s > plane.keep_s  # an inferred surface: kept only as long as asked
        z, z0 = self.z, plane.z
        return z is not None and z0 is not None and abs(z - z0) > self.body_radius_m

    def clearance(self, now: float, axis_rad: float, yaw_rad: float) -> float | None:
        """Smallest perpendicular distance to a remembered surface facing this body axis."""
        a = yaw_rad + axis_rad
        ux, uy = math.cos(a), math.sin(a)
        best = None
        stale = []
        for key, plane in self.planes.items():
            if self._stale(plane, now):
                stale.append(key)
                continue
            nx, ny, off = plane.nx, plane.ny, plane.offset_m
            if ux * nx + uy * ny < self.cos_max:
                continue
            d = off - (self.x * nx + self.y * ny)
            if best is None or d < best:
                best = d
        for key in stale:
            del self.planes[key]
        return best
