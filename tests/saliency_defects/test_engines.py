"""The engines by name (``load_engine``): the one map from ``--engine`` to a model and its
functions, shared by ``inspect-pipe detect`` and the pipeline; the default; bad models and a
missing onnxruntime as one-line errors, with ``--engine saliency`` still working."""

import inspect
import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from inspect_pipe.errors import InputError
from inspect_pipe.saliency_defects import DEFAULT_ENGINE, ENGINES, load_engine

FIX = Path(__file__).resolve().parents[1] / "fixtures" / "defects"
runner = CliRunner()
KINDS = ("corrosion", "crack")


def _invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def test_one_default_for_detect_run_demo_and_the_pipeline():
    # the default is the rule's choice on the VALIDATION images (fastest engine within 0.01 of the
    # best mean validation figure, read from the fitted fused parameters); every entry point
    # takes it from the one constant
    from cli.demo import demo
    from cli.detect import run as detect_run
    from cli.run import run as pipeline_run
    from inspect_pipe.pipeline import DetectConfig
    from inspect_pipe.saliency_defects._fused import default_engine_on_validation, default_fused_path, load_fused_params

    assert DEFAULT_ENGINE == default_engine_on_validation(load_fused_params(default_fused_path())) == "onnx"
    for cmd in (detect_run, pipeline_run, demo):
        assert inspect.signature(cmd).parameters["engine"].default.value == DEFAULT_ENGINE, cmd.__module__
    assert DetectConfig().engine == DEFAULT_ENGINE


@pytest.mark.parametrize("name", ENGINES)
def test_per_class_decisions_are_the_engines_own(name):
    # GIVEN a real rusty frame WHEN an engine detects THEN its per-class decision (what the
    # pipeline stores per class) unites to the detection's own mask, and defects.json names it
    eng = load_engine(name)
    img = cv2.imread(str(FIX / "vt_train_112.jpeg"), cv2.IMREAD_COLOR)
    det = eng.detect(img, kinds=KINDS)
    union = np.zeros(det.mask.shape, bool)
    for k in KINDS:
        union |= eng.decide(det.class_probs[k], k)
    assert det.mask.any() and np.array_equal(union, det.mask)
    doc = eng.model_doc(KINDS)
    assert doc["engine"] == name and doc["version"] == eng.version and set(doc["operating_points"]) == set(KINDS)


def test_batch_equals_one_at_a_time():
    eng = load_engine("onnx")
    imgs = [cv2.imread(str(FIX / f), cv2.IMREAD_COLOR) for f in ("crackforest_004.jpg", "crackforest_014.jpg", "vt_train_112.jpeg")]
    batch = eng.detect_batch(imgs, kinds=KINDS)
    assert len(batch) == len(imgs)
    for a, b in zip(batch, [eng.detect(im, kinds=KINDS) for im in imgs]):
        assert np.array_equal(a.mask, b.mask) and np.abs(a.prob.astype(int) - b.prob).max() <= 1


def test_unknown_engine_and_another_engines_model_file():
    with pytest.raises(InputError, match="'paint' unknown"):
        load_engine("paint")
    npz = load_engine("saliency").model_path
    with pytest.raises(InputError, match=r"a saliency engine model \(\.npz\).*add --engine saliency"):
        load_engine("onnx", npz)
    with pytest.raises(InputError, match="model has no class 'rust'"):
        load_engine("onnx").check_kinds(("rust",))
    with pytest.raises(InputError, match="not a multiple of 16"):
        load_engine("onnx").check_tile(300)


def test_missing_onnxruntime_is_one_line_naming_saliency(tmp_path, monkeypatch):
    # GIVEN onnxruntime cannot be imported
    monkeypatch.setitem(sys.modules, "onnxruntime", None)
    for name in ("onnx", "fused"):
        with pytest.raises(InputError, match=r"onnxruntime: not installed .*--engine saliency"):
            load_engine(name)
    # THEN the default engine fails with one line, exit 2, nothing written
    r = _invoke("detect", FIX / "crackforest_004.jpg", "-o", tmp_path / "o1")
    lines = [ln for ln in r.output.strip().splitlines() if ln]
    assert r.exit_code == 2 and len(lines) == 1 and "onnxruntime" in lines[0] and "--engine saliency" in lines[0], r.output
    assert not (tmp_path / "o1").exists()
    # AND the saliency engine still works
    r = _invoke("detect", FIX / "crackforest_004.jpg", "-o", tmp_path / "o2", "--engine", "saliency")
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "o2" / "defects.json").read_text())["model"]["engine"] == "saliency"


def test_detect_without_engine_uses_the_network(tmp_path):
    r = _invoke("detect", FIX / "crackforest_004.jpg", "-o", tmp_path)
    assert r.exit_code == 0, r.output
    model = json.loads((tmp_path / "defects.json").read_text())["model"]
    assert model["engine"] == "onnx" and Path(model["file"]).name == "defects_unet_v5.onnx"
