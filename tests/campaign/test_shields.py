"""Baseline shields on scripted cases: one test per documented behaviour of ArduPilot's AC_Avoid
(proximity, slide) and PX4's acceleration-based CollisionPrevention, and the vehicle protections
all three shields share."""

from __future__ import annotations

import math

import pytest

from inspect_pipe.campaign import ArduPilotLikeShield, Px4LikeShield, fly_scenario
from inspect_pipe.campaign._avoid_math import ardupilot_sqrt_controller, px4_cp_scale, px4_max_speed_from_distance
from inspect_pipe.flight import parse_scenario
from inspect_pipe.flight_stack.messages import (
    Clearance, EstimationMode, Measurements, OperatorInput, RangeReading, SpeedCommand, StateEstimate,
)
from inspect_pipe.flight_stack.params import BehaviorParams

EST = StateEstimate(1.0, 1.0, 0.0, 0.0, 0.0, EstimationMode.BOTTOM_FRONT)


def _cmd(shield, now, stick, front=None, left=None, right=None, ages=(0.05, 0.05, 0.05), link_ok=True, est=EST):
    def rr(d, age):
        return None if age is None else RangeReading(now - age, d)

    m = Measurements(front_sonar=rr(front, ages[0]), left_sonar=rr(left, ages[1]), right_sonar=rr(right, ages[2]))
    shield.observe(now, m)
    return shield.update(now, est, Clearance(), OperatorInput(stick=stick, link_ok=link_ok),
                         battery_percent=90.0, flying=True, dt=0.02)


def _hold(shield, stick, seconds, t0=1.0, **kw):
    """The shield's command after ``seconds`` of the same stick and readings (fresh each tick)."""
    out = None
    for k in range(int(round(seconds / 0.02))):
        out = _cmd(shield, t0 + 0.02 * k, stick, **kw)
    return out


# ---------------------------------------------------------------- ArduPilot AC_Avoid


def test_sqrt_controller_is_linear_near_zero_then_square_root():
    # p = 1, limit 1 m/s^2: linear within 1 m, beyond it sqrt(2 a (e - 0.5))
    assert ardupilot_sqrt_controller(0.5, 1.0, 1.0, 0.0) == pytest.approx(0.5)
    assert ardupilot_sqrt_controller(2.0, 1.0, 1.0, 0.0) == pytest.approx(math.sqrt(3.0))
    assert ardupilot_sqrt_controller(-2.0, 1.0, 1.0, 0.0) == pytest.approx(-math.sqrt(3.0))
    # and never more than closes the error within dt
    assert ardupilot_sqrt_controller(0.01, 1.0, 1.0, 0.02) == pytest.approx(0.01)


def test_ardupilot_slides_limiting_only_the_component_towards_the_face():
    s = ArduPilotLikeShield(BehaviorParams())
    # A wall 1.5 m ahead, pushing diagonally: forward limited to sqrt_controller(0.5 m) = 0.5 m/s
    # (linear zone of P = 1), sideways untouched.
    out = _hold(s, SpeedCommand(0.8, 0.4, 0, 0), 1.0, front=1.5, left=4.0, right=4.0)
    assert out.command.vx_m_s == pytest.approx(0.5, abs=0.01)
    assert out.command.vy_m_s == pytest.approx(0.4, abs=0.01)
    assert "avoid_slide" in out.behaviors


def test_ardupilot_brakes_at_most_at_one_metre_per_second_squared_not_avoid_accel_max():
    s = ArduPilotLikeShield(BehaviorParams())
    # 3 m beyond the margin: sqrt(2 x 1 x (3 - 0.5)) = 2.24 m/s with the 1 m/s^2 cap (AC_AVOID_ACCEL_CMSS_MAX);
    # with AVOID_ACCEL_MAX = 3 as the braking rate it would allow 3.8 m/s
    out = _hold(s, SpeedCommand(1.0, 0, 0, 0), 0.5, front=4.0, left=4.0, right=4.0)
    assert out.command.vx_m_s == pytest.approx(1.0)  # 1 m/s is below either limit
    s2 = ArduPilotLikeShield(BehaviorParams())
    out = _hold(s2, SpeedCommand(1.0, 0, 0, 0), 1.0, front=1.6, left=4.0, right=4.0)
    assert out.command.vx_m_s == pytest.approx(ardupilot_sqrt_controller(0.6, 1.0, 1.0, 0.02), abs=0.01)


def test_ardupilot_avoid_accel_max_limits_how_fast_avoidance_changes_the_velocity():
    s = ArduPilotLikeShield(BehaviorParams())
    _hold(s, SpeedCommand(1.0, 0, 0, 0), 0.5, front=4.5, left=4.0, right=4.0)
    # a wall appears 1.05 m ahead: the limit drops to 0.05 m/s, but the velocity handed on falls
    # by at most AVOID_ACCEL_MAX x dt = 0.06 m/s per 20 ms tick
    out = _cmd(s, 2.0, SpeedCommand(1.0, 0, 0, 0), front=1.05, left=4.0, right=4.0)
    assert out.command.vx_m_s == pytest.approx(1.0 - 3.0 * 0.02, abs=1e-6)
    out = _hold(s, SpeedCommand(1.0, 0, 0, 0), 0.5, t0=2.02, front=1.05, left=4.0, right=4.0)
    assert out.command.vx_m_s == pytest.approx(0.05, abs=0.01)


def test_ardupilot_backs_away_beyond_the_dead_zone_at_most_backup_speed():
    s = ArduPilotLikeShield(BehaviorParams())
    # 0.05 m inside the margin: within AVOID_BACKUP_DZ, no back-away
    assert _hold(s, SpeedCommand(), 0.5, front=0.95, left=4.0, right=4.0).command.vx_m_s == pytest.approx(0.0)
    # 0.3 m inside: sqrt_controller(0.3, 1, 0.4) = 0.3 m/s back
    s = ArduPilotLikeShield(BehaviorParams())
    assert _hold(s, SpeedCommand(), 1.0, front=0.7, left=4.0, right=4.0).command.vx_m_s == pytest.approx(-0.3, abs=0.01)
    # 0.7 m inside: sqrt(2 x 0.4 x (0.7 - 0.2)) = 0.63; at 0.35 m from a wall on two sides the sum
    # of quadrant maxima is capped at AVOID_BACKUP_SPD
    s = ArduPilotLikeShield(BehaviorParams())
    out = _hold(s, SpeedCommand(), 1.0, front=0.35, left=0.35, right=4.0)
    assert math.hypot(out.command.vx_m_s, out.command.vy_m_s) == pytest.approx(0.75, abs=0.01)
    assert "avoid_backup" in out.behaviors


def test_ardupilot_proximity_has_no_data_only_when_no_rangefinder_reported_for_200_ms():
    s = ArduPilotLikeShield(BehaviorParams())
    # One sonar 0.6 s old, the others fresh: still Good, the fresh front face still limits
    out = _hold(s, SpeedCommand(0.8, 0, 0, 0), 0.5, front=1.0, left=4.0, right=4.0, ages=(0.05, 0.6, None))
    assert out.command.vx_m_s == pytest.approx(0.0, abs=0.01)
    # every rangefinder silent for more than 200 ms: NoData, avoidance does nothing
    s = ArduPilotLikeShield(BehaviorParams())
    _cmd(s, 1.0, SpeedCommand(0.8, 0, 0, 0), front=1.0, left=4.0, right=4.0)
    out = _cmd(s, 1.3, SpeedCommand(0.8, 0, 0, 0), front=1.0, left=4.0, right=4.0, ages=(0.3, 0.3, 0.3))
    assert out.command.vx_m_s == pytest.approx(0.8)


def test_ardupilot_out_of_range_reading_clears_its_face_and_a_silent_face_expires():
    s = ArduPilotLikeShield(BehaviorParams())
    _cmd(s, 1.0, SpeedCommand(0.8, 0, 0, 0), front=1.0, left=4.0, right=4.0)
    # front now reports no echo (out of range): its face is cleared, forward is free
    assert _hold(s, SpeedCommand(0.8, 0, 0, 0), 0.5, t0=1.1, front=None, left=4.0, right=4.0).command.vx_m_s == pytest.approx(0.8)


# ---------------------------------------------------------------- PX4 CollisionPrevention


def test_px4_trajectory_helpers():
    # computeMaxSpeedFromDistance: v with v^2 = 2 a (x - v 2 a / j); a 3, j 8, x 1 -> 1.31 m/s
    v = px4_max_speed_from_distance(1.0, accel_m_s2=3.0, jerk_m_s3=8.0)
    assert v * v == pytest.approx(2 * 3.0 * (1.0 - v * 2 * 3.0 / 8.0), rel=1e-6)
    # _getScale: quadratic outside CP_DIST, negative (pushing away) inside
    assert px4_cp_scale(2.0, keep_m=1.0, scale_distance_m=1.0526) == pytest.approx((1.0 / 1.0526) ** 2)
    assert px4_cp_scale(0.8, keep_m=1.0, scale_distance_m=1.0526) == pytest.approx(-0.2)
    assert px4_cp_scale(9.0, keep_m=1.0, scale_distance_m=1.0526) == 1.0


def test_px4_scales_the_acceleration_towards_the_closest_obstacle_and_stops_at_cp_dist():
    s = Px4LikeShield(BehaviorParams())
    # far from everything the set-point settles at the stick
    assert _hold(s, SpeedCommand(0.5, 0, 0, 0), 3.0, front=4.9, left=4.9, right=4.9).command.vx_m_s == pytest.approx(0.5, abs=0.02)
    # a wall 1.2 m ahead: pushing on at full stick the velocity set-point comes down below 0.1 m/s
    s = Px4LikeShield(BehaviorParams())
    out = _hold(s, SpeedCommand(1.0, 0, 0, 0), 4.0, front=1.2, left=4.9, right=4.9)
    assert 0.0 <= out.command.vx_m_s < 0.1 and "collision_prevention" in out.behaviors
    # inside CP_DIST the scale turns negative: the set-point backs away
    s = Px4LikeShield(BehaviorParams())
    assert _hold(s, SpeedCommand(0.5, 0, 0, 0), 2.0, front=0.8, left=4.9, right=4.9).command.vx_m_s < -0.02


def test_px4_velocity_compensation_brakes_a_fast_approach():
    s = Px4LikeShield(BehaviorParams())
    _hold(s, SpeedCommand(1.0, 0, 0, 0), 3.0, front=4.9, left=4.9, right=4.9)  # cruising at 1 m/s
    # 1.3 m from the wall the stoppable speed, after CP_DELAY x v, is far below 1 m/s: it brakes hard
    before = s._v_sp[0]
    out = _cmd(s, 5.0, SpeedCommand(1.0, 0, 0, 0), front=1.3, left=4.9, right=4.9)
    assert before - out.command.vx_m_s > 0.03  # more than the 0.06 m/s^2 x 0.02 s drag alone


def test_px4_no_rear_sensor_no_flying_backwards_and_cp_go_no_data():
    s = Px4LikeShield(BehaviorParams())
    out = _hold(s, SpeedCommand(-0.5, 0, 0, 0), 1.0, front=4.9, left=4.9, right=4.9)
    assert out.command.vx_m_s == pytest.approx(0.0, abs=0.01)
    from inspect_pipe.campaign.shields import Px4LikeParams

    s = Px4LikeShield(BehaviorParams(), Px4LikeParams(cp_go_no_data=True))
    assert _hold(s, SpeedCommand(-0.5, 0, 0, 0), 2.0, front=4.9, left=4.9, right=4.9).command.vx_m_s < -0.3


def test_px4_bins_go_stale_after_500_ms_and_without_data_it_stops_then_holds():
    s = Px4LikeShield(BehaviorParams())
    # left data 0.6 s old: the left bins are empty, no motion to the left; to the right yes
    assert _hold(s, SpeedCommand(0, 0.5, 0, 0), 1.0, front=4.9, left=4.0, right=4.0, ages=(0.05, 0.6, 0.05)).command.vy_m_s == pytest.approx(0.0, abs=0.01)
    s = Px4LikeShield(BehaviorParams())
    assert _hold(s, SpeedCommand(0, -0.5, 0, 0), 2.0, front=4.9, left=4.0, right=4.0, ages=(0.05, 0.6, 0.05)).command.vy_m_s < -0.3
    # no data at all: no acceleration (the set-point decays), after 5 s Hold
    s = Px4LikeShield(BehaviorParams())
    _cmd(s, 0.0, SpeedCommand(0, 0.5, 0, 0), left=3.0, right=3.0, front=3.0)
    out = _cmd(s, 1.0, SpeedCommand(0.3, 0.3, 0, 0), ages=(None, None, None))
    assert "cp_no_data" in out.behaviors
    out = _cmd(s, 5.6, SpeedCommand(0.3, 0.3, 0, 0), ages=(None, None, None))
    assert "cp_hold_no_data" in out.behaviors and out.command.vx_m_s == 0 and out.command.vy_m_s == 0


def test_px4_guidance_turns_the_setpoint_by_at_most_cp_guide_ang_towards_a_freer_bin():
    s = Px4LikeShield(BehaviorParams())
    # diagonal forward-left (45 deg, a bin no sensor sees), the left wall close, the front free
    _cmd(s, 1.0, SpeedCommand(0.5, 0.5, 0, 0), front=4.9, left=1.6, right=4.9)
    chosen = s._guide(s._bin_of(1.0, 1.0))
    # THEN the direction turns to the free front's edge bin, 30 deg away (CP_GUIDE_ANG), not further
    assert chosen * s.p.bin_deg == 15
    # AND with the left wall far as well, the nearer of the two seen directions wins no more than 30 deg away
    s = Px4LikeShield(BehaviorParams())
    _cmd(s, 1.0, SpeedCommand(0.5, 0.5, 0, 0), front=1.6, left=4.9, right=4.9)
    assert s._guide(s._bin_of(1.0, 1.0)) * s.p.bin_deg == 75


# ---------------------------------------------------------------- shared vehicle protections


@pytest.mark.parametrize("cls", [Px4LikeShield, ArduPilotLikeShield])
def test_baselines_get_our_link_loss_hover_and_alarm_stick(cls):
    s = cls(BehaviorParams())
    _hold(s, SpeedCommand(0.4, 0, 0, 0), 2.0, front=4.9, left=4.9, right=4.9)
    # link lost: waiting_for_connectivity's hover at once, whatever the last stick; no landing
    out = _cmd(s, 3.1, SpeedCommand(0.4, 0, 0, 0), front=4.9, left=4.9, right=4.9, link_ok=False)
    assert "waiting_for_connectivity" in out.behaviors and not out.land_request
    out = _hold(s, SpeedCommand(0.4, 0, 0, 0), 1.0, t0=3.12, front=4.9, left=4.9, right=4.9, link_ok=False)
    assert abs(out.command.vx_m_s) < 0.05
    # an alarm mode: the stick is zeroed as ours does (the filled state brings the vehicle down)
    s = cls(BehaviorParams())
    alarm = StateEstimate(1.0, 1.0, 0.0, 0.0, 0.0, EstimationMode.ALARM_NONE)
    out = _hold(s, SpeedCommand(0.4, 0.3, 0.2, 0.1), 1.0, front=4.9, left=4.9, right=4.9, est=alarm)
    assert abs(out.command.vx_m_s) < 0.05 and abs(out.command.vy_m_s) < 0.05 and out.command.vz_m_s == 0.0
    assert out.command.yaw_rate_rad_s == pytest.approx(0.1)


@pytest.mark.parametrize("shield", ["px4_like", "ardupilot_like"])
def test_baselines_stop_before_the_wall_in_flight(shield):
    sc = parse_scenario({
        "format": "inspect_pipe.scenario/1", "name": "approach", "duration_s": 16, "seed": 3,
        "world": {"hold": {"length_m": 9, "width_m": 8, "height_m": 8}},
        "vehicle": {"start": {"position": [4.0, 0, 0]}},
        "operator": [{"t": 0.5, "button": "takeoff"}, {"t": 4.0, "stick": {"vx": 0.5}}],
    })
    closest = [9.0]
    res = fly_scenario(sc, shield, lambda r: closest.__setitem__(0, min(closest[0], r.dist_true.front)))
    assert res.status.value == "completed"
    assert 0.6 < closest[0] < 1.5
