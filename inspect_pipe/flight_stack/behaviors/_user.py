"""Attenuation of a user speed vector towards zero near obstacles, shared by attenuated_go and
attenuated_inspect (and the go_ahead/inspect_ahead latches)."""

from __future__ import annotations

import math

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
    # Whether the motion is diagonal is decided on the operator's direction, before the per-axis
    # attenuation below turns a diagonal push towards the less attenuated axis (safety campaign:
    # a 49 deg push into an inside corner became a 76 deg crawl, judged "seen by the left beam",
    # into a pillar's corner that no beam had heard).
    vx, vy = sensed_direction(vx, vy, inputs, p)
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


def sensed_direction(vx: float, vy: float, inputs: BehaviorInputs, p: BehaviorParams) -> tuple[float, float]:
    """A diagonal motion that no sonar beam looks along, near a wall: only its component along
    the axis nearer its direction is flown (beyond the paper).

    The sonars look ahead, left and right (+-15 deg beams); a diagonal path between them crosses
    space no sensor has heard, and the convex corner of a pillar or coaming standing in it is only
    heard when the vehicle is already too close to stop. Obstacles stand at the walls, so within
    ``blind_attenuation_start_m`` of the nearer of the two neighbouring walls the push is turned
    onto the nearer axis, where a beam sees what the vehicle moves towards and the per-axis
    attenuation stops it; far from the walls it is flown as given. (Slowed instead, from 3 m to
    zero at the safe distance, the diagonal still crept at 0.07-0.1 m/s into pillars standing
    0.5-2 m out of a corner. PX4's collision
    prevention turns a set-point into the nearest direction with data, ``CP_GUIDE_ANG``, for the
    same reason.)"""
    if vx <= 0.0 or vy == 0.0:
        return vx, vy
    off_axis = math.degrees(math.atan2(abs(vy), vx))
    if off_axis <= p.covered_half_angle_deg or off_axis >= 90.0 - p.covered_half_angle_deg:
        return vx, vy
    c = inputs.clearance
    side = c.left_m if vy > 0.0 else c.right_m
    near = min((d for d in (c.front_m, side) if d is not None), default=None)
    if near is None or near >= p.blind_attenuation_start_m:
        return vx, vy
    return (vx, 0.0) if off_axis < 45.0 else (0.0, vy)
