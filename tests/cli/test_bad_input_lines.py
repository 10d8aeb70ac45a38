"""Bad input a user could plausibly give, each answered by one line that names the right file (or
option) and what to do, exit 2: cases found by a sweep of every command with damaged inputs."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.main import app

FIX = Path(__file__).resolve().parents[1] / "fixtures"
runner = CliRunner()


def _line(args: list[str]) -> str:
    res = runner.invoke(app, args)
    assert res.exit_code == 2, res.output
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in res.output, res.output
    return lines[0]


def test_a_negative_spacing_in_a_frame_table_is_named(tmp_path):
    plan = tmp_path / "plan.yaml"
    plan.write_text(
        "format: inspect_pipe.survey_plan/1\n"
        "vessel: {name: MV Sim, imo: '9074729'}\n"
        "survey: {type: special survey, date: '2026-11-20', surveyor: B. S}\n"
        "compartment: {name: hold}\n"
        "hold: {aft_bulkhead_frame: 100, frame_spacing_m: [{from_frame: 100, spacing_m: 0.8}, {from_frame: 110, spacing_m: -0.7}]}\n"
        "wall: fore_transverse_bulkhead\n"
        "takeoff: {position_m: [10.5, 0.5, 0.0], heading_deg: 0}\n")
    line = _line(["doctor", "--survey", str(plan)])
    # the table's entry, not the other branch of the union ("should be a valid number")
    assert "hold.frame_spacing_m.1.spacing_m" in line and "-0.7" in line and "valid number" not in line


def test_a_model_file_that_is_not_a_model_says_what_to_give(tmp_path):
    fake = tmp_path / "fake.npz"
    fake.write_text("not a model")
    img = next((FIX / "defects").glob("*.jpg"))
    line = _line(["detect", str(img), "-o", str(tmp_path / "o"), "--engine", "saliency", "--model", str(fake)])
    assert str(fake) in line and "detect train" in line and not (tmp_path / "o").exists()


def test_a_file_where_the_output_folder_goes(tmp_path):
    taken = tmp_path / "taken"
    taken.write_text("x")
    line = _line(["mosaic", str(FIX / "mosaic" / "synth_rust_mini"), "-o", str(taken)])
    assert str(taken) in line and "a file is there" in line and taken.read_text() == "x"


def test_compare_given_a_sweep_says_to_run_it_first(tmp_path):
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    (sweep / "sweep.json").write_text("{}")
    line = _line(["compare", str(sweep), str(sweep), "-o", str(tmp_path / "c")])
    assert f"{sweep}: a sweep, not a run" in line and f"inspect-pipe run {sweep}" in line


def test_review_of_a_run_without_a_register_names_the_register_before_the_reviewer(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    line = _line(["review", str(run), "--port", "18799"])
    assert "report/defects.json: not found" in line and "--reviewer" not in line


@pytest.mark.parametrize("args, want", [
    (["--pattern", "charuco", "--board", "7x5", "--square-m", "0.04"], "missing: a ChArUco board needs the side of its markers"),
    (["--pattern", "charuco", "--board", "7x5", "--square-m", "0.04", "--marker-m", "0.05"], "0.05: a ChArUco marker must be smaller"),
])
def test_charuco_marker_side(tmp_path, args, want):
    shots = sorted((FIX / "calibration").glob("*.jpg"))[:3]
    line = _line(["calibrate", *map(str, shots), "-o", str(tmp_path / "cam.yaml"), *args])
    assert line.startswith(f"error: --marker-m: {want}")
