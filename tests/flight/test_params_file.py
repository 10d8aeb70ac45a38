"""Bad input to ``inspect-pipe fly`` (issue 19): a parameter file outside its bounds, a scenario
with an unknown fault, sensor or wall: one line naming the file and the field, exit 2, no log."""

from __future__ import annotations

import json
import statistics

import pytest
import yaml
from typer.testing import CliRunner

from cli.main import app
from inspect_pipe.errors import InputError
from inspect_pipe.flight import parse_scenario, run_scenario
from inspect_pipe.flight_stack.params import load_params

BASE = {
    "format": "inspect_pipe.scenario/1", "name": "p", "duration_s": 3, "seed": 1,
    "world": {"hold": {"length_m": 12, "width_m": 10, "height_m": 8}},
    "vehicle": {"start": {"position": [2.0, 0, 0]}},
    "operator": [{"t": 0.5, "button": "takeoff"}],
}


def _fly(tmp_path, scenario: dict, params: dict | str | None = None):
    sc = tmp_path / "s.yaml"
    sc.write_text(yaml.safe_dump(scenario))
    args = ["fly", "--scenario", str(sc), "--log", str(tmp_path / "log.jsonl")]
    if params is not None:
        pf = tmp_path / "p.yaml"
        pf.write_text(params if isinstance(params, str) else yaml.safe_dump(params))
        args += ["--params", str(pf)]
    return CliRunner().invoke(app, args)


@pytest.mark.parametrize("params, field", [
    ({"control": {"speed_kp_1_s": 25.0}}, "control.speed_kp_1_s"),  # bounds [0, 20]
    ({"estimation": {"flow_min_quality": -3}}, "estimation.flow_min_quality"),
    ({"control": {"no_such_gain": 1.0}}, "control.no_such_gain"),
    ({"guidance": {"x": 1.0}}, "guidance"),
    ({"control": {"speed_kp_1_s": "fast"}}, "control.speed_kp_1_s"),
])
def test_a_parameter_file_outside_its_bounds_is_one_line_exit_2(tmp_path, params, field):
    res = _fly(tmp_path, BASE, params)
    assert res.exit_code == 2
    lines = [line for line in res.output.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and "p.yaml" in lines[0] and field in lines[0], res.output
    assert "Traceback" not in res.output
    assert not (tmp_path / "log.jsonl").exists()


def test_a_valid_parameter_file_reaches_the_stack(tmp_path):
    p = tmp_path / "ok.yaml"
    p.write_text(yaml.safe_dump({"behaviors": {"safe_distance_m": 1.5}}))
    assert load_params(p).behaviors.safe_distance_m == 1.5
    res = _fly(tmp_path, BASE, {"behaviors": {"safe_distance_m": 1.5}})
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "log.jsonl").read_text().splitlines()[-1])["t"] == 3.0
    with pytest.raises(InputError, match="not found"):
        load_params(tmp_path / "missing.yaml")


@pytest.mark.parametrize("change, field", [
    ({"faults": [{"t": 1, "duration_s": 1, "fault": "solar_flare"}]}, "faults[0].fault"),
    ({"faults": [{"t": 1, "duration_s": 1, "fault": "low_texture", "sensor": "left_sonar", "rate": 0.5}]}, "faults[0].sensor"),
    ({"faults": [{"t": 1, "duration_s": 1, "fault": "sensor_dropout", "sensor": "rear_lidar"}]}, "faults[0].sensor"),
    ({"faults": [{"t": 1, "duration_s": 1, "fault": "weak_motor"}]}, "faults[0].rate"),
    ({"world": {"hold": {"length_m": 12, "width_m": 10, "height_m": 8},
                "wall_textures": {"ceiling": {"image": "x.png", "m_per_px": 0.01}}}}, "wall_textures"),
])
def test_a_scenario_with_an_unknown_fault_sensor_or_wall_is_one_line_exit_2(tmp_path, change, field):
    res = _fly(tmp_path, {**BASE, **change})
    assert res.exit_code == 2
    lines = [line for line in res.output.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and field in lines[0], res.output
    assert not (tmp_path / "log.jsonl").exists()


def test_steady_one_metre_per_second_is_tracked_within_five_percent():
    # GIVEN a 1 m/s forward command held in a 40 m hold WHEN steady (9-15 s after the command)
    doc = {**BASE, "name": "track", "duration_s": 21, "seed": 11,
           "world": {"hold": {"length_m": 40, "width_m": 10, "height_m": 8}},
           "operator": [{"t": 0.5, "button": "takeoff"}, {"t": 5.0, "stick": {"vx": 1.0}}]}
    ticks = []
    run_scenario(parse_scenario(doc), on_tick=ticks.append)
    steady = [t.vel_true[0] for t in ticks if 14.0 <= t.t <= 20.0]
    # THEN the true speed is the command within 5 % (it ran 5-10 % low with the leaking integrators)
    assert statistics.fmean(steady) == pytest.approx(1.0, rel=0.05)


def test_inspection_mode_sweeps_laterally_and_vertically_at_the_paper_speed_within_a_hundredth(fly):
    # GIVEN the Fig. 7 sweep (inspection mode, 0.2 m/s whatever the stick's amplitude)
    f = fly("fig7_inspection_sweep")
    # THEN the lateral passes fly 0.20 +- 0.01 m/s (0.188 / 0.190 before the observers' band)
    for t0, t1 in ((10.0, 15.5), (33.0, 35.5)):
        v = statistics.fmean(r.vel_true[1] for r in f.between(t0, t1))
        assert v == pytest.approx(-0.2, abs=0.01), (t0, t1)
    # AND the vertical ones too, from 2 s after the stick (0.201 / 0.218 while the height loop's
    # last output was handed over as trim and the speed integrator took the command's steps)
    for t0, t1, sign in ((18.0, 20.5, 1), (28.5, 30.5, -1)):
        v = statistics.fmean(r.vel_true[2] for r in f.between(t0, t1))
        assert v == pytest.approx(0.2 * sign, abs=0.01), (t0, t1)


def test_every_parameter_is_declared_with_unit_bounds_and_a_reason():
    from inspect_pipe.flight_stack.params import describe

    rows = describe()
    # Issue 19 aims at half of 98 (101 before session 10); at least no more than today: 94 after
    # session 18, 89 since session 21 merged five that held the same value for the same role (session
    # 22 added the observers' noise sigma and merged the vertical speed loop's integral gain with the XY one;
    # 88 since session 28 split that gain again and moved the two range sensors' delays to constants;
    # 89 since session 29 weighs a PX4Flow reading by its quality as EKF2 does, EKF2_OF_N_MAX's analogue;
    # 84 since session 30 dropped the vertical integrator's fast unwinding, which the reference-model
    # integration and the disturbance observers running to touchdown had made idle, counts one stuck
    # reading for flows and range sensors alike, and has every position hold use position_gain_1_s;
    # 85 since session 32 leaves the speed loops' error within the IMU's noise alone in the alarm
    # modes, carried_noise_sigma: docs/flight.md).
    assert len(rows) <= 85
    for name, value, lo, hi, unit, reason in rows:
        assert unit and lo <= value <= hi and len(reason) > 10, name
    # AND docs/flight.md states the count the code has
    from pathlib import Path

    doc = " ".join((Path(__file__).resolve().parents[2] / "docs" / "flight.md").read_text().split())
    assert f"reason ({len(rows)} of them" in doc


def test_inspection_passes_hold_the_paper_speed_on_other_seeds_against_the_air_disturbance():
    # GIVEN the Fig. 7 sweep flown with four seeds never used while tuning (the simulator's slowly
    # varying air disturbance differs with the seed; with ki 0.6 on the raw speed error 3 of these
    # 12 lateral passes missed 0.20 +- 0.01, one at 0.219 m/s)
    from pathlib import Path

    doc = yaml.safe_load((Path(__file__).resolve().parents[2] / "scenarios" / "fig7_inspection_sweep.yaml").read_text())
    lateral = []
    for seed in (233, 234, 235, 236):
        ticks = []
        run_scenario(parse_scenario({**doc, "seed": seed}), on_tick=ticks.append)
        for t0, t1 in ((10.0, 15.5), (23.0, 26.5), (33.0, 35.5)):
            lateral.append(abs(statistics.fmean(r.vel_true[1] for r in ticks if t0 <= r.t <= t1)))
    # THEN every lateral pass is within 0.02 of 0.20 m/s and at most one misses 0.01
    assert all(abs(v - 0.2) <= 0.02 for v in lateral), lateral
    assert sum(abs(v - 0.2) > 0.01 for v in lateral) <= 1, lateral
