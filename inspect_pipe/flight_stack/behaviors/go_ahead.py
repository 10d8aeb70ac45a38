"""go_ahead: keep the user's speed command after the stick is released.

Latched when the go_ahead button is pressed; released by a new stick command, by an obstacle in
the direction of motion (prevent_collision then stops the vehicle), by losing the link, or on
leaving the flying state.
"""

from __future__ import annotations

from inspect_pipe.flight_stack.behaviors._obstacle_math import must_stop
from inspect_pipe.flight_stack.messages import AxisVector, BehaviorInputs, SpeedCommand
from inspect_pipe.flight_stack.params import BehaviorParams


def obstacle_ahead(cmd: SpeedCommand, inputs: BehaviorInputs, p: BehaviorParams) -> bool:
    c, e = inputs.clearance, inputs.estimate
    if (cmd.vx_m_s > 0 and c.front_stale) or (cmd.vy_m_s > 0 and c.left_stale) or (cmd.vy_m_s < 0 and c.right_stale):
        return True  # moving into a sector whose sonar went silent
    kw = dict(safe_m=p.safe_distance_m, response_time_s=p.response_time_s, decel_m_s2=p.brake_decel_m_s2)
    if cmd.vx_m_s > 0 and must_stop(c.front_m, max(e.vx_m_s, cmd.vx_m_s), **kw):
        return True
    if cmd.vy_m_s > 0 and must_stop(c.left_m, max(e.vy_m_s, cmd.vy_m_s), **kw):
        return True
    if cmd.vy_m_s < 0 and must_stop(c.right_m, max(-e.vy_m_s, -cmd.vy_m_s), **kw):
        return True
    if cmd.vz_m_s < 0 and c.down_m is not None and c.down_m <= p.floor_clearance_m:
        return True
    return False


def _differs(a: SpeedCommand, b: SpeedCommand, eps: float) -> bool:
    return (
        abs(a.vx_m_s - b.vx_m_s) > eps
        or abs(a.vy_m_s - b.vy_m_s) > eps
        or abs(a.vz_m_s - b.vz_m_s) > eps
        or abs(a.yaw_rate_rad_s - b.yaw_rate_rad_s) > eps
    )


class GoAhead:
    name = "go_ahead"

    def __init__(self, params: BehaviorParams) -> None:
        self.p = params
        self.latched: SpeedCommand | None = None

    def activate(self) -> None:
        self.latched = None

    def command_from(self, stick: SpeedCommand) -> SpeedCommand:
        return stick

    def update(self, inputs: BehaviorInputs, dt: float) -> AxisVector | None:
        p = self.p
        if inputs.go_ahead_pressed and inputs.flying:
            cmd = self.command_from(inputs.stick)
            self.latched = None if cmd.is_zero() else cmd
        elif self.latched is not None:
            stick = self.command_from(inputs.stick)
            if not stick.is_zero() and _differs(stick, self.latched, p.stick_deadband_m_s):
                self.latched = None  # a new desired speed
            elif not inputs.link_ok or not inputs.flying:
                self.latched = None
        if self.latched is not None and obstacle_ahead(self.latched, inputs, p):
            self.latched = None
        return None if self.latched is None else AxisVector.full(self.latched)
