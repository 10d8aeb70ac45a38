"""``inspect-pipe fly``: log format, exit codes, determinism."""

from __future__ import annotations

import json

import yaml
from typer.testing import CliRunner

from cli.main import app
from inspect_pipe.flight import load_scenario, record_to_json, run_scenario

REQUIRED = {
    "t", "pos_true", "vel_true", "est", "est_mode", "fsm", "user_cmd", "cmd", "behaviors",
    "inspection_mode", "dist_true", "battery_percent", "link_ok", "collided", "imu", "att_est", "att_true",
}


def test_fly_writes_a_versioned_log_with_every_spec_field(tmp_path, scenarios_dir):
    log = tmp_path / "out" / "flight.jsonl"
    res = CliRunner().invoke(app, ["fly", "--scenario", str(scenarios_dir / "prevent_collision_backoff.yaml"), "--log", str(log)])
    assert res.exit_code == 0, res.output
    lines = log.read_text().splitlines()
    header = json.loads(lines[0])
    assert header["format"] == "inspect_pipe.flight_log/1"
    assert header["scenario"] == "prevent_collision_backoff" and header["tick_hz"] == 50.0
    ticks = [json.loads(line) for line in lines[1:]]
    assert len(ticks) == 12 * 50 + 1
    assert all(REQUIRED <= t.keys() for t in ticks)
    assert set(ticks[-1]["est"]) >= {"height", "vx", "vy", "vz"}
    assert set(ticks[-1]["dist_true"]) == {"front", "back", "left", "right", "down"}
    assert {t["fsm"] for t in ticks} >= {"landed", "taking_off", "flying"}
    assert ticks[-1]["est_mode"] in (0, 1, 2, 3, -1, -2)
    # the IMU's specific force (body frame: +g up when level) and both attitudes (issue 19)
    assert set(ticks[-1]["imu"]) == {"ax", "ay", "az"} and 8.0 < ticks[-1]["imu"]["az"] < 11.5
    assert set(ticks[-1]["att_est"]) == set(ticks[-1]["att_true"]) == {"roll", "pitch"}


def test_flying_backwards_into_the_wall_is_a_collision_exit_1(tmp_path):
    # GIVEN no sensor looks backwards and the operator flies back into the back wall
    doc = {
        "format": "inspect_pipe.scenario/1", "name": "reverse_crash", "duration_s": 9, "seed": 2,
        "world": {"hold": {"length_m": 12, "width_m": 10, "height_m": 16}},
        "vehicle": {"start": {"position": [1.5, 0, 0]}},
        "operator": [{"t": 0.5, "button": "takeoff"}, {"t": 3.0, "stick": {"vx": -0.6}}],
    }
    sc = tmp_path / "crash.yaml"
    sc.write_text(yaml.safe_dump(doc))
    log = tmp_path / "crash.jsonl"
    res = CliRunner().invoke(app, ["fly", "--scenario", str(sc), "--log", str(log)])
    assert res.exit_code == 1
    last = json.loads(log.read_text().splitlines()[-1])
    assert last["collided"] is True and last["dist_true"]["back"] < 0.35


def test_bad_scenario_is_exit_2_with_one_line(tmp_path):
    sc = tmp_path / "bad.yaml"
    sc.write_text(yaml.safe_dump({"format": "inspect_pipe.scenario/1", "name": "x", "duration_s": 5,
                                  "world": {"hold": {"length_m": 12, "width_m": 10, "height_m": 16}},
                                  "vehicle": {"start": {"position": [2, 0, 0]}},
                                  "operator": [{"t": 1, "button": "barrel_roll"}]}))
    res = CliRunner().invoke(app, ["fly", "--scenario", str(sc), "--log", str(tmp_path / "l.jsonl")])
    assert res.exit_code == 2
    out = res.output.strip()
    assert out.count("\n") == 0 and "operator[0].button" in out and "bad.yaml" in out
    assert "Traceback" not in res.output


def test_same_seed_same_flight(scenarios_dir):
    sc = load_scenario(scenarios_dir / "prevent_collision_backoff.yaml")
    a, b = [], []
    run_scenario(sc, on_tick=lambda r: a.append(record_to_json(r)))
    run_scenario(sc, on_tick=lambda r: b.append(record_to_json(r)))
    assert a == b
