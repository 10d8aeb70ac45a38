"""The detection core shared by every engine (``_core``): tile grid, uint8 conversion, decision
with and without hysteresis, and that each engine uses the one definition."""

import cv2
import numpy as np
import pytest

from inspect_pipe.saliency_defects import _core, _detect, _engines, _fused, _onnx_detect, _onnx_train
from inspect_pipe.saliency_defects._core import OPERATING_RANGE_U8, decide_u8, tiles, to_u8


@pytest.mark.parametrize("h,w,tile,margin", [(100, 130, 32, 16), (768, 769, 768, 96), (5, 7, 64, 0)])
def test_tile_cores_cover_the_image_exactly_once(h, w, tile, margin):
    seen = np.zeros((h, w), int)
    for (y0, y1, x0, x1), (ty0, ty1, tx0, tx1) in tiles(h, w, tile, margin):
        seen[y0:y1, x0:x1] += 1
        # each tile holds its core plus the margin, clipped to the image
        assert ty0 == max(y0 - margin, 0) and tx1 == min(x1 + margin, w)
        assert y0 % tile == 0 and x0 % tile == 0
    assert (seen == 1).all()


def test_to_u8_rounds_and_clips():
    p = np.array([-0.1, 0.0, 0.5 / 255, 0.51, 1.0, 1.7], np.float32)
    assert to_u8(p).tolist() == [0, 0, 0, 130, 255, 255]  # 0.5/255 rounds to even 0, 0.51*255 = 130.05
    u = np.array([3, 250], np.uint8)
    assert to_u8(u) is u


def test_hysteresis_keeps_weak_pixels_connected_to_a_strong_one():
    # GIVEN two weak blobs (p = 100), one touching a strong pixel (p = 200)
    p = np.zeros((20, 40), np.uint8)
    p[2:8, 2:10] = 100
    p[5, 5] = 200
    p[12:18, 20:30] = 100
    # WHEN decided at 150 with a low threshold of 80
    mask = decide_u8(p, 150, 1, low_u8=80)[0]
    # THEN the blob with a strong pixel is kept whole, the other dropped
    assert mask[2:8, 2:10].all() and not mask[12:18, 20:30].any()
    # without hysteresis only the strong pixel, which the speckle size then removes
    assert decide_u8(p, 150, 1)[0].sum() == 1 and decide_u8(p, 150, 2)[0].sum() == 0


def test_the_saliency_decision_is_the_core_one():
    # GIVEN the shipped saliency crack model's thresholds on a smooth random map
    from inspect_pipe.saliency_defects import default_model_path, load_model

    cm = load_model(default_model_path()).classes["crack"]
    rng = np.random.default_rng(0)
    p = cv2.GaussianBlur(rng.integers(0, 256, (120, 160)).astype(np.uint8), (0, 0), 3)
    p = cv2.normalize(p, None, 0, 255, cv2.NORM_MINMAX)
    # THEN the engine's decision equals the plain formula: components of p >= low holding a pixel
    # >= high, no smaller than min_area_px
    hi, lo = int(np.ceil(cm.threshold * 255)), min(int(np.ceil(cm.low_threshold * 255)), int(np.ceil(cm.threshold * 255)))
    n, lab, st, _ = cv2.connectedComponentsWithStats((p >= lo).astype(np.uint8), connectivity=8, ltype=cv2.CV_32S)
    keep = (np.bincount(lab[p >= hi], minlength=n) > 0) & (st[:, cv2.CC_STAT_AREA] >= cm.min_area_px)
    keep[0] = False
    assert np.array_equal(_detect.decide(p, cm)[0], keep[lab])


def test_one_definition_used_by_every_engine():
    # the default tile size, the class -> data-set map and the uint8 conversion are the core's
    assert _detect.TILE_PX is _core.TILE_PX and _onnx_detect.TILE_PX is _core.TILE_PX
    assert _fused.SET_OF_CLASS is _core.SET_OF_CLASS and _onnx_train.SET_OF_CLASS is _core.SET_OF_CLASS
    assert _onnx_detect.to_u8 is _core.to_u8 and _onnx_train.to_u8 is _core.to_u8
    assert _engines.DetectorEngine.detect.__kwdefaults__["tile_px"] == _core.TILE_PX
    lo, hi = OPERATING_RANGE_U8
    assert 0 < lo < 128 < hi < 255


@pytest.mark.parametrize("gain", [0.5, 1.0, 2.0, 6.0])
def test_map_calibration_keeps_every_decision_and_scales_the_logit(gain):
    # GIVEN every operating point the validation may choose and the crack network's 251, and a calibration gain
    v = np.arange(65536)
    for t in list(range(OPERATING_RANGE_U8[0], OPERATING_RANGE_U8[1] + 1)) + [251]:
        lut = _core.calibration_lut(t, gain)
        # THEN the map stays monotone, and a 16-bit probability reaches 128 exactly where its uint8 rounding reached t
        assert np.all(np.diff(lut.astype(int)) >= 0)
        assert np.array_equal(lut >= 128, _core.to_u8(v / 65535) >= t), t
    # AND the logit around the operating point is scaled by the gain
    logit = lambda p: np.log(p / (1 - p))  # noqa: E731
    e = (200 - 0.5) / 255
    for p in (0.6, 0.7, 0.8, 0.85, 0.9):
        assert logit(_core.calibrate(np.array([p]), 200, gain)[0]) == pytest.approx(gain * (logit(p) - logit(e)), rel=1e-6)
    # AND a saturated map keeps its resolution: the crack network's 251..255 is about 1150 16-bit levels, many calibrated ones
    assert len(np.unique(_core.calibration_lut(251, 0.75)[_core.to_u8(v / 65535) >= 251])) > 60
