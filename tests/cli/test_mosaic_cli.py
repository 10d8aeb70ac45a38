"""``inspect-pipe mosaic`` as a user runs it: outputs, exit codes, one-line errors."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
from typer.testing import CliRunner

from cli.main import app

FIXTURE = Path(__file__).resolve().parent.parent / "fixtures" / "mosaic" / "synth_rust_mini"
runner = CliRunner()


def _copy(tmp_path: Path, names=None) -> Path:
    d = tmp_path / "in"
    d.mkdir()
    for p in sorted(FIXTURE.glob("*.jpg")):
        if names is None or p.name in names:
            shutil.copy(p, d / p.name)
    return d


def test_mosaic_writes_png_and_json_with_one_homography_per_frame(tmp_path):
    src = _copy(tmp_path)
    out = tmp_path / "out"
    res = runner.invoke(app, ["mosaic", str(src), "-o", str(out), "-q"])
    assert res.exit_code == 0, res.output
    doc = json.loads((out / "mosaic.json").read_text())
    assert doc["format"] == "inspect_pipe.mosaic/1"
    assert len(doc["frames"]) == 13 and doc["unplaced"] == []
    img = cv2.imread(str(out / "mosaic.png"), cv2.IMREAD_UNCHANGED)
    assert img.shape[2] == 4
    # H maps each frame's centre inside the covered part of the mosaic
    for f in doc["frames"]:
        H = np.array(f["H"])
        assert H.shape == (3, 3)
        c = H @ [128, 96, 1]
        x, y = (c[:2] / c[2]).round().astype(int)
        assert img[y, x, 3] == 255


def test_console_script_help_has_examples():
    res = subprocess.run([sys.executable, "-m", "cli.main", "mosaic", "--help"], capture_output=True, text=True)
    assert res.returncode == 0
    assert "Examples" in res.stdout and "mosaic.json" in res.stdout


def test_missing_folder_is_one_line_exit_2(tmp_path):
    res = runner.invoke(app, ["mosaic", str(tmp_path / "nope"), "-o", str(tmp_path / "o")])
    assert res.exit_code == 2
    assert "nope" in res.output and "not found" in res.output
    assert "Traceback" not in res.output


def test_empty_folder(tmp_path):
    (tmp_path / "empty").mkdir()
    res = runner.invoke(app, ["mosaic", str(tmp_path / "empty"), "-o", str(tmp_path / "o")])
    assert res.exit_code == 2 and "no images found" in res.output


def test_truncated_and_corrupt_images_are_named_and_the_rest_is_mosaicked(tmp_path):
    src = _copy(tmp_path)
    data = (src / "frame_0003.jpg").read_bytes()
    (src / "frame_0003.jpg").write_bytes(data[: len(data) // 2])
    (src / "frame_0066.jpg").write_bytes(b"this is not a jpeg")
    out = tmp_path / "out"
    res = runner.invoke(app, ["mosaic", str(src), "-o", str(out), "-q"])
    assert res.exit_code == 2
    last = res.output.strip().splitlines()[-1]
    assert "frame_0003.jpg" in last and "truncated" in last and "1 more" in last
    doc = json.loads((out / "mosaic.json").read_text())
    assert len(doc["frames"]) == 11
    reasons = {u["file"]: u["reason"] for u in doc["unplaced"]}
    assert "truncated" in reasons["frame_0003.jpg"] and "not a JPEG" in reasons["frame_0066.jpg"]
    assert (out / "mosaic.png").exists()


def test_image_of_a_different_size_is_unplaced(tmp_path):
    src = _copy(tmp_path)
    img = cv2.imread(str(src / "frame_0070.jpg"))
    cv2.imwrite(str(src / "frame_0070.jpg"), cv2.resize(img, (200, 150)))
    res = runner.invoke(app, ["mosaic", str(src), "-o", str(tmp_path / "out"), "-q"])
    assert res.exit_code == 2 and "frame_0070.jpg" in res.output and "differs" in res.output
    doc = json.loads((tmp_path / "out" / "mosaic.json").read_text())
    assert len(doc["frames"]) == 12


def test_single_image_is_written_and_reported(tmp_path):
    src = _copy(tmp_path, {"frame_0000.jpg"})
    res = runner.invoke(app, ["mosaic", str(src), "-o", str(tmp_path / "out"), "-q"])
    assert res.exit_code == 2 and "only one image" in res.output
    doc = json.loads((tmp_path / "out" / "mosaic.json").read_text())
    assert len(doc["frames"]) == 1 and (tmp_path / "out" / "mosaic.png").exists()


def test_no_overlap(tmp_path):
    d = tmp_path / "in"
    d.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(d / f"{i}.png"), rng.integers(0, 255, (120, 160, 3), dtype=np.uint8))
    res = runner.invoke(app, ["mosaic", str(d), "-o", str(tmp_path / "out"), "-q"])
    assert res.exit_code == 2 and "overlap" in res.output
    doc = json.loads((tmp_path / "out" / "mosaic.json").read_text())
    assert doc["frames"] == [] and len(doc["unplaced"]) == 3


def test_two_disconnected_groups_give_two_mosaics(tmp_path):
    # two short passes over parts of a wall 1000 px apart: nothing links them
    from inspect_pipe.mosaic.synthetic import render_frame, textured_wall

    wall = textured_wall(1500, 400, np.random.default_rng(7))
    d = tmp_path / "in"
    d.mkdir()
    for k, x0 in enumerate([20, 20, 20, 1100, 1100, 1100]):
        x = x0 + 40 * (k % 3)
        H = np.array([[1, 0, x], [0, 1, 100], [0, 0, 1.0]])
        cv2.imwrite(str(d / f"f{k}.png"), render_frame(wall, H, (256, 192)))
    out = tmp_path / "out"
    res = runner.invoke(app, ["mosaic", str(d), "-o", str(out), "-q"])
    assert res.exit_code == 0, res.output
    doc = json.loads((out / "mosaic.json").read_text())
    assert len(doc["groups"]) == 2
    assert (out / "mosaic.png").exists() and (out / "mosaic_group1.png").exists()
    assert {f["group"] for f in doc["frames"]} == {0, 1}
    assert doc["unplaced"] == []


def test_bad_input_never_replaces_a_good_earlier_mosaic(tmp_path):
    # GIVEN a good mosaic in OUT
    good = _copy(tmp_path)
    out = tmp_path / "out"
    assert runner.invoke(app, ["mosaic", str(good), "-o", str(out), "-q"]).exit_code == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert json.loads((out / "mosaic.json").read_text())["problems"] == []
    # WHEN the same OUT is given a folder with a truncated frame, then one whose images do not overlap
    bad = tmp_path / "bad"
    shutil.copytree(good, bad)
    data = (bad / "frame_0003.jpg").read_bytes()
    (bad / "frame_0003.jpg").write_bytes(data[: len(data) // 2])
    apart = tmp_path / "apart"
    apart.mkdir()
    rng = np.random.default_rng(1)
    for i in range(2):
        cv2.imwrite(str(apart / f"{i}.png"), rng.integers(0, 255, (96, 128, 3), dtype=np.uint8))
    for src, what in ((bad, "frame_0003.jpg: truncated"), (apart, "overlap")):
        res = runner.invoke(app, ["mosaic", str(src), "-o", str(out), "-q"])
        # THEN exit 2, one line naming the file (with its folder) or the folder, and saying the earlier mosaic is kept ...
        last = res.output.strip().splitlines()[-1]
        assert res.exit_code == 2 and what in last and str(src) in last and "keeps its earlier mosaic" in last, res.output
        # ... which is there byte for byte, with nothing added, and no staging folder left beside it
        assert {p.name: p.read_bytes() for p in out.iterdir()} == before
        assert [p.name for p in tmp_path.iterdir() if "staging" in p.name] == []
    # AND over an output that had problems of its own, a new result replaces it: stale group images go
    partial = tmp_path / "partial"
    assert runner.invoke(app, ["mosaic", str(bad), "-o", str(partial), "-q"]).exit_code == 2
    assert len(json.loads((partial / "mosaic.json").read_text())["problems"]) == 1
    (partial / "mosaic_group1.png").write_bytes((partial / "mosaic.png").read_bytes())  # as an earlier run would leave
    assert runner.invoke(app, ["mosaic", str(apart), "-o", str(partial), "-q"]).exit_code == 2
    doc = json.loads((partial / "mosaic.json").read_text())
    assert doc["mosaic"] is None and sorted(p.name for p in partial.iterdir()) == ["mosaic.json"]


def test_bad_input_writes_nothing_and_a_broken_earlier_mosaic_is_not_kept(tmp_path):
    # GIVEN a missing input folder WHEN mosaicked into a path whose parents do not exist THEN nothing is made
    res = runner.invoke(app, ["mosaic", str(tmp_path / "none"), "-o", str(tmp_path / "a" / "b" / "out")])
    assert res.exit_code == 2 and not (tmp_path / "a").exists()
    # GIVEN an earlier clean mosaic whose image was since cut short on disk
    good = _copy(tmp_path)
    out = tmp_path / "out"
    assert runner.invoke(app, ["mosaic", str(good), "-o", str(out), "-q"]).exit_code == 0
    png = (out / "mosaic.png").read_bytes()
    (out / "mosaic.png").write_bytes(png[: len(png) // 2])
    # WHEN a run with a truncated frame comes THEN its partial result replaces the broken one (nothing whole to keep)
    data = (good / "frame_0003.jpg").read_bytes()
    (good / "frame_0003.jpg").write_bytes(data[: len(data) // 2])
    res = runner.invoke(app, ["mosaic", str(good), "-o", str(out), "-q"])
    assert res.exit_code == 2 and "keeps its earlier mosaic" not in res.output
    doc = json.loads((out / "mosaic.json").read_text())
    assert len(doc["frames"]) == 12 and len(doc["problems"]) == 1
    assert cv2.imread(str(out / "mosaic.png"), cv2.IMREAD_UNCHANGED) is not None
    assert [p.name for p in out.iterdir() if p.name.startswith(".staging")] == []
