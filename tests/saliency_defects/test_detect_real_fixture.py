"""Golden scores of the shipped model on a tiny real fixture (evaluation-split images).

If the shipped model is retrained on purpose, re-measure and update the GOLDEN figures."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from inspect_pipe.saliency_defects import default_model_path, detect, load_model
from inspect_pipe.saliency_defects._metrics import tolerance_counts

FIX = Path(__file__).resolve().parents[1] / "fixtures" / "defects"
GOLDEN_CRACK_F = 0.727  # 2 px tolerance, counts summed over the two CrackForest images
GOLDEN_CORROSION_F = 0.729  # strict pixel F1 on the VT image


def _load(stem, ext):
    img = cv2.imread(str(FIX / f"{stem}.{ext}"), cv2.IMREAD_COLOR)
    gt = cv2.imread(str(FIX / f"{stem}.mask.png"), cv2.IMREAD_GRAYSCALE) > 0
    assert img is not None and gt.shape == img.shape[:2]
    return img, gt


@pytest.fixture(scope="module")
def model():
    return load_model(default_model_path())


def _f(model, stems, ext, kind, tol):
    tot = None
    for s in stems:
        img, gt = _load(s, ext)
        det = detect(img, model, kinds=(kind,))
        c = tolerance_counts(det.mask.astype(np.uint8) * 255, gt, tol)
        tot = c if tot is None else tot + c
    return float(tot.prf()[2][255])


def test_crackforest_golden_f(model):
    f = _f(model, ["crackforest_004", "crackforest_014"], "jpg", "crack", 2.0)
    assert f == pytest.approx(GOLDEN_CRACK_F, abs=0.01)
    assert f > 0.65


def test_vt_corrosion_golden_f(model):
    f = _f(model, ["vt_train_112"], "jpeg", "corrosion", 0.0)
    assert f == pytest.approx(GOLDEN_CORROSION_F, abs=0.01)
    assert f > 0.5
