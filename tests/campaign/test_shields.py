"""Baseline shields on scripted cases: each behaves as its documentation says."""

from __future__ import annotations

import math

import pytest

from inspect_pipe.campaign import ArduPilotLikeShield, Px4LikeShield, fly_scenario
from inspect_pipe.campaign._avoid_math import jerk_limited_max_speed_m_s, quadratic_scale
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
    out = shield.update(now, est, Clearance(), OperatorInput(stick=stick, link_ok=link_ok),
                        battery_percent=90.0, flying=True, dt=0.02)
    return out


def test_px4_scales_quadratically_and_stops_at_the_keep_distance():
    s = Px4LikeShield(BehaviorParams())
    # GIVEN a wall 2 m ahead (1 m beyond CP_DIST, half the 2 m scaling band) WHEN full stick forward
    out = _cmd(s, 1.0, SpeedCommand(1.0, 0, 0, 0), front=2.0)
    # THEN the speed is the quadratic scale 0.25 x cruise (the braking limit is higher there)
    assert out.command.vx_m_s == pytest.approx(0.25 * quadratic_scale(2.0, keep_m=1.0, band_m=2.0) / 0.25, abs=1e-6)
    assert jerk_limited_max_speed_m_s(1.0, accel_m_s2=1.2, jerk_m_s3=8.0) > 0.25
    # At the keep distance nothing goes forward; sideways motion stays allowed.
    out = _cmd(s, 1.1, SpeedCommand(0.0, 0.5, 0, 0), front=1.0, left=4.0, right=4.0)
    assert out.command.vx_m_s == pytest.approx(0.0, abs=1e-9) and out.command.vy_m_s == pytest.approx(0.5)
    out = _cmd(s, 1.2, SpeedCommand(0.5, 0.0, 0, 0), front=1.0)
    assert abs(out.command.vx_m_s) < 0.05


def test_px4_blocks_stale_sectors_and_the_rear_and_holds_without_data():
    s = Px4LikeShield(BehaviorParams())
    # Left data 0.6 s old: no motion to the left, but to the right.
    assert _cmd(s, 2.0, SpeedCommand(0, 0.5, 0, 0), front=None, left=3.0, right=3.0, ages=(0.05, 0.6, 0.05)).command.vy_m_s == pytest.approx(0.0)
    assert _cmd(s, 2.1, SpeedCommand(0, -0.5, 0, 0), front=None, left=3.0, right=3.0, ages=(0.05, 0.6, 0.05)).command.vy_m_s == pytest.approx(-0.5)
    # No rear sensor: cannot fly backwards (CP_GO_NO_DATA = 0).
    assert _cmd(s, 2.2, SpeedCommand(-0.5, 0, 0, 0), front=None, left=3.0, right=3.0).command.vx_m_s == pytest.approx(0.0)
    # No data at all for more than 5 s: hold.
    s2 = Px4LikeShield(BehaviorParams())
    _cmd(s2, 0.0, SpeedCommand(0, 0.5, 0, 0), left=3.0, right=3.0, front=3.0)
    out = _cmd(s2, 5.5, SpeedCommand(0.3, 0.3, 0, 0), ages=(None, None, None))
    assert "cp_hold_no_data" in out.behaviors and out.command.vx_m_s == 0 and out.command.vy_m_s == 0


def test_ardupilot_slides_brakes_by_square_root_and_backs_away():
    s = ArduPilotLikeShield(BehaviorParams())
    # Slide: only the component towards the wall is cut.
    out = _cmd(s, 1.0, SpeedCommand(0.5, 0.5, 0, 0), front=1.0, left=4.0, right=4.0)
    assert out.command.vx_m_s == pytest.approx(0.0) and out.command.vy_m_s == pytest.approx(0.5)
    # Square-root law at 1 m/s^2: 0.2 m before the margin -> sqrt(0.4) m/s.
    out = _cmd(s, 1.1, SpeedCommand(1.0, 0, 0, 0), front=1.2, left=4.0, right=4.0)
    assert out.command.vx_m_s == pytest.approx(math.sqrt(0.4))
    # Inside the dead zone: no back-away; beyond it: back away, at most 0.75 m/s.
    assert _cmd(s, 1.2, SpeedCommand(0, 0, 0, 0), front=0.95, left=4.0, right=4.0).command.vx_m_s == pytest.approx(0.0)
    assert _cmd(s, 1.3, SpeedCommand(0, 0, 0, 0), front=0.7, left=4.0, right=4.0).command.vx_m_s == pytest.approx(-0.3)
    assert _cmd(s, 1.4, SpeedCommand(0, 0, 0, 0), front=0.3, left=4.0, right=4.0).command.vx_m_s == pytest.approx(-0.75)


def test_ardupilot_does_nothing_while_the_proximity_sensor_is_unhealthy():
    s = ArduPilotLikeShield(BehaviorParams())
    out = _cmd(s, 1.0, SpeedCommand(0.8, 0, 0, 0), front=1.0, left=4.0, right=4.0, ages=(0.05, 0.6, 0.05))
    assert out.command.vx_m_s == pytest.approx(0.8)


def test_link_loss_failsafes():
    px4, ap = Px4LikeShield(BehaviorParams()), ArduPilotLikeShield(BehaviorParams())
    go = SpeedCommand(0.4, 0, 0, 0)
    for s in (px4, ap):
        _cmd(s, 1.0, go, front=4.0, left=4.0, right=4.0)
    # The link layer reports loss 0.25 s after the last message: PX4 keeps the stick until 0.5 s.
    assert _cmd(px4, 1.2, SpeedCommand(), front=4.0, left=4.0, right=4.0, link_ok=False).command.vx_m_s > 0.1
    out = _cmd(px4, 1.3, SpeedCommand(), front=4.0, left=4.0, right=4.0, link_ok=False)
    assert out.command.vx_m_s == 0 and not out.land_request
    # ArduPilot keeps it until RC_FS_TIMEOUT = 1 s, then lands.
    assert _cmd(ap, 1.7, SpeedCommand(), front=4.0, left=4.0, right=4.0, link_ok=False).command.vx_m_s > 0.1
    assert _cmd(ap, 1.8, SpeedCommand(), front=4.0, left=4.0, right=4.0, link_ok=False).land_request


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
    assert 0.6 < closest[0] < 1.5  # PX4-like creeps on quadratically: 0.03 m/s at 1.35 m
