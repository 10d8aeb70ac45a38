"""Behaviours one by one, with synthetic inputs."""

from __future__ import annotations

import pytest

from inspect_pipe.flight_stack.behaviors import (
    AttenuatedGo,
    AttenuatedInspect,
    EnsureReferenceSurfaceDetection,
    GoAhead,
    LimitMaxHeight,
    LowBatteryLand,
    MAVBehaviors,
    PreventCollision,
    WaitingForConnectivity,
)
from inspect_pipe.flight_stack.behaviors._obstacle_math import attenuation, stop_point_m
from inspect_pipe.flight_stack.messages import (
    BehaviorInputs,
    Button,
    Clearance,
    EstimationMode,
    OperatorInput,
    SpeedCommand,
    StateEstimate,
)
from inspect_pipe.flight_stack.params import BehaviorParams

P = BehaviorParams()


def _in(stick=SpeedCommand(), *, front=None, left=None, right=None, down=1.5, vx=0.0, vy=0.0, vz=0.0,
        alt=1.5, link=True, inspection=False, go=False, battery=100.0, mode=EstimationMode.BOTTOM_FRONT):
    est = StateEstimate(down, alt, vx, vy, vz, mode)
    return BehaviorInputs(0.0, est, Clearance(front, left, right, down), stick, link, inspection, go, battery, True)


@pytest.mark.parametrize("d, factor", [(3.0, 1.0), (1.5, 1.0), (1.25, 0.5), (1.0, 0.0), (0.7, 0.0), (None, 1.0)])
def test_attenuation_is_linear_between_1_5_and_1_m(d, factor):
    assert attenuation(d, start_m=1.5, stop_m=1.0) == pytest.approx(factor)


def test_stop_point_accounts_for_response_time_and_braking():
    assert stop_point_m(2.0, 1.0, response_time_s=0.35, decel_m_s2=1.2) == pytest.approx(2.0 - 0.35 - 1 / 2.4)
    assert stop_point_m(2.0, -0.5, response_time_s=0.35, decel_m_s2=1.2) == 2.0


def test_attenuated_go_attenuates_only_towards_the_obstacle():
    v = AttenuatedGo(P).update(_in(SpeedCommand(0.4, 0.05, 0.0, 0.2), front=1.25, left=3.0), 0.02)
    assert v.vx_m_s == pytest.approx(0.2) and v.vy_m_s == pytest.approx(0.05) and v.yaw_rate_rad_s == 0.2
    side = AttenuatedGo(P).update(_in(SpeedCommand(0.0, 0.3, 0.0, 0.0), front=1.0, left=3.0), 0.02)
    assert side.vy_m_s == pytest.approx(0.3)  # sliding along the wall: seen by the left beam


def test_a_diagonal_push_between_the_beams_flies_only_its_sensed_axis_near_a_wall():
    # GIVEN a diagonal stick (40 deg: outside the +-15 deg beams) 2 m from the front wall
    v = AttenuatedGo(P).update(_in(SpeedCommand(0.5, 0.42, 0.0, 0.0), front=2.0, left=4.0), 0.02)
    # THEN only the component along the axis nearer its direction (forward) is flown
    assert (v.vx_m_s, v.vy_m_s) == (pytest.approx(0.5), 0.0)
    # AND a 50 deg push flies sideways only, attenuated by the left wall it moves towards
    side = AttenuatedGo(P).update(_in(SpeedCommand(0.42, 0.5, 0.0, 0.0), front=2.0, left=1.25), 0.02)
    assert (side.vx_m_s, side.vy_m_s) == (0.0, pytest.approx(0.25))
    # AND far from walls, or within a beam, nothing changes
    free = AttenuatedGo(P).update(_in(SpeedCommand(0.5, 0.5, 0.0, 0.0), front=None, left=None), 0.02)
    assert (free.vx_m_s, free.vy_m_s) == (0.5, 0.5)
    far = AttenuatedGo(P).update(_in(SpeedCommand(0.5, 0.5, 0.0, 0.0), front=3.5, left=4.0), 0.02)
    assert (far.vx_m_s, far.vy_m_s) == (0.5, 0.5)
    near_axis = AttenuatedGo(P).update(_in(SpeedCommand(0.5, 0.1, 0.0, 0.0), front=2.0, left=4.0), 0.02)
    assert (near_axis.vx_m_s, near_axis.vy_m_s) == (0.5, 0.1)
    back = AttenuatedGo(P).update(_in(SpeedCommand(-0.4, 0, 0, 0), front=1.1), 0.02)
    assert back.vx_m_s == pytest.approx(-0.4)

def test_attenuated_go_stops_descents_near_the_floor():
    v = AttenuatedGo(P).update(_in(SpeedCommand(0, 0, -0.5, 0), down=P.floor_clearance_m), 0.02)
    assert v.vz_m_s == 0.0


def test_attenuated_inspect_fixes_speed_and_ignores_longitudinal_and_yaw():
    v = AttenuatedInspect(P).update(_in(SpeedCommand(0.8, 0.07, -0.9, 0.5)), 0.02)
    assert (v.vx_m_s, v.vy_m_s, v.vz_m_s, v.yaw_rate_rad_s) == (0.0, 0.2, -0.2, 0.0)
    still = AttenuatedInspect(P).update(_in(SpeedCommand(0.0, 0.03, 0.0, 0.0)), 0.02)
    assert still.vy_m_s == 0.0  # inside the dead band: hover


def test_waiting_for_connectivity_hovers_only_without_link():
    assert WaitingForConnectivity().update(_in(link=True), 0.02) is None
    v = WaitingForConnectivity().update(_in(SpeedCommand(0.4), link=False), 0.02)
    assert v.to_command().is_zero()


def test_prevent_collision_repulsion_grows_with_proximity_and_is_capped():
    pc = PreventCollision(P)
    v09 = pc.update(_in(front=0.9), 0.02).vx_m_s
    v06 = pc.update(_in(front=0.6), 0.02).vx_m_s
    v01 = pc.update(_in(front=0.1), 0.02).vx_m_s
    assert v09 < 0 and v06 < v09 and v01 == -P.hold_speed_max_m_s
    assert pc.update(_in(front=3.0, vx=0.4), 0.02) is None
    side = pc.update(_in(left=0.8, right=0.9), 0.02)
    assert side.vy_m_s == pytest.approx(-P.position_gain_1_s * 0.2 + P.position_gain_1_s * 0.1)


def test_prevent_collision_holds_without_repulsion_inside_the_dead_band():
    pc = PreventCollision(P)
    # a few centimetres inside the line: hold (0), not a never-ending creep backwards
    assert pc.update(_in(front=P.safe_distance_m - 0.5 * P.repulsion_deadband_m), 0.02).vx_m_s == 0.0
    deeper = pc.update(_in(front=P.safe_distance_m - P.repulsion_deadband_m - 0.1), 0.02).vx_m_s
    assert deeper == pytest.approx(-P.position_gain_1_s * 0.1)


def test_the_dead_band_holds_only_a_vehicle_not_moving_in():
    pc = PreventCollision(P)
    d = P.safe_distance_m - 0.04  # 4 cm inside the line, within the 5 cm hold band
    # GIVEN a vehicle at rest (or backing out) there: hold
    assert pc.update(_in(front=d, vx=0.0), 0.02).vx_m_s == 0.0
    assert pc.update(_in(front=d, vx=-0.05), 0.02).vx_m_s == 0.0
    # GIVEN one still creeping in at 0.05 m/s (a trim left from the approach): pushed back from the line
    assert pc.update(_in(front=d, vx=0.05), 0.02).vx_m_s == pytest.approx(-P.position_gain_1_s * 0.04)
    # the same for a side wall (moving right, towards it)
    assert pc.update(_in(right=d, vy=-0.05), 0.02).vy_m_s == pytest.approx(P.position_gain_1_s * 0.04)
    # AND with the link lost the wider band holds whatever the speed (hover first)
    assert pc.update(_in(front=d, vx=0.05, link=False), 0.02).vx_m_s == 0.0


def test_prevent_collision_stops_every_axis_when_an_oblique_surface_closes_in():
    import dataclasses

    pc = PreventCollision(P)
    base = _in(left=1.2, vx=0.5)  # moving forward; the left sonar sees a wall at 1.2 m
    # the left range holds still: a wall parallel to the motion, nothing to do
    still = dataclasses.replace(base, clearance=Clearance(left_m=1.2, down_m=1.5, left_closing_m_s=0.0))
    assert pc.update(still, 0.02) is None
    # the left range closes at 0.5 m/s with no lateral speed: the wall is oblique, forward motion
    # closes it, and the stop would end inside 1 m: stop X and Y
    closing = dataclasses.replace(base, clearance=Clearance(left_m=1.2, down_m=1.5, left_closing_m_s=0.5))
    v = pc.update(closing, 0.02)
    assert (v.vx_m_s, v.vy_m_s) == (0.0, 0.0)
    # far enough to stop in time: no action yet
    far = dataclasses.replace(base, clearance=Clearance(left_m=2.5, down_m=1.5, left_closing_m_s=0.5))
    assert pc.update(far, 0.02) is None


def test_prevent_collision_bounds_only_the_speed_towards_the_obstacle():
    pc = PreventCollision(P)
    # held inside the dead band at the right wall, the operator escapes left at 0.4 m/s: allowed
    assert pc.update(_in(SpeedCommand(0.0, 0.4), right=0.97), 0.02).vy_m_s == pytest.approx(0.4)
    # pushing into it: still held
    assert pc.update(_in(SpeedCommand(0.0, -0.4), right=0.97), 0.02).vy_m_s == 0.0
    # deeper: the repulsion, or the operator's faster retreat from the front wall
    assert pc.update(_in(SpeedCommand(0.0, 0.0), right=0.7), 0.02).vy_m_s > 0.0
    assert pc.update(_in(SpeedCommand(-0.5), front=0.8), 0.02).vx_m_s == pytest.approx(-0.5)


def test_prevent_collision_brakes_when_the_stop_would_breach_the_safe_distance():
    pc = PreventCollision(P)
    # 1.4 m away at 1 m/s: the stop point is 1.4 - 0.3 - 0.42 < 1 m, so brake now
    assert pc.update(_in(front=1.4, vx=1.0), 0.02).vx_m_s == 0.0
    assert pc.update(_in(front=1.4, vx=0.1), 0.02) is None


def test_go_ahead_latches_releases_on_new_stick_and_on_obstacle():
    g = GoAhead(P)
    assert g.update(_in(SpeedCommand(0.4), front=4.0, go=True), 0.02).vx_m_s == 0.4
    assert g.update(_in(SpeedCommand(), front=4.0, vx=0.4), 0.02).vx_m_s == 0.4  # stick released
    assert g.update(_in(SpeedCommand(0.0, 0.3), front=4.0, vx=0.4), 0.02) is None  # new desired speed
    g.update(_in(SpeedCommand(0.4), front=4.0, go=True), 0.02)
    # wall ahead: 1.15 m at 0.4 m/s, the stop point 1.15 - 0.4 * 0.3 - 0.4^2 / 2.4 is inside 1 m
    assert g.update(_in(SpeedCommand(), front=1.15, vx=0.4), 0.02) is None


def test_limit_max_height_attracts_down_only_near_the_ceiling():
    lm = LimitMaxHeight(P)
    assert lm.update(_in(alt=5.0), 0.02) is None
    v = lm.update(_in(alt=P.max_height_m - 0.2), 0.02)
    assert v.vz_m_s < 0 and v.vx_m_s is None


def test_ensure_reference_surface_detection_pulls_back_into_range():
    er = EnsureReferenceSurfaceDetection(P)
    assert er.update(_in(down=3.0), 0.02) is None
    assert er.update(_in(down=5.5, alt=5.5), 0.02).vz_m_s < 0  # no wall in range: go down
    assert er.update(_in(down=6.0, alt=6.0, front=2.0), 0.02) is None  # the wall is a reference
    assert er.update(_in(down=6.0, alt=6.0, front=4.4), 0.02).vx_m_s > 0  # keep the wall in range


def test_low_battery_land_latches():
    lb = LowBatteryLand(P)
    assert lb.viable(_in(battery=50))
    assert not lb.viable(_in(battery=19.9))
    assert not lb.viable(_in(battery=50))


def test_mav_behaviors_toggles_inspection_mode_and_reports_contributors():
    node = MAVBehaviors(P)
    est = StateEstimate(1.5, 1.5, 0.0, 0.0, 0.0, EstimationMode.BOTTOM_FRONT)
    op = OperatorInput(SpeedCommand(0.5, 0.5, 0.0, 0.3), frozenset({Button.INSPECTION_MODE_ON}))
    out = node.update(0.0, est, Clearance(front_m=0.9), op, battery_percent=90, flying=True, dt=0.02)
    assert node.inspection_mode
    assert out.command.vx_m_s < 0  # repulsion only: the longitudinal stick is ignored
    assert out.command.vy_m_s == pytest.approx(0.2) and out.command.yaw_rate_rad_s == 0.0
    assert out.behaviors == ("prevent_collision", "attenuated_inspect")
    assert not out.land_request


def test_waiting_for_connectivity_brakes_to_rest_then_holds_where_it_stopped():
    import dataclasses

    wfc = WaitingForConnectivity(P)
    # GIVEN the link is lost while the vehicle still moves at 0.6 m/s (odometry at x = 2.0)
    moving = _in(link=False, vx=0.6)
    moving = dataclasses.replace(moving, estimate=dataclasses.replace(moving.estimate, odometry=(2.0, 0.0, 0.0)))
    # THEN it commands a plain hover, it does not yet pick a point to hold
    assert wfc.update(moving, 0.02).to_command().is_zero()
    # WHEN it has braked to rest at x = 2.3 and is then pushed (a gust) to x = 2.4
    rest = dataclasses.replace(moving, estimate=dataclasses.replace(moving.estimate, vx_m_s=0.02, odometry=(2.3, 0.0, 0.0)))
    assert wfc.update(rest, 0.02).to_command().is_zero()
    pushed = dataclasses.replace(rest, estimate=dataclasses.replace(rest.estimate, odometry=(2.4, 0.0, 0.0)))
    v = wfc.update(pushed, 0.02)
    # THEN it flies back towards the rest point, not towards where the loss was detected
    assert v.vx_m_s == pytest.approx(-P.position_gain_1_s * 0.1)


def test_waiting_for_connectivity_in_an_alarm_mode_is_the_papers_hover_and_forgets_its_point():
    import dataclasses

    wfc = WaitingForConnectivity(P)
    # GIVEN the link lost and the vehicle holding the point where it came to rest (x = 2.3)
    rest = _in(link=False, vx=0.02)
    rest = dataclasses.replace(rest, estimate=dataclasses.replace(rest.estimate, odometry=(2.3, 0.0, 0.0)))
    assert wfc.update(rest, 0.02).to_command().is_zero()
    # WHEN every range sensor is lost (mode -2: the odometry is the IMU's dead reckoning) and it reads 0.2 m off
    for mode in (EstimationMode.ALARM_NONE, EstimationMode.ALARM_TOF):
        blind = dataclasses.replace(rest, estimate=dataclasses.replace(rest.estimate, mode=mode, odometry=(2.5, 0.0, 0.0)))
        # THEN it commands a plain hover, not a chase of that reading
        assert wfc.update(blind, 0.02).to_command().is_zero()
    # AND once a speed is measured again it holds the point where it is then, not the one from before
    back = dataclasses.replace(rest, estimate=dataclasses.replace(rest.estimate, odometry=(2.5, 0.0, 0.0)))
    assert wfc.update(back, 0.02).to_command().is_zero()
    moved = dataclasses.replace(back, estimate=dataclasses.replace(back.estimate, odometry=(2.6, 0.0, 0.0)))
    assert wfc.update(moved, 0.02).vx_m_s == pytest.approx(-P.position_gain_1_s * 0.1)


def test_near_a_wall_the_station_keeping_is_bounded_not_cancelled_while_the_link_is_lost():
    import dataclasses

    from inspect_pipe.flight_stack.messages import OperatorInput

    node = MAVBehaviors(P)
    lost = OperatorInput(SpeedCommand(), frozenset(), link_ok=False)

    def tick(t, y, left_m):
        e = dataclasses.replace(StateEstimate(1.5, 1.5, 0.0, 0.0, 0.0, EstimationMode.BOTTOM_FRONT), odometry=(0.0, y, 0.0))
        return node.update(t, e, Clearance(left_m=left_m, down_m=1.5), lost, battery_percent=90, flying=True, dt=0.02)

    # GIVEN the link lost with the vehicle at rest 0.92 m from a wall on its left: a little inside the safe distance,
    # where prevent_collision holds (0 towards the wall) rather than backing away
    assert tick(0.0, 0.0, 0.92).command.vy_m_s == 0.0
    # WHEN a gust carries it 0.06 m towards the wall
    out = tick(0.02, 0.06, 0.86)
    # THEN the station keeping flies it back to its rest point, away from the wall (before 2026-11-28
    # prevent_collision bounded the absent operator's zero instead and cancelled the hold on that axis:
    # seed 83 e331 drifted 0.41 m in a 1 m/s gust, e1317 0.21 m)
    assert out.command.vy_m_s == pytest.approx(-P.position_gain_1_s * 0.06)
    # AND towards the wall the bound still holds: carried 0.06 m away from it, it does not close in again
    out = tick(0.04, -0.06, 0.98)
    assert out.command.vy_m_s <= 0.0 and "prevent_collision" in out.behaviors
