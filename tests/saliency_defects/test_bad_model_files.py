"""A damaged or mismatched model file is refused when it is opened, naming the file and the field
(one line, exit 2, nothing written), never found out on an image or, worse, used: each engine's
file (the network's metadata, the saliency tables, the fused parameters) and the outputs of
``detect`` when writing them fails."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from inspect_pipe.saliency_defects import _onnx_detect as od
from inspect_pipe.saliency_defects._model import load_model, save_model

from tests.reliability.test_user_files import _png_claiming

from ._onnx_bytes import one_node_model, with_metadata

FIX = Path(__file__).resolve().parents[1] / "fixtures" / "defects"
IMG = FIX / "crackforest_004.jpg"
runner = CliRunner()


def _detect(*args):
    return runner.invoke(app, ["detect", *[str(a) for a in args]])


def _one_line_exit_2(r, *words):
    lines = [ln for ln in r.output.strip().splitlines() if ln]
    assert r.exit_code == 2 and len(lines) == 1 and lines[0].startswith("error:"), r.output
    for w in words:
        assert w in lines[0], r.output


@pytest.fixture(scope="module")
def shipped():
    path = od.default_onnx_path()
    return path.read_bytes(), od.load_onnx_model(path).meta


def _edit(meta: dict, dotted: str, value):
    m = copy.deepcopy(meta)
    *head, last = dotted.split(".")
    node = m
    for k in head:
        node = node[k]
    node[last] = value
    return m


@pytest.mark.parametrize("field, value", [
    ("input", "x"), ("input.mean", ["a", 0.5, 0.5]), ("input.std", [0.0, 0.5, 0.5]), ("input.scale", True),
    ("output", "x"), ("output.stride", 0), ("output.stride", 0.5), ("classes", 5),
    ("operating_points_u8", [1, 2, 3]), ("operating_points_u8.crack", None), ("min_area_px", "x"),
    ("min_area_px.crack", None), ("calibration", [1]), ("severity.output", ["x"]), ("severity.logit_bias", [0, "a", 0]),
])
def test_network_metadata_outside_its_schema_names_the_field(tmp_path, shipped, field, value):
    raw, meta = shipped
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(with_metadata(raw, _edit(meta, field, value)))
    r = _detect(IMG, "-o", tmp_path / "o", "--model", bad)
    _one_line_exit_2(r, str(bad), "metadata", field.split(".")[0])
    assert not (tmp_path / "o").exists()


def test_network_whose_outputs_do_not_match_its_metadata_is_refused(tmp_path, shipped):
    _, meta = shipped
    meta = {k: v for k, v in meta.items() if k != "severity"} | {"output": {"name": "prob", "stride": 1}}
    cases = {
        "fixed": (one_node_model("Sigmoid", [1, 3, 64, 64], [1, 3, 64, 64], meta), "fixed batch or size"),
        "fixed_batch": (one_node_model("Sigmoid", [1, 3, "h", "w"], [1, 3, "h", "w"], meta), "fixed batch or size"),
        "pooled": (one_node_model("GlobalAveragePool", ["n", 3, "h", "w"], ["n", 3, 1, 1], meta), "(2, 3, 1, 1)"),
        "stride": (one_node_model("Sigmoid", ["n", 3, "h", "w"], ["n", 3, "h", "w"], _edit(meta, "output.stride", 4)),
                   "output stride 4"),
    }
    for name, (model, words) in cases.items():
        bad = tmp_path / f"{name}.onnx"
        bad.write_bytes(model)
        r = _detect(IMG, "-o", tmp_path / "o", "--model", bad)
        _one_line_exit_2(r, str(bad), words)
        assert not (tmp_path / "o").exists()
    # the same graph with free dimensions and a true stride runs (the checks refuse what is wrong only)
    ok = tmp_path / "ok.onnx"
    ok.write_bytes(one_node_model("Sigmoid", ["n", 3, "h", "w"], ["n", 3, "h", "w"], meta))
    assert _detect(IMG, "-o", tmp_path / "o_ok", "--model", ok).exit_code == 0


@pytest.mark.parametrize("change, words", [
    (lambda c: setattr(c, "level", 20), "feature level"),
    (lambda c: setattr(c, "threshold", float("nan")), "thresholds"),
    (lambda c: setattr(c, "smooth_sigma_px", 1e6), "smooth_sigma_px"),
    (lambda c: setattr(c.stages[0], "weights", c.stages[0].weights[:-1]), "one finite weight per table"),
    (lambda c: setattr(c.stages[0].tables[0], "llr", c.stages[0].tables[0].llr[:-5]), "not a whole table"),
])
def test_damaged_saliency_tables_are_refused_when_loaded(tmp_path, change, words):
    import dataclasses

    from inspect_pipe.saliency_defects import default_model_path

    model = load_model(default_model_path())
    crack = model.classes["crack"]
    # the model's dataclasses are frozen: rebuild the class with the damage (object.__setattr__ on a copy)
    stages = [dataclasses.replace(s, tables=tuple(dataclasses.replace(t) for t in s.tables)) for s in crack.stages]
    crack = dataclasses.replace(crack, stages=tuple(stages))

    def setattr(obj, name, value):  # noqa: A001 - the lambdas' edit, on frozen dataclasses
        object.__setattr__(obj, name, value)

    change.__globals__["setattr"] = setattr
    try:
        change(crack)
    finally:
        del change.__globals__["setattr"]
    bad = tmp_path / "bad.npz"
    save_model(dataclasses.replace(model, classes={**model.classes, "crack": crack}), bad)
    r = _detect(IMG, "-o", tmp_path / "o", "--engine", "saliency", "--model", bad)
    _one_line_exit_2(r, str(bad), "damaged model file", words)


@pytest.mark.parametrize("edit, words", [
    (lambda p: p["classes"].__setitem__("crack", "x"), "weight must be"),
    (lambda p: p["classes"]["crack"].__setitem__("threshold_u8", True), "threshold in 1..255"),
    (lambda p: p["classes"]["crack"].__setitem__("min_area_px", None), "min_area_px"),
    (lambda p: p.__setitem__("engines", "x"), "'engines'"),
    (lambda p: p["engines"].__setitem__("onnx", "x"), "'engines'"),
])
def test_damaged_fused_parameters_are_refused_when_loaded(tmp_path, edit, words):
    from inspect_pipe.saliency_defects._fused import default_fused_path

    p = json.loads(default_fused_path().read_text())
    edit(p)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(p))
    _one_line_exit_2(_detect(IMG, "-o", tmp_path / "o", "--engine", "fused", "--model", bad), str(bad), words)


def test_an_image_whose_header_claims_too_many_pixels_fails_alone(tmp_path):
    huge = _png_claiming(100000, 100000)
    folder = tmp_path / "in"
    folder.mkdir()
    (folder / "z_huge.png").write_bytes(huge)
    cv2.imwrite(str(folder / "a.png"), cv2.imread(str(IMG)))
    r = _detect(folder, "-o", tmp_path / "o", "--engine", "saliency")
    assert r.exit_code == 2 and "z_huge.png" in r.output
    doc = json.loads((tmp_path / "o" / "defects.json").read_text())
    assert [i["name"] for i in doc["images"]] == ["a"] and len(doc["errors"]) == 1
    assert "more pixels than OpenCV decodes" in doc["errors"][0]["problem"]


def test_outputs_that_cannot_be_written_leave_no_half_sets(tmp_path):
    folder = tmp_path / "in"
    folder.mkdir()
    for name in ("a", "b"):
        cv2.imwrite(str(folder / f"{name}.png"), cv2.imread(str(IMG)))
    out = tmp_path / "o"
    (out / "b.mask.png").mkdir(parents=True)  # b's mask cannot be written: b fails, a is kept
    r = _detect(folder, "-o", out, "--engine", "saliency", "--kind", "crack")
    assert r.exit_code == 2
    doc = json.loads((out / "defects.json").read_text())
    assert [i["name"] for i in doc["images"]] == ["a"] and doc["errors"][0]["file"].endswith("b.png")
    assert not (out / "b.prob.png").exists()
    # defects.json itself cannot be written: none of the maps of this run is left
    out2 = tmp_path / "o2"
    (out2 / "defects.json").mkdir(parents=True)
    r = _detect(folder, "-o", out2, "--engine", "saliency", "--kind", "crack")
    last = r.output.strip().splitlines()[-1]
    assert r.exit_code == 2 and last.startswith("error:") and "defects.json" in last and "nothing written" in last
    assert sorted(p.name for p in out2.iterdir()) == ["defects.json"]
    # an output folder that is a file; and a run into its own input folder does not read its maps back
    _one_line_exit_2(_detect(IMG, "-o", folder / "a.png", "--engine", "saliency"), "is not a folder")
    for _ in range(2):
        r = _detect(folder, "-o", folder, "--engine", "saliency", "--kind", "crack")
        assert r.exit_code == 0, r.output
    assert [i["name"] for i in json.loads((folder / "defects.json").read_text())["images"]] == ["a", "b"]


def test_train_output_that_cannot_be_written_is_refused_before_training(tmp_path):
    (tmp_path / "afile").write_text("x")
    for args, words in ((["-o", tmp_path / "m.npz", "--engine", "onnx"], "writes a .onnx file"),
                        (["-o", tmp_path / "m.onnx"], "writes a .npz file"),
                        (["-o", tmp_path / "afile" / "m.npz"], "is a file, not a folder")):
        r = runner.invoke(app, ["detect", "train", str(FIX), *[str(a) for a in args]])
        _one_line_exit_2(r, words)


def test_too_small_for_the_saliency_features(tmp_path):
    img = tmp_path / "one.png"
    cv2.imwrite(str(img), np.zeros((1, 1, 3), np.uint8))
    _one_line_exit_2(_detect(img, "-o", tmp_path / "o", "--engine", "saliency"), "too small")


def test_a_jpeg_with_damaged_data_but_its_end_marker_is_refused_with_the_decoders_reason(tmp_path):
    ok, buf = cv2.imencode(".jpg", cv2.imread(str(IMG)))
    half = buf.tobytes()[: len(buf) // 2] + b"\xff\xd9"  # a card pulled mid-copy, the marker restored by a tool
    bad = tmp_path / "half.jpg"
    bad.write_bytes(half)
    assert cv2.imread(str(bad)) is not None  # OpenCV alone decodes it, grey rows and all
    r = _detect(bad, "-o", tmp_path / "o", "--engine", "saliency")
    _one_line_exit_2(r, str(bad), "damaged image data", "Corrupt JPEG data")
    assert not (tmp_path / "o").exists()
    good = tmp_path / "whole.jpg"
    good.write_bytes(buf.tobytes())
    assert _detect(good, "-o", tmp_path / "o2", "--engine", "saliency").exit_code == 0


def test_what_else_reaches_stderr_during_a_read_is_not_damage(tmp_path):
    """A progress bar forced on (FORCE_COLOR, as in CI logs) redraws from its own thread while an
    image is read; a few padding bytes before a JPEG marker change no pixel; a closed stderr."""
    import os
    import subprocess
    import sys

    folder = tmp_path / "in"
    folder.mkdir()
    big = cv2.resize(cv2.imread(str(IMG)), (3000, 2000))
    for k in range(3):
        cv2.imwrite(str(folder / f"im{k}.jpg"), big)
    root = Path(__file__).resolve().parents[2]
    env = dict(os.environ, FORCE_COLOR="1", COLUMNS="100")
    r = subprocess.run([sys.executable, "-m", "cli.main", "detect", str(folder), "-o", str(tmp_path / "o"), "--engine", "saliency",
                        "--kind", "crack"], capture_output=True, text=True, cwd=root, env=env, timeout=300)
    assert r.returncode == 0 and "damaged" not in r.stdout + r.stderr, r.stdout + r.stderr
    assert len(json.loads((tmp_path / "o" / "defects.json").read_text())["images"]) == 3
    # two padding bytes before the frame header: libjpeg notes them, no pixel changes
    raw = (folder / "im0.jpg").read_bytes()
    sof = raw.index(b"\xff\xc0")
    padded = tmp_path / "padded.jpg"
    padded.write_bytes(raw[:sof] + b"\x00\x00" + raw[sof:])
    assert np.array_equal(cv2.imread(str(padded)), cv2.imread(str(folder / "im0.jpg")))
    assert _detect(padded, "-o", tmp_path / "o2", "--engine", "saliency", "--kind", "crack").exit_code == 0
    # stderr closed (2>&-): read without listening, as before
    r = subprocess.run([sys.executable, "-m", "cli.main", "detect", str(padded), "-o", str(tmp_path / "o3"), "--engine", "saliency",
                        "--kind", "crack"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, cwd=root, timeout=300,
                       preexec_fn=lambda: os.close(2))
    assert r.returncode == 0 and (tmp_path / "o3" / "defects.json").exists()
