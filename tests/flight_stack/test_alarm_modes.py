"""Alarm modes (-1, -2): no sensor measures the horizontal speed. The vehicle must still brake to a
stop rather than coast on at the speed it had (campaign seed 1, episode 183)."""

from __future__ import annotations

from pathlib import Path

import pytest

from inspect_pipe.flight import load_scenario, run_scenario
from inspect_pipe.flight_stack.estimation import MAVStateUpdater
from inspect_pipe.flight_stack.messages import EstimationMode, ImuReading, Measurements

SCENARIO = Path(__file__).resolve().parents[2] / "scenarios" / "regressions" / "campaign_range_loss_coast_e183.yaml"


def test_alarm_mode_carries_the_speed_with_the_imu():
    upd = MAVStateUpdater()
    upd.obs[0].v = 0.5  # moving forward at 0.5 m/s when the last reference sensor went silent
    est = None
    for k in range(0, 21):  # 0.4 s braking at 1 m/s^2
        est, _ = upd.update(k * 0.02, Measurements(imu=ImuReading.level(k * 0.02, -1.0, 0.0, 0.0)))
    assert est.mode == EstimationMode.ALARM_NONE
    assert est.vx_m_s == pytest.approx(0.1, abs=0.01)  # 0.5 - 0.4: the braking is seen
    for k in range(21, 400):  # coasting with no acceleration: the speed is carried on, not lost
        est, _ = upd.update(k * 0.02, Measurements(imu=ImuReading.level(k * 0.02, 0.0, 0.0, 0.0)))
    assert est.vx_m_s == pytest.approx(0.1, abs=0.01)


def test_range_loss_during_an_approach_brakes_instead_of_coasting_into_the_wall():
    # GIVEN every range sensor lost for 2.6 s at 1.65 m from the front wall, approaching at 0.5 m/s
    fronts = []
    run_scenario(load_scenario(SCENARIO), on_tick=lambda r: fronts.append((r.t, r.dist_true.front)))
    during = [f for t, f in fronts if 12.8 <= t <= 15.3]
    assert during
    # THEN the vehicle stops short of the wall (it coasted to 0.42 m before, still closing)
    assert min(during) > 0.9
