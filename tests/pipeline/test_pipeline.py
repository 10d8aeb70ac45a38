"""The pipeline on a real folder of frames: resume by artifact presence, --force, --rerun-from,
changed options, and the run command's bad input."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.main import app
from inspect_pipe.pipeline import STEP_NAMES, RunStore, plan, run_pipeline
from inspect_pipe.pipeline._steps import DetectConfig, RunConfig

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "mosaic" / "synth_rust_mini"
runner = CliRunner()


def _cfg(src: Path, engine: str = "onnx", **report) -> RunConfig:
    return RunConfig(input=str(src), focal_px=618.0, detect=DetectConfig(keyframe_spacing=0.0, engine=engine),
                     report={"m_per_px": 0.002, "pdf": False, **report})


def _cli_args(src: Path, out: Path) -> list[str]:
    """``inspect-pipe run`` with the options of ``_cfg`` for detect (so a copy of the finished
    run keeps its detect step when the engine is the same)."""
    return ["run", str(src), "-o", str(out), "--focal-px", "618", "--m-per-px", "0.002", "--keyframe-spacing", "0", "--no-pdf"]


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
    # the report names the engine and model that produced the detections, in every output
    assert run["steps"]["detect"]["options"]["detect"]["engine"] == "onnx"
    trace = doc["traceability"]
    assert (trace["detector_engine"], trace["model_file"], trace["model_version"]) == ("onnx", "defects_unet_v5.onnx", "5")
    html = (store.report_dir / "report.html").read_text()
    assert "onnx engine, model defects_unet_v5.onnx v5" in html
    # the condition states come from the states network's head (v6): named in the trace and the page, and the hard
    # rust rated from its states
    assert trace["condition_states_model"] == "defects_unet_v6.onnx v6"
    assert "condition-state head of defects_unet_v6.onnx v6" in trace["hard_rust_rule"]
    assert "detector onnx (defects_unet_v5.onnx v5; condition states defects_unet_v6.onnx v6)" in html
    assert "condition states from the head of defects_unet_v6.onnx v6" in html
    assert "onnx engine, defects_unet_v5.onnx v5" in json.loads((store.report_dir / "coco.json").read_text())["info"]["description"]


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


def test_changed_engine_reruns_detect_and_report(done_run, tmp_path):
    root, src, _ = done_run
    run = tmp_path / "run"
    shutil.copytree(root / "run", run)
    store = RunStore(run)
    # GIVEN a run finished with the onnx engine WHEN the engine changes THEN detect and report run again
    steps = plan(store, _cfg(src, engine="saliency"))
    assert [a for _, a, _ in steps] == ["n/a", "skip", "run", "run"] and steps[2][2] == "options changed"
    out = run_pipeline(run, _cfg(src, engine="saliency"), log=lambda s: None)
    assert [(s.name, s.action) for s in out.steps[1:]] == [("mosaic", "skipped"), ("detect", "ran"), ("report", "ran")]
    det = json.loads((store.detect_dir / "defects.json").read_text())
    assert det["model"]["engine"] == "saliency" and Path(det["model"]["file"]).name == "defects_v1.npz"
    reg = json.loads((store.report_dir / "defects.json").read_text())
    assert reg["traceability"]["detector_engine"] == "saliency"
    assert "saliency engine, model defects_v1.npz v1" in (store.report_dir / "report.html").read_text()
    # AND back to onnx redoes them again
    assert [a for _, a, _ in plan(store, _cfg(src))] == ["n/a", "skip", "run", "run"]


def test_run_recorded_before_engines_existed_redetects(done_run, tmp_path):
    # GIVEN a run.json whose detect options have no engine (runs made when only saliency existed)
    root, src, _ = done_run
    run = tmp_path / "run"
    shutil.copytree(root / "run", run)
    store = RunStore(run)
    doc = json.loads(store.run_json.read_text())
    del doc["steps"]["detect"]["options"]["detect"]["engine"]
    store.run_json.write_text(json.dumps(doc))
    # THEN the default engine's run does not take those detections for its own
    steps = plan(store, _cfg(src))
    assert [a for _, a, _ in steps] == ["n/a", "skip", "run", "run"] and steps[2][2] == "options changed"


def test_run_command_engine_option(done_run, tmp_path):
    root, src, _ = done_run
    run = tmp_path / "run"
    shutil.copytree(root / "run", run)
    # WHEN run without --engine on a run made with the onnx engine THEN detect is not redone
    res = runner.invoke(app, _cli_args(src, run))
    assert res.exit_code == 0, res.output
    assert "detect skipped" in res.output and "report ran" in res.output
    # WHEN --engine saliency THEN detect runs with it
    res = runner.invoke(app, _cli_args(src, run) + ["--engine", "saliency"])
    assert res.exit_code == 0, res.output
    assert "detect ran" in res.output
    assert json.loads((run / "detect" / "defects.json").read_text())["model"]["engine"] == "saliency"
    # WHEN the engine cannot load THEN one line, exit 2, before any step
    res = runner.invoke(app, _cli_args(src, tmp_path / "o") + ["--engine", "paint"])
    assert res.exit_code == 2 and "paint" in res.output and not (tmp_path / "o").exists()


def test_run_without_onnxruntime_fails_first_and_saliency_runs(done_run, tmp_path, monkeypatch):
    root, src, _ = done_run
    monkeypatch.setitem(sys.modules, "onnxruntime", None)
    res = runner.invoke(app, _cli_args(src, tmp_path / "o"))
    lines = [ln for ln in res.output.strip().splitlines() if ln]
    assert res.exit_code == 2 and len(lines) == 1 and "onnxruntime: not installed" in lines[0] and "--engine saliency" in lines[0]
    assert not (tmp_path / "o").exists()  # checked before the mosaic is computed
    run = tmp_path / "run"
    shutil.copytree(root / "run", run)
    res = runner.invoke(app, _cli_args(src, run) + ["--engine", "saliency"])
    assert res.exit_code == 0 and "detect ran" in res.output, res.output


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
        assert [a for _, a, _ in steps] == ["n/a", "skip", "run", "run"] and steps[2][2] == "output missing or damaged"
        # AND so do detections cut short (a crash or a copy), which are no output either
        (store.detect_dir / "defects.json").write_bytes(saved[:100])
        steps = plan(store, _cfg(src))
        assert [a for _, a, _ in steps] == ["n/a", "skip", "run", "run"] and steps[2][2] == "output missing or damaged"
    finally:
        (store.detect_dir / "defects.json").write_bytes(saved)


def test_run_command_bad_input(tmp_path):
    res = runner.invoke(app, ["run", str(tmp_path / "nope"), "-o", str(tmp_path / "o")])
    assert res.exit_code == 2 and "nope: not found" in res.output
    assert not (tmp_path / "o").exists()
    res = runner.invoke(app, ["run", str(FIXTURE), "-o", str(tmp_path / "o"), "--rerun-from", "paint"])
    assert res.exit_code == 2 and "'paint' is not one of 'capture', 'mosaic', 'detect', 'report'" in res.output
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


def test_an_input_that_cannot_run_leaves_no_run_directory(tmp_path):
    # an empty folder, a missing scenario: one line, exit 2, and no RUN/run.json left behind
    (tmp_path / "empty").mkdir()
    for spec, words in ((str(tmp_path / "empty"), "no images found"), (f"fly:{tmp_path / 'nope.yaml'}", "scenario file not found")):
        out = tmp_path / "run"
        res = runner.invoke(app, ["run", spec, "-o", str(out)])
        assert res.exit_code == 2 and words in res.output, res.output
        assert not out.exists()
