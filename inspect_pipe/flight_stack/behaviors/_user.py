"""Attenuation of a user speed vector towards zero near obstacles, shared by attenuated_go and
attenuated_inspect (and the go_ahead/inspect_ahead latches)."""

from __future__ import annotations

from inspect_pipe.flight_stack.behaviors._obstacle_math import attenuation, clamp
from inspect_pipe.flight_stack.messages import BehaviorInputs, SpeedCommand
from inspect_pipe.flight_stack.params import BehaviorParams


def attenuate(cmd: SpeedCommand, inputs: BehaviorInputs, p: BehaviorParams) -> SpeedCommand:
    """Scale each axis by the closeness of the obstacle it moves towards (front, sides, floor).

    A sector whose sonar has gone silent is unknown: no user motion into it (the safety
    campaign found pushes held at a wall running into it when the wall's sonar blacked out)."""
    c = inputs.clearance
    vx = clamp(cmd.vx_m_s, p.max_speed_m_s)
    vy = clamp(cmd.vy_m_s, p.max_speed_m_s)
    vz = clamp(cmd.vz_m_s, p.max_vertical_speed_m_s)
    start, stop = p.attenuation_start_m, p.safe_distance_m
    if vx > 0.0:
        vx = 0.0 if c.front_stale else vx * attenuation(c.front_m, start_m=start, stop_m=stop)
    if vy > 0.0:
        vy = 0.0 if c.left_stale else vy * attenuation(c.left_m, start_m=start, stop_m=stop)
    elif vy < 0.0:
        vy = 0.0 if c.right_stale else vy * attenuation(c.right_m, start_m=start, stop_m=stop)
    if vz < 0.0:
        vz *= attenuation(c.down_m, start_m=p.floor_attenuation_start_m, stop_m=p.floor_clearance_m)
    return SpeedCommand(vx, vy, vz, cmd.yaw_rate_rad_s)
