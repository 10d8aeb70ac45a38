"""waiting_for_connectivity: hold station while the link with the base station is lost.

The paper's behaviour commands zero speed (hover), and so does this one until the vehicle has
braked to rest (estimated speed below ``link_loss_rest_m_s``). A speed loop told "zero" then
gives way to a gust or to an estimator's slow error, so from there on the vehicle holds the
odometry position where it came to rest: a speed towards it of ``position_gain_1_s`` per
metre of error, at most ``hold_speed_max_m_s``. (Holding the point where the loss was
detected instead flew the vehicle back over its own braking distance, 0.3 m from 0.8 m/s,
with nobody at the stick.) Without odometry (no heading from the autopilot) it is the paper's
plain hover, and so it is in the alarm modes (-1, -2): there no sensor measures the horizontal
speed, the odometry is the IMU's dead reckoning, and chasing the point it held flew a vibrating
vehicle 0.3 m towards the wall it no longer heard; the point is
dropped, and a new one taken at rest once a speed is measured again.
"""

from __future__ import annotations

import math

from inspect_pipe.flight_stack.messages import HOVER, AxisVector, BehaviorInputs


class WaitingForConnectivity:
    name = "waiting_for_connectivity"

    def __init__(self, params=None) -> None:
        self.p = params
        self._hold: tuple[float, float] | None = None

    def activate(self) -> None:
        pass

    def update(self, inputs: BehaviorInputs, dt: float) -> AxisVector | None:
        if inputs.link_ok:
            self._hold = None
            return None
        odo = inputs.estimate.odometry
        if odo is None or self.p is None or not inputs.flying or inputs.estimate.mode < 0:
            self._hold = None
            return AxisVector.full(HOVER)
        x, y, yaw = odo
        if self._hold is None:
            e = inputs.estimate
            if math.hypot(e.vx_m_s, e.vy_m_s) >= self.p.link_loss_rest_m_s:
                return AxisVector.full(HOVER)
            self._hold = (x, y)
        k, vmax = self.p.position_gain_1_s, self.p.hold_speed_max_m_s
        ex, ey = self._hold[0] - x, self._hold[1] - y
        vx_w, vy_w = k * ex, k * ey
        n = math.hypot(vx_w, vy_w)
        if n > vmax:
            vx_w, vy_w = vx_w * vmax / n, vy_w * vmax / n
        c, s = math.cos(yaw), math.sin(yaw)
        return AxisVector(c * vx_w + s * vy_w, -s * vx_w + c * vy_w, 0.0, 0.0)
