"""Reliability of the outputs (issue 20, item 6): file modes follow the umask, COMPLETE is checked
against the disk (and the checksums with --verify), a sweep cut by a crash or holding a corrupt
frame is mosaicked from its whole frames, one failing sweep does not stop a batch, and coco.json
names the mosaic where it lies."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from inspect_pipe._files import atomic_write, current_umask, write_json
from inspect_pipe.capture import CameraModel, SweepWriter, read_sweep

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "mosaic" / "synth_rust_mini"
runner = CliRunner()


def _mode(p: Path) -> int:
    return stat.S_IMODE(p.stat().st_mode)


@pytest.fixture
def umask():
    def set_(m: int) -> None:
        os.umask(m)

    old = os.umask(0o022)
    os.umask(old)
    yield set_
    os.umask(old)


def test_files_get_the_mode_of_the_umask_not_0600(tmp_path, umask):
    umask(0o022)
    atomic_write(tmp_path / "a.bin", b"x")
    write_json(tmp_path / "b.json", {"a": 1})
    assert _mode(tmp_path / "a.bin") == 0o644 and _mode(tmp_path / "b.json") == 0o644
    umask(0o077)
    assert current_umask() == 0o077
    atomic_write(tmp_path / "c.bin", b"x")
    assert _mode(tmp_path / "c.bin") == 0o600
    umask(0o002)
    atomic_write(tmp_path / "a.bin", b"y")  # replacing a file: the new one's mode, content whole
    assert _mode(tmp_path / "a.bin") == 0o664 and (tmp_path / "a.bin").read_bytes() == b"y"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], "no temporary file left"


def make_sweep(dst: Path, n: int = 6) -> Path:
    """A real sweep (SweepWriter, with COMPLETE and checksums) of the first ``n`` overlapping
    frames of the mini rust fixture (256 x 192, focal 309 px)."""
    cam = CameraModel(np.array([[309.0, 0, 128], [0, 309.0, 96], [0, 0, 1]]), np.zeros(5), 256, 192, "fixture")
    w = SweepWriter(dst, {"camera": cam.to_json(), "survey": {"vessel": "MV Test"}}, encoders=1)
    for i, p in enumerate(sorted(FIXTURE.glob("frame_000*.jpg"))[:n]):
        assert w.submit(i, cv2.imread(str(p)), {"t_s": 0.1 * i, "exposure_s": 0.004})
    w.close({"stop_reason": "test"})
    assert w.error is None
    return dst


def test_complete_that_lists_more_frames_than_the_disk_holds_is_not_complete(tmp_path):
    sw = make_sweep(tmp_path / "sw")
    s = read_sweep(sw)
    assert s.complete and len(s) == 6 and not s.problems
    # a partial copy: COMPLETE and sweep.json came along, 2 of the 6 frames did not
    lines = (sw / "frames.jsonl").read_text().splitlines(keepends=True)
    (sw / "frames.jsonl").write_text("".join(lines[:4]))
    s = read_sweep(sw)
    assert len(s) == 4 and not s.complete
    assert "lists 6 frames but 4 are on disk" in str(s.problems[0]) and "COMPLETE" in str(s.problems[0])


def test_verify_lists_a_changed_image_as_corrupt_and_the_mosaic_unplaces_it(tmp_path):
    sw = make_sweep(tmp_path / "sw")
    assert read_sweep(sw, verify=True).corrupt == {}
    img = sw / "images" / "000002.png"
    a = cv2.imread(str(img))
    a[10:20, 10:20] = 0  # decodes fine; only the checksum tells
    cv2.imwrite(str(img), a)
    s = read_sweep(sw, verify=True)
    assert list(s.corrupt) == [2] and "sha256 differs" in s.corrupt[2] and not s.complete
    assert read_sweep(sw).complete, "without --verify only the cheap checks run"
    r = runner.invoke(app, ["mosaic", str(sw), "-o", str(tmp_path / "m"), "-q", "--verify"])
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp_path / "m" / "mosaic.json").read_text())
    assert [u["index"] for u in doc["unplaced"]] == [2] and "sha256 differs" in doc["unplaced"][0]["reason"]
    assert len(doc["frames"]) == 5 and doc["input"]["verified"] is True
    assert "warning:" in r.output and "sha256" in r.output


def test_mosaic_of_a_sweep_cut_mid_line_keeps_the_whole_frames_and_exits_0(tmp_path):
    sw = make_sweep(tmp_path / "sw")
    raw = (sw / "frames.jsonl").read_bytes()
    (sw / "frames.jsonl").write_bytes(raw[: raw.rfind(b"\n", 0, len(raw) - 1) + 30])  # last line cut by a crash
    (sw / "COMPLETE").unlink()  # a crash writes no marker
    r = runner.invoke(app, ["mosaic", str(sw), "-o", str(tmp_path / "m"), "-q"])
    assert r.exit_code == 0, r.output
    warnings = [line for line in r.output.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1 and "truncated at line 6" in warnings[0]
    doc = json.loads((tmp_path / "m" / "mosaic.json").read_text())
    assert len(doc["frames"]) == 5 and doc["input"]["complete"] is False


def test_corrupt_frame_in_a_sweep_is_unplaced_with_its_reason_not_fatal(tmp_path):
    sw = make_sweep(tmp_path / "sw")
    p = sw / "images" / "000003.png"
    p.write_bytes(p.read_bytes()[:200])  # cut short
    r = runner.invoke(app, ["mosaic", str(sw), "-o", str(tmp_path / "m"), "-q"])
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp_path / "m" / "mosaic.json").read_text())
    assert doc["unplaced"] == [{"index": 3, "file": "images/000003.png", "reason": "truncated PNG (no IEND chunk)"}]
    assert len(doc["frames"]) == 5
    # run: the same sweep goes through every step; the report lists the frame as unplaced
    r = runner.invoke(app, ["run", str(sw), "-o", str(tmp_path / "run"), "--keyframe-spacing", "0.5", "--no-pdf", "--m-per-px", "0.002"])
    assert r.exit_code == 0, r.output
    html = (tmp_path / "run" / "report" / "report.html").read_text()
    assert "truncated PNG (no IEND chunk)" in html


def test_run_many_finishes_the_others_and_lists_the_failed_one(tmp_path, monkeypatch):
    import inspect_pipe.pipeline._runner as R

    good = make_sweep(tmp_path / "good")
    bad = make_sweep(tmp_path / "bad")
    real = R.run_pipeline

    def flaky(run_dir, cfg, **kw):  # a bug (not an input error) in one sweep's pipeline
        if Path(run_dir).name == "bad":
            raise ZeroDivisionError("division by zero")
        return real(run_dir, cfg, **kw)

    monkeypatch.setattr(R, "run_pipeline", flaky)
    out = tmp_path / "runs"
    r = runner.invoke(app, ["run", str(bad), str(good), "-o", str(out), "--workers", "1", "--keyframe-spacing", "0", "--no-pdf", "--m-per-px", "0.002"])
    assert r.exit_code == 2
    assert (out / "good" / "report" / "report.html").is_file(), "the other sweep finished"
    runs = json.loads((out / "runs.json").read_text())["runs"]
    assert [(Path(x["run"]).name, x["status"]) for x in runs] == [("bad", "failed"), ("good", "done")]
    assert "ZeroDivisionError: division by zero" in runs[0]["error"] and (out / "bad" / "error.txt").is_file()
    last = r.output.strip().splitlines()[-1]
    assert last.startswith("error:") and "1 of 2 sweeps failed (bad)" in last


def test_a_sweep_unreadable_before_running_is_a_failure_of_its_own_in_a_batch(tmp_path):
    # GIVEN a good sweep and one whose sweep.json was cut short (found before anything is written)
    good = make_sweep(tmp_path / "good")
    bad = make_sweep(tmp_path / "cut")
    text = (bad / "sweep.json").read_text()
    (bad / "sweep.json").write_text(text[: len(text) // 2])
    out = tmp_path / "runs"
    r = runner.invoke(app, ["run", str(good), str(bad), "-o", str(out), "--workers", "1", "--keyframe-spacing", "0", "--no-pdf", "--m-per-px", "0.002"])
    # THEN the good one finishes, the bad one is listed failed with the file named, and the exit is 2
    assert r.exit_code == 2
    assert (out / "good" / "report" / "report.html").is_file()
    runs = json.loads((out / "runs.json").read_text())["runs"]
    assert [(Path(x["run"]).name, x["status"]) for x in runs] == [("good", "done"), ("cut", "failed")]
    assert "sweep.json" in runs[1]["error"] and not (out / "cut").exists()
    last = r.output.strip().splitlines()[-1]
    assert "1 of 2 sweeps failed (cut); the others finished" in last


def test_a_sweep_with_no_readable_frame_is_one_line_not_warnings_first(tmp_path):
    sweep = make_sweep(tmp_path / "sw")
    for p in (sweep / "images").iterdir():
        p.unlink()
    r = runner.invoke(app, ["run", str(sweep), "-o", str(tmp_path / "run"), "--no-pdf"])
    lines = r.output.strip().splitlines()
    assert r.exit_code == 2 and len(lines) == 1, r.output
    assert "frames.jsonl: no readable frames" in lines[0] and not (tmp_path / "run").exists()


def test_a_rerun_on_bad_frames_keeps_the_earlier_run_whole(tmp_path):
    # GIVEN a finished run of a folder of frames
    src = tmp_path / "frames"
    src.mkdir()
    for p in sorted(FIXTURE.glob("*.jpg")):
        (src / p.name).write_bytes(p.read_bytes())
    out = tmp_path / "run"
    args = ["-o", str(out), "--workers", "1", "--keyframe-spacing", "0", "--no-pdf", "--m-per-px", "0.002"]
    assert runner.invoke(app, ["run", str(src), *args]).exit_code == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    # WHEN it is run again after a frame was cut short on disk
    data = (src / "frame_0003.jpg").read_bytes()
    (src / "frame_0003.jpg").write_bytes(data[: len(data) // 2])
    r = runner.invoke(app, ["run", str(src), *args, "--force"])
    # THEN exit 2, one line naming the frame and saying the earlier mosaic is kept, and every file of
    # the run, run.json included, is as it was
    last = r.output.strip().splitlines()[-1]
    assert r.exit_code == 2 and "frame_0003.jpg: truncated" in last and "keeps its earlier mosaic" in last, r.output
    assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


def test_coco_names_the_mosaic_where_it_lies_and_outputs_are_readable(tmp_path, umask):
    umask(0o022)
    sw = make_sweep(tmp_path / "sw")
    r = runner.invoke(app, ["run", str(sw), "-o", str(tmp_path / "run"), "--keyframe-spacing", "0", "--no-pdf", "--m-per-px", "0.002"])
    assert r.exit_code == 0, r.output
    rep = tmp_path / "run" / "report"
    coco = json.loads((rep / "coco.json").read_text())
    img = coco["images"][0]
    assert img["file_name"] == "../mosaic/mosaic.png"
    on_disk = cv2.imread(str(rep / img["file_name"]), cv2.IMREAD_UNCHANGED)
    assert on_disk is not None and on_disk.shape[:2] == (img["height"], img["width"])
    for p in [rep / "report.html", rep / "defects.json", rep / "coco.json", tmp_path / "run" / "mosaic" / "mosaic.png", tmp_path / "run" / "run.json"]:
        assert _mode(p) == 0o644, p
