"""The fused engine (``--engine fused``): per-class weighted mean of the saliency and onnx maps,
weights and thresholds fitted on the validation images (``models/fused_v2.json``)."""

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from inspect_pipe.saliency_defects import _fused as fu
from inspect_pipe.saliency_defects import _onnx_detect as od
from inspect_pipe.saliency_defects import class_probabilities_u8, default_model_path
from inspect_pipe.saliency_defects._metrics import mask_prf, tolerance_counts

FIX = Path(__file__).resolve().parents[1] / "fixtures" / "defects"
runner = CliRunner()


@pytest.fixture(scope="module")
def model():
    return fu.load_fused_model()


def _fixture(img_name, mask_name):
    return cv2.imread(str(FIX / img_name), cv2.IMREAD_COLOR), cv2.imread(str(FIX / mask_name), cv2.IMREAD_GRAYSCALE) > 0


def test_shipped_parameters_record_validation_split_and_match_the_shipped_models(model):
    p = model.params
    assert p["format"] == fu.FUSED_FORMAT and p["fitted_on"]["split"] == "validation"
    assert "% 5 == 0" in p["fitted_on"]["val_rule"] and "% 3 == 0" in p["fitted_on"]["split_rule"]
    # fitted for these exact model files: retraining an engine without refitting fails here
    assert p["engines"]["saliency"]["sha256"] == fu.sha256_of(default_model_path())
    assert p["engines"]["onnx"]["sha256"] == fu.sha256_of(od.default_onnx_path())
    for c in ("corrosion", "crack", "surface"):
        cp = p["classes"][c]
        assert cp["weight_saliency"] in fu.WEIGHT_GRID and 1 <= cp["threshold_u8"] <= 255
        curve = cp["validation"]["by_weight"]
        # the chosen weight is the validation optimum of its criterion
        assert curve[f"{cp['weight_saliency']:.1f}"][cp["criterion"]] == max(v[cp["criterion"]] for v in curve.values())


def test_weights_zero_and_one_give_each_engine_map(model):
    img, _ = _fixture("crackforest_004.jpg", "crackforest_004.mask.png")
    ps = class_probabilities_u8(img, model.saliency, ("crack",))["crack"]
    po = od.onnx_probabilities_u8(img, model.onnx)["crack"]
    assert np.array_equal(fu.fuse_u8(ps, po, 1.0), ps) and np.array_equal(fu.fuse_u8(ps, po, 0.0), po)
    mid = fu.fuse_u8(ps, po, 0.5).astype(int)
    assert np.abs(mid - (ps.astype(int) + po.astype(int)) / 2).max() <= 0.5 + 1e-9
    with pytest.raises(ValueError, match="shape"):
        fu.fuse_u8(ps, po[:-1], 0.5)


def test_weight_choice_prefers_the_informative_map():
    # GIVEN maps where the 'saliency' map is the truth and the 'onnx' map is noise
    rng = np.random.default_rng(0)
    maps = []
    for _ in range(3):
        gt = np.zeros((64, 64), bool)
        gt[20:40, 10:50] = True
        maps.append((np.where(gt, 230, 20).astype(np.uint8), rng.integers(0, 256, (64, 64)).astype(np.uint8), gt))
    hi, lo = fu.score_weight(maps, "corrosion", 1.0), fu.score_weight(maps, "corrosion", 0.0)
    # THEN the saliency-only weight scores perfectly and the noise-only one does not
    assert hi["F"] == pytest.approx(1.0) and lo["F"] < 0.7


# Golden figures: the shipped fusion on the fixtures (all from the 'eval' part), measured when the
# parameters were committed (refit of 2026-11-29 for the default network v5: crack and surface w 0, corrosion
# w 0.1 at 191; v5 leaves the saliency maps little to add). The refit of 2026-11-28 for v1 (crack w 0.3 at 101,
# corrosion w 0.4 at 120) gave 0.803, 0.737; the v2 refit of 2026-11-25 0.772, 0.734.
GOLDEN = {"crack": 0.822, "corrosion": 0.791}
GOLDEN_TOL = 0.01


def test_golden_f_on_real_fixtures(model):
    counts = None
    for name in ("crackforest_004", "crackforest_014"):
        img, gt = _fixture(f"{name}.jpg", f"{name}.mask.png")
        det = fu.detect_fused(img, model, kinds=("crack",))
        c = tolerance_counts(det.mask.astype(np.uint8) * 255, gt, 2.0)
        counts = c if counts is None else counts + c
    f_crack = float(counts.prf()[2][255])
    img, gt = _fixture("vt_train_112.jpeg", "vt_train_112.mask.png")
    f_corr = mask_prf(fu.detect_fused(img, model, kinds=("corrosion",)).mask, gt)[2]
    assert f_crack == pytest.approx(GOLDEN["crack"], abs=GOLDEN_TOL), f_crack
    assert f_corr == pytest.approx(GOLDEN["corrosion"], abs=GOLDEN_TOL), f_corr


def test_cli_fused_engine_writes_the_three_outputs(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    shutil.copy(FIX / "crackforest_004.jpg", src / "a.jpg")
    shutil.copy(FIX / "vt_train_112.jpeg", src / "b.jpeg")
    out = tmp_path / "out"
    r = runner.invoke(app, ["detect", str(src), "-o", str(out), "--engine", "fused"])
    assert r.exit_code == 0, r.output
    doc = json.loads((out / "defects.json").read_text())
    assert doc["model"]["engine"] == "fused" and len(doc["images"]) == 2 and doc["regions"]
    assert set(doc["model"]["weights_saliency"]) == {"corrosion", "crack"}
    for name in ("a", "b"):
        mask = cv2.imread(str(out / f"{name}.mask.png"), cv2.IMREAD_UNCHANGED)
        assert set(np.unique(mask)) <= {0, 255}


@pytest.mark.parametrize("content,words", [
    (None, "not found"), ("{not json", "not JSON"), ('{"format": "x/9", "classes": {}}', "format"),
    ('{"format": "inspect_pipe.defect_fused/1", "classes": {"crack": {"weight_saliency": 2, "threshold_u8": 9}}}', "weight"),
    # fitted for other network weights than the ones it would mix: refused, not mixed at weights chosen for another map
    ('{"format": "inspect_pipe.defect_fused/1", "classes": {"crack": {"weight_saliency": 0.3, "threshold_u8": 101}},'
     ' "engines": {"onnx": {"file": "defects_unet_v1.onnx", "sha256": "' + "0" * 64 + '"}}}', "fitted for other onnx weights"),
])
def test_bad_parameter_file_exits_2_with_one_line(tmp_path, content, words):
    bad = tmp_path / "p.json"
    if content is not None:
        bad.write_text(content)
    r = runner.invoke(app, ["detect", str(FIX / "crackforest_004.jpg"), "-o", str(tmp_path / "o"),
                            "--engine", "fused", "--model", str(bad)])
    assert r.exit_code == 2
    lines = [ln for ln in r.output.strip().splitlines() if ln]
    assert len(lines) == 1 and lines[0].startswith("error:") and words in lines[0], r.output
