"""The pipeline on a real folder of frames: resume by artifact presence, --force, --rerun-from,
changed options, and the run command's bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.main import app
from inspect_pipe.pipeline import STEP_NAMES, RunStore, plan, run_pipeline
from inspect_pipe.pipeline._steps import DetectConfig, RunConfig

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "mosaic" / "synth_rust_mini"
runner = CliRunner()


def _cfg(src: Path, **report) -> RunConfig:
    return RunConfig(input=str(src), focal_px=618.0, detect=DetectConfig(keyframe_spacing=0.0),
                     report={"m_per_px": 0.002, "pdf": False, **report})


@pytest.fixture(scope="module")
def done_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("pipe")
    src = root / "frames"
    shutil.copytree(FIXTURE, src)
    out = run_pipeline(root / "run", _cfg(src), log=lambda s: None)
    return root, src, out


def test_first_run_runs_every_step_and_writes_the_report(done_run):
    root, src, out = done_run
    assert [(s.name, s.action) for s in out.steps] == [("capture", "not needed"), ("mosaic", "ran"), ("detect", "ran"), ("report", "ran")]
    store = RunStore(root / "run")
    assert store.mosaic_exists() and store.detect_exists() and store.report_exists()
    doc = json.loads((store.report_dir / "defects.json").read_text())
    assert doc["format"] == "inspect_pipe.defect_register/1" and doc["defects"], "the rusty fixture has defects"
    assert all(d["area_m2"] > 0 and len(d["centroid_wall_m"]) == 2 for d in doc["defects"])
    run = json.loads(store.run_json.read_text())
    assert set(run["steps"]) == {"mosaic", "detect", "report"}


def test_second_run_skips_finished_steps(done_run):
    root, src, _ = done_run
    logs = []
    out = run_pipeline(root / "run", _cfg(src), log=logs.append)
    assert [s.action for s in out.steps[1:]] == ["skipped"] * 3
    assert any("mosaic: skipped" in line for line in logs)


def test_changed_report_option_reruns_only_the_report(done_run):
    root, src, _ = done_run
    store = RunStore(root / "run")
    steps = plan(store, _cfg(src, rating={"scheme": "MSC.1/Circ.1399"}))
    assert [a for _, a, _ in steps] == ["n/a", "skip", "skip", "run"]
    assert steps[3][2] == "options changed"


def test_rerun_from_and_force_and_missing_output(done_run):
    root, src, _ = done_run
    store = RunStore(root / "run")
    assert [a for _, a, _ in plan(store, _cfg(src), rerun_from="detect")] == ["n/a", "skip", "run", "run"]
    assert [a for _, a, _ in plan(store, _cfg(src), force=True)] == ["n/a", "run", "run", "run"]
    # GIVEN the detections deleted THEN detect and everything after it run again
    saved = (store.detect_dir / "defects.json").read_bytes()
    (store.detect_dir / "defects.json").unlink()
    try:
        steps = plan(store, _cfg(src))
        assert [a for _, a, _ in steps] == ["n/a", "skip", "run", "run"] and steps[2][2] == "output missing"
    finally:
        (store.detect_dir / "defects.json").write_bytes(saved)


def test_run_command_bad_input(tmp_path):
    res = runner.invoke(app, ["run", str(tmp_path / "nope"), "-o", str(tmp_path / "o")])
    assert res.exit_code == 2 and "nope: not found" in res.output
    assert not (tmp_path / "o").exists()
    res = runner.invoke(app, ["run", str(FIXTURE), "-o", str(tmp_path / "o"), "--rerun-from", "paint"])
    assert res.exit_code == 2 and "'paint' is not a step" in res.output
    assert STEP_NAMES == ("capture", "mosaic", "detect", "report")


def test_run_many_without_dask_and_with_a_local_cluster(tmp_path, done_run):
    from inspect_pipe.pipeline import run_many

    root, src, _ = done_run
    # two run directories copied from the finished one: every step is skipped, so this tests the
    # fan-out (in-process and on 2 Dask worker processes), not the steps again
    jobs = []
    for k in range(2):
        d = tmp_path / f"r{k}"
        shutil.copytree(root / "run", d)
        jobs.append((d, _cfg(src)))
    outs = run_many(jobs, workers=1)
    assert [o.error for o in outs] == [None, None] and all(s.action != "ran" for o in outs for s in o.steps)
    pytest.importorskip("dask.distributed")
    outs = run_many(jobs, workers=2)
    assert sorted(str(o.run_dir) for o in outs) == sorted(str(d) for d, _ in jobs)
    assert all(o.error is None for o in outs)
