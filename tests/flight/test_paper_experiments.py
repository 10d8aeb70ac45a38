"""The paper's experiments (Section IV) replayed in the simulated hold, with physical tolerances."""

from __future__ import annotations

import dataclasses
import math
import statistics
from pathlib import Path

import pytest

from inspect_pipe.flight import ExitStatus, load_scenario, run_scenario
from inspect_pipe.flight_stack import EstimationMode, FlightState


def _flying(ticks):
    return [r for r in ticks if r.out.fsm is FlightState.FLYING]


def test_fig6_top_attenuated_go_stops_at_one_metre_while_user_keeps_pushing(fly):
    # GIVEN the operator flying at 0.4 m/s towards the front wall and never letting go until t=19 s
    f = fly("fig6_top_attenuated_go")
    # WHEN the vehicle approaches the wall
    approach = [r for r in _flying(f.between(5.0, 19.0)) if r.out.user_cmd.vx_m_s > 0.39]
    # THEN the command equals the user's while the wall is far (before A)
    far = [r for r in approach if r.dist_true.front > 1.7]
    assert far and all(abs(r.out.command.vx_m_s - 0.4) < 1e-6 for r in far)
    # AND attenuation starts at 1.5 m (A)
    onset = next(r for r in approach if r.out.command.vx_m_s < 0.38)
    assert onset.dist_true.front == pytest.approx(1.5, abs=0.1)
    # AND the vehicle stops at the 1 m stop line, at most 0.1 m past it (B: within 3 cm of it,
    # the sonar's noise; the attenuation is linear in the distance, so the last centimetres are
    # an exponential approach of about 1.25 s)
    assert min(r.dist_true.front for r in f.ticks) >= 0.9
    b = next(r.t for r in _flying(f.between(10.0, 19.0)) if r.dist_true.front <= 1.03)
    assert b <= 18.5
    rest = f.between(b, 19.0)
    assert statistics.fmean(r.dist_true.front for r in rest) == pytest.approx(1.0, abs=0.1)
    # AND the user command is kept (0.4 m/s) but ignored (B -> C)
    assert all(r.out.user_cmd.vx_m_s == pytest.approx(0.4) for r in rest)
    # (ignored: 5 % of the push on average; the line's few cm of sonar noise give up to 10 %)
    assert statistics.fmean(r.out.command.vx_m_s for r in rest) <= 0.02
    assert all(r.out.command.vx_m_s <= 0.04 for r in rest)
    assert all(abs(r.vel_true[0]) < 0.08 for r in f.between(17.0, 19.0))
    assert f.result.status is ExitStatus.COMPLETED


def test_stop_line_overshoot_at_one_metre_per_second_is_within_ten_centimetres(fly):
    # GIVEN the operator pushing forward at 1 m/s, 2.5 times the paper's speed
    f = fly("approach_1ms")
    # WHEN the vehicle reaches the wall THEN it really flew at 1 m/s on the way
    assert max(r.vel_true[0] for r in f.ticks) > 0.9
    # AND stops no more than 0.10 m past the 1 m stop line and rests near it
    assert min(r.dist_true.front for r in f.ticks) >= 0.9
    assert statistics.fmean(r.dist_true.front for r in f.between(13.0, 15.0)) == pytest.approx(1.0, abs=0.1)
    assert f.result.status is ExitStatus.COMPLETED


def test_fig6_bottom_go_ahead_keeps_speed_after_release_and_stops_at_one_metre(fly):
    # GIVEN 0.4 m/s, go_ahead pressed at t=6 s (D) and the stick released at t=7 s
    f = fly("fig6_bottom_go_ahead")
    # WHEN the stick is centred and the wall still far
    cruise = [r for r in f.between(7.5, 30.0) if r.dist_true.front > 2.0]
    # THEN the command stays at 0.4 m/s from go_ahead although the user asks for nothing
    assert cruise
    assert all(r.out.user_cmd.vx_m_s == 0.0 and r.out.command.vx_m_s == pytest.approx(0.4) for r in cruise)
    assert all("go_ahead" in r.out.behaviors for r in cruise)
    assert statistics.fmean(r.vel_true[0] for r in cruise[-50:]) == pytest.approx(0.4, abs=0.04)
    # AND prevent_collision cancels it at the wall (E): stop at 1 m, at most 0.1 m past
    assert min(r.dist_true.front for r in f.ticks) >= 0.9
    end = f.between(22.0, 24.0)
    assert statistics.fmean(r.dist_true.front for r in end) == pytest.approx(1.0, abs=0.1)
    assert all("go_ahead" not in r.out.behaviors for r in end)
    assert any("prevent_collision" in r.out.behaviors for r in f.ticks)


def test_prevent_collision_backs_off_to_the_safe_distance(fly):
    # GIVEN a take-off 0.7 m from the front wall, inside the 1 m safe distance
    f = fly("prevent_collision_backoff")
    # WHEN flying THEN prevent_collision produces a negative speed command (E -> F)
    repulsive = [r for r in f.ticks if "prevent_collision" in r.out.behaviors and r.out.command.vx_m_s < -0.05]
    assert repulsive
    # AND separates the vehicle from the wall until it is again at the safe distance (F)
    assert statistics.fmean(r.dist_true.front for r in f.between(10.0, 12.0)) == pytest.approx(1.0, abs=0.1)
    assert f.result.status is ExitStatus.COMPLETED


def test_fig7_inspection_mode_sweeps_at_fixed_speed_and_ignores_longitudinal_and_yaw(fly):
    # GIVEN a take-off 0.75 m from the front wall and 0.8 m from the left one, inspection mode
    # on at t=7 s, then lateral and vertical stick commands mixed with forward and yaw commands
    f = fly("fig7_inspection_sweep")
    # THEN repulsion separates the vehicle from both walls before inspection (C, D, E)
    pre = f.between(0.0, 7.0)
    assert any(r.out.command.vx_m_s < -0.05 and "prevent_collision" in r.out.behaviors for r in pre)
    assert any(r.out.command.vy_m_s < -0.05 and "prevent_collision" in r.out.behaviors for r in pre)
    assert f.at(7.0).dist_true.front >= 0.9 and f.at(7.0).dist_true.left >= 0.9
    inspecting = [r for r in f.between(7.5, 37.5)]
    assert all(r.inspection_mode for r in (x.out for x in inspecting))
    # AND the longitudinal and yaw commands are ignored (only repulsion may act on X)
    assert any(abs(r.out.user_cmd.vx_m_s) > 0.2 for r in inspecting)
    assert all(r.out.command.yaw_rate_rad_s == 0.0 for r in inspecting)
    assert all(r.out.command.vx_m_s <= 0.0 for r in inspecting)
    yaw0 = f.at(7.5).yaw_true
    assert max(abs(r.yaw_true - yaw0) for r in inspecting) < math.radians(2.0)
    # AND lateral and vertical speed is 0.2 +- 0.02 m/s, whatever the stick's amplitude
    for (t0, t1, axis, sign) in [(10.0, 15.5, 1, -1), (18.0, 20.5, 2, 1), (28.5, 30.5, 2, -1), (33.0, 35.5, 1, -1)]:
        v = statistics.fmean(r.vel_true[axis] for r in f.between(t0, t1))
        assert v == pytest.approx(0.2 * sign, abs=0.02), (t0, t1, axis)
    # AND it stays at the inspection distance and lands at the end
    assert min(r.dist_true.front for r in inspecting) >= 0.85
    assert f.result.final_fsm is FlightState.LANDED
    assert f.result.status is ExitStatus.COMPLETED


def test_fig7_inspection_passes_hold_the_paper_speed_across_seeds():
    # GIVEN the Fig. 7 sweep flown with 20 seeds (air disturbance, sensor and attitude errors
    # drawn anew for each), each lateral pass's mean true speed from 2 s after its command
    base = load_scenario(Path(__file__).resolve().parents[2] / "scenarios" / "fig7_inspection_sweep.yaml")
    errors = []
    for seed in range(321, 341):
        ticks = []
        run_scenario(dataclasses.replace(base, seed=seed), on_tick=ticks.append)
        for t0, t1 in ((10.0, 15.5), (23.0, 26.5), (33.0, 35.5)):
            errors.append(abs(statistics.fmean(r.vel_true[1] for r in ticks if t0 <= r.t <= t1)) - 0.2)
    # THEN the passes fly the inspection speed, 0.20 +- 0.01 m/s, with at most one of 60 off and
    # none by more than 0.015 (measured: none off, rms 0.0039; with the XY trim's ki 3 of
    # sessions 21-27: 3 of 60 off, rms 0.0051)
    assert sum(abs(e) > 0.01 for e in errors) <= 1
    assert max(abs(e) for e in errors) <= 0.015
    assert math.sqrt(statistics.fmean(e * e for e in errors)) < 0.0045


@pytest.mark.parametrize("mode", [0, 1, 2, 3])
def test_fig5_one_minute_hover_in_each_estimation_mode(fly, mode):
    # GIVEN a hover from t=6 s to t=66 s with the sensor set of Table I mode `mode`
    f = fly(f"fig5_hover_mode{mode}")
    hover = f.between(6.0, 66.0)
    # THEN the estimator is in that mode all along
    assert sum(int(r.out.estimate.mode) == mode for r in hover) >= 0.98 * len(hover)
    # AND the velocity histograms are centred on zero
    for axis in ("vx_m_s", "vy_m_s", "vz_m_s"):
        est = [getattr(r.out.estimate, axis) for r in hover]
        assert abs(statistics.fmean(est)) < 0.02, axis
        assert abs(statistics.median(est)) < 0.02, axis
    for k in range(3):
        assert abs(statistics.fmean(r.vel_true[k] for r in hover)) < 0.02
    # AND the horizontal drift is at most 0.25 m RMS
    x0, y0 = hover[0].pos_true[0], hover[0].pos_true[1]
    drift = math.sqrt(statistics.fmean((r.pos_true[0] - x0) ** 2 + (r.pos_true[1] - y0) ** 2 for r in hover))
    assert drift <= 0.25
    assert f.result.status is ExitStatus.COMPLETED


def test_table1_each_mode_reached_by_its_sensor_set_and_alarm_descends_to_landing(fly):
    # GIVEN sensors switched off in turn while hovering 2.5 m from the front wall
    f = fly("table1_modes")
    # THEN each window shows the mode of Table I for the sensors left
    for (t0, t1, mode) in [(4.0, 8.0, 1), (9.0, 13.0, 0), (14.0, 18.0, 2), (19.0, 23.0, 3)]:
        w = f.between(t0, t1)
        assert all(r.out.estimate.mode == mode for r in w), (t0, t1, mode)
    # AND with only the TeraRanger left (mode -1) the vehicle descends and lands
    alarm = f.between(24.0, 34.0)
    assert alarm[0].out.estimate.mode == EstimationMode.ALARM_TOF
    assert f.at(24.0).pos_true[2] - min(r.pos_true[2] for r in alarm) > 0.8
    assert f.result.final_fsm is FlightState.LANDED
    assert f.result.status is ExitStatus.COMPLETED


def test_alarm_mode_minus_two_descends_and_lands_without_crashing(fly):
    # GIVEN a hover at about 3 m when every reference sensor goes silent at t=9 s
    f = fly("alarm_none_descent")
    alarm = f.between(9.5, 28.0)
    assert any(r.out.estimate.mode == EstimationMode.ALARM_NONE for r in alarm)
    # THEN the filled state makes the vehicle descend (1 m within 8 s), then it lands softly
    assert f.at(9.0).pos_true[2] - f.at(17.0).pos_true[2] > 1.0
    assert max(-r.vel_true[2] for r in alarm) < 1.0
    assert f.result.final_fsm is FlightState.LANDED
    assert f.result.status is ExitStatus.COMPLETED


def test_a_stuck_teraranger_in_mode_minus_one_is_dropped_and_the_vehicle_lands_softly(fly):
    # GIVEN a hover at about 2.5 m on the TeraRanger alone (mode -1) when it sticks at t=10 s
    f = fly("alarm_stuck_teraranger")
    assert f.at(9.8).out.estimate.mode == EstimationMode.ALARM_TOF
    stuck = f.between(10.0, 34.0)
    # THEN within 1.5 s the repeated reading no longer counts (mode -2: no height reference)
    first = next(r for r in stuck if r.out.estimate.mode == EstimationMode.ALARM_NONE)
    assert first.t <= 11.5
    # AND the vehicle descends at the alarm's pace, never falling (1.47 m/s into the floor before)
    assert max(-r.vel_true[2] for r in stuck) < 0.5
    assert f.result.final_fsm is FlightState.LANDED
    assert f.result.status is ExitStatus.COMPLETED


def test_vibration_spikes_in_mode_minus_two_high_above_the_floor_are_not_a_touchdown(fly):
    # GIVEN every range sensor lost at about 2 m (mode -2) and a vibration fault 0.5 s later
    f = fly("alarm_none_vibration")
    blind = f.between(9.2, 12.0)
    assert all(r.out.estimate.mode == EstimationMode.ALARM_NONE for r in blind)
    # THEN no touchdown is taken from the spikes: no landing, no fall (4 m/s before)
    assert all(r.out.fsm is FlightState.FLYING for r in f.between(9.0, 16.0))
    assert max(-r.vel_true[2] for r in f.between(9.0, 16.0)) < 0.6
    assert f.result.status is ExitStatus.COMPLETED


def test_floor_box_overflight_keeps_altitude_while_height_steps_with_the_floor(fly):
    # GIVEN a flight at 1.5 m over a 1 m box
    f = fly("floor_box_overflight")
    cruise = f.between(9.0, 27.0)
    z_ref = statistics.fmean(r.pos_true[2] for r in f.between(8.0, 9.0))
    assert z_ref == pytest.approx(1.5, abs=0.15)
    over = [r for r in cruise if 4.9 <= r.pos_true[0] <= 6.1]
    assert len(over) > 50
    # THEN the height estimate steps with the floor (0.5 m above the box)
    assert statistics.fmean(r.out.estimate.height_m for r in over) == pytest.approx(z_ref - 1.0, abs=0.15)
    # AND the vehicle neither climbs nor dives: altitude excursion at most 0.15 m
    assert max(abs(r.pos_true[2] - z_ref) for r in cruise) <= 0.15
    assert f.result.status is ExitStatus.COMPLETED


def test_link_loss_hovers_within_0_3_s_of_the_last_operator_message(fly):
    # GIVEN flying forward at 0.4 m/s when the link drops from t=8 s to t=11 s
    f = fly("link_loss")
    # THEN within 0.3 s of the last message waiting_for_connectivity takes over with a hover command
    first = next(r for r in f.between(8.0, 11.0) if not r.link_ok)
    assert first.t <= 8.3 and first.out.command.vx_m_s == 0.0
    lost = f.between(first.t, 11.0)
    assert all(not r.link_ok and "waiting_for_connectivity" in r.out.behaviors for r in lost)
    # AND it holds station where it came to rest: the stop from 0.4 m/s carries it less than
    # 0.15 m on, and from rest on it stays within 3 cm
    x0 = first.pos_true[0]
    assert max(abs(r.pos_true[0] - x0) for r in lost) < 0.15
    rest = next(i for i, r in enumerate(lost) if abs(r.vel_true[0]) < 0.1)
    x_rest = lost[rest].pos_true[0]
    assert max(abs(r.pos_true[0] - x_rest) for r in lost[rest:]) < 0.03
    assert all(abs(r.vel_true[0]) < 0.1 for r in f.between(9.8, 11.0))
    # AND obeys the stick again once the link is back
    assert all(r.out.command.vx_m_s == pytest.approx(0.4) for r in f.between(11.4, 13.0))


def test_low_battery_descends_and_lands(fly):
    # GIVEN a battery that reaches 20 % in flight
    f = fly("low_battery")
    states = [r.out.fsm for r in f.ticks]
    first_descent = states.index(FlightState.DESCENDING)
    # THEN low_battery_land starts the descent at the threshold, and the vehicle lands
    assert f.ticks[first_descent].battery_percent <= 20.0 + 0.1
    assert "low_battery_land" in f.ticks[first_descent].out.behaviors
    after = states[first_descent:]
    assert FlightState.LANDING in after and after[-1] is FlightState.LANDED
    assert FlightState.FLYING not in after
    assert f.ticks[-1].pos_true[2] < 0.1
    assert f.result.status is ExitStatus.COMPLETED


def test_max_height_is_never_exceeded_and_tof_takes_over_above_five_metres(fly):
    # GIVEN an operator who keeps climbing for 18 s with a 7 m ceiling
    f = fly("max_height")
    # THEN the vehicle never goes above it
    assert max(r.pos_true[2] for r in f.ticks) <= 7.0
    assert max(r.pos_true[2] for r in f.ticks) >= 6.0
    assert any("limit_max_height" in r.out.behaviors for r in f.ticks)
    # AND above the bottom sonar's 5 m the estimator is in mode 2 (TeraRanger height)
    high = [r for r in f.ticks if r.pos_true[2] > 5.3]
    assert high and all(r.out.estimate.mode == EstimationMode.TOF_FRONT for r in high)
    assert f.result.status is ExitStatus.COMPLETED
