"""``doctor --sweep`` says what a real sweep still lacks for a report in ship terms, and what follows."""

from __future__ import annotations

import json

import cv2
import numpy as np
from typer.testing import CliRunner

from cli.main import app

PLAN = """format: inspect_pipe.survey_plan/1
vessel: {name: MV Example, imo: "9074729"}
survey: {type: annual survey, date: "2026-11-20"}
compartment: {name: Cargo hold No. 1}
hold: {aft_bulkhead_frame: 120, frame_spacing_m: 0.7}
wall: fore_transverse_bulkhead
"""


def _sweep(root, *, with_state: bool):
    (root / "images").mkdir(parents=True)
    K = [[500, 0, 31.5], [0, 500, 23.5], [0, 0, 1]]
    (root / "sweep.json").write_text(json.dumps({
        "format": "inspect_pipe.sweep/1", "software_version": "test", "image_format": "png", "time_base": "host_monotonic_s",
        "source": {"kind": "v4l2"}, "camera": {"width": 64, "height": 48, "K": K, "dist": [0, 0, 0, 0, 0], "note": "uncalibrated: 60° guess"},
        "cam_to_body": {"R": np.eye(3).tolist(), "t_m": [0.1, 0, 0]}, "survey": {}, "odometry_frame": "takeoff"}))
    lines = []
    for i in range(3):
        cv2.imwrite(str(root / f"images/{i:06d}.png"), np.full((48, 64, 3), 40 * i, np.uint8))
        state = {"t_s": 0.1 * i, "position_m": [0.1 * i, 0, 1.5], "dist_front_m": 1.5, "height_m": 1.5,
                 "velocity_m_s": [1, 0, 0], "est_mode": None, "fsm": "flying", "inspection_mode": None} if with_state else None
        lines.append(json.dumps({"index": i, "image": f"images/{i:06d}.png", "t_s": 0.1 * i, "exposure_s": 0.004, "state": state}))
    (root / "frames.jsonl").write_text("\n".join(lines) + "\n")
    return root


def test_doctor_names_every_missing_piece(tmp_path):
    sweep = _sweep(tmp_path / "s", with_state=False)
    r = CliRunner().invoke(app, ["doctor", "--sweep", str(sweep)])
    assert r.exit_code == 0, r.output
    out = r.output
    assert "no  calibration: uncalibrated" in out and "--camera camera.yaml" in out
    assert "no  vehicle state: none of 3 frames carries a vehicle position" in out
    assert "no  survey plan" in out and "--survey plan.yaml" in out
    assert "thing(s) to provide" in out


def test_doctor_with_a_plan_lacking_takeoff_and_breadth(tmp_path):
    sweep = _sweep(tmp_path / "s", with_state=True)
    plan = tmp_path / "plan.yaml"
    plan.write_text(PLAN)
    r = CliRunner().invoke(app, ["doctor", "--sweep", str(sweep), "--survey", str(plan)])
    assert r.exit_code == 0, r.output
    assert "ok  vehicle state: 3 of 3 frames carry a position (takeoff frame)" in r.output
    assert "ok  survey plan: MV Example, Cargo hold No. 1, fore transverse bulkhead" in r.output
    assert "no  take-off tie" in r.output
    assert "no  hold dimensions: the hold's length_m is needed" in r.output


def test_doctor_refuses_a_nonsense_plan_in_one_line(tmp_path):
    sweep = _sweep(tmp_path / "s", with_state=True)
    plan = tmp_path / "plan.yaml"
    plan.write_text(PLAN.replace("0.7}", "-0.7}"))
    r = CliRunner().invoke(app, ["doctor", "--sweep", str(sweep), "--survey", str(plan)])
    assert r.exit_code == 2
    assert f"{plan}: field 'hold.frame_spacing_m': -0.7" in r.output
    assert "Traceback" not in r.output


def test_a_plan_given_on_the_command_line_supplies_the_hold_dimensions(tmp_path):
    # the sweep stores no plan; the --survey plan has length and width: nothing is missing about the hold
    sweep = _sweep(tmp_path / "s", with_state=True)
    plan = tmp_path / "plan.yaml"
    plan.write_text(PLAN.replace("frame_spacing_m: 0.7}", "frame_spacing_m: 0.7, length_m: 20, width_m: 24}")
                    + "takeoff: {position_m: [19, 0, 0], heading_deg: 0}\n")
    r = CliRunner().invoke(app, ["doctor", "--sweep", str(sweep), "--survey", str(plan)])
    assert r.exit_code == 0, r.output
    assert "hold dimensions" not in r.output and "take-off tie" not in r.output


def test_doctor_checks_a_plan_on_its_own_and_refuses_a_sweep_without_readable_frames(tmp_path):
    # GIVEN a plan alone: it is judged (one line when good, the one-line error when not)
    plan = tmp_path / "plan.yaml"
    plan.write_text(PLAN)
    r = CliRunner().invoke(app, ["doctor", "--survey", str(plan)])
    assert r.exit_code == 0 and f"ok  survey plan {plan}: MV Example, Cargo hold No. 1, fore_transverse_bulkhead" in r.output
    plan.write_text(PLAN.replace("0.7}", "-0.7}"))
    r = CliRunner().invoke(app, ["doctor", "--survey", str(plan)])
    assert r.exit_code == 2 and "field 'hold.frame_spacing_m': -0.7" in r.output
    # AND a sweep whose images are gone is no sweep to judge (not "none of 0 frames carries a position")
    sweep = _sweep(tmp_path / "s", with_state=True)
    for p in (sweep / "images").iterdir():
        p.unlink()
    r = CliRunner().invoke(app, ["doctor", "--sweep", str(sweep)])
    assert r.exit_code == 2 and "frames.jsonl: no readable frames" in r.output and "missing" in r.output


def test_a_nan_in_a_frames_state_is_no_state_for_that_frame(tmp_path):
    # GIVEN a sweep whose second frame's position is NaN (json writes NaN; a damaged log can hold one)
    from inspect_pipe.capture import read_sweep

    sweep = _sweep(tmp_path / "s", with_state=True)
    lines = (sweep / "frames.jsonl").read_text().splitlines()
    d = json.loads(lines[1])
    d["state"]["position_m"] = [float("nan"), 0.0, 1.5]
    lines[1] = json.dumps(d)
    (sweep / "frames.jsonl").write_text("\n".join(lines) + "\n")
    # THEN that frame carries no position (never a NaN into the mosaic's odometry), the others do
    sw = read_sweep(sweep)
    assert [f.position_m is None for f in sw.frames] == [False, True, False]
    r = CliRunner().invoke(app, ["doctor", "--sweep", str(sweep)])
    assert r.exit_code == 0 and "2 of 3 frames carry a position" in r.output
