"""The detection core every engine shares (saliency, onnx, fused, and the onnx training's
validation): the default tile size, the tile grid, probability -> uint8, the per-class
decision (threshold, optional hysteresis, speckle removal) and the class -> data-set mapping.
Defined here once; the engines only differ in how they compute their probability maps.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator

import cv2
import numpy as np

#: Default tile core side (px) of every engine for large images (``--tile-px``): a multiple of
#: the saliency engine's pyramid alignment (64) and of the network's (16).
TILE_PX = 768

#: Operating points (uint8 thresholds) are chosen on validation images within this range, about
#: 0.1 .. 0.9 in probability: away from the ends, where a threshold only reflects how saturated
#: the network's sigmoid is (the crack threshold of the first networks sat at 251 / 255).
OPERATING_RANGE_U8 = (26, 230)

#: Class -> the labelled data set that trains and scores it (folder under data/defects).
SET_OF_CLASS = {"corrosion": "vt_corrosion_cs", "crack": "crackforest", "surface": "sd_saliency_900"}


def to_u8(p: np.ndarray) -> np.ndarray:
    """Probability map (float 0..1, or already uint8) -> uint8 0..255, rounded to nearest."""
    if p.dtype == np.uint8:
        return p
    return np.clip(np.rint(p * np.float32(255)), 0, 255).astype(np.uint8)


def calibrate(p: np.ndarray, operating_point_u8: int, gain: float) -> np.ndarray:
    """A class's float probabilities (0..1) calibrated so that its operating point is 0.5 and the
    logit around it is scaled by ``gain``: ``q = sigmoid(gain * (logit(p) - logit(e)))``, with ``e =
    (t - 0.5) / 255`` the least probability the uint8 decision at ``t`` keeps, so ``to_u8(q) >= 128``
    exactly where ``to_u8(p) >= t``. A gain below 1 spreads the map, above 1 sharpens it."""
    e = (int(operating_point_u8) - 0.5) / 255
    q = np.clip(np.asarray(p, np.float64), 1e-9, 1 - 1e-9)
    z = float(gain) * (np.log(q) - np.log1p(-q) - np.log(e / (1 - e)))
    return 1 / (1 + np.exp(-np.clip(z, -40, 40)))


@functools.lru_cache(maxsize=16)
def calibration_lut(operating_point_u8: int, gain: float) -> np.ndarray:
    """:func:`calibrate` as a table from 16-bit probabilities (``v / 65535``, index 0..65535) to the
    calibrated uint8 map. Maps are calibrated at 16 bits after their up-sampling, so a saturated
    network keeps its resolution (the first network's crack map has 5 uint8 levels above its
    operating point of 251, about 1150 at 16 bits) and every decision is kept: ``lut[v] >= 128``
    exactly where ``to_u8(v / 65535) >= t``."""
    lut = to_u8(calibrate(np.arange(65536) / 65535, operating_point_u8, gain))
    lut.flags.writeable = False
    return lut


def tiles(h: int, w: int, tile_px: int, margin_px: int) -> Iterator[tuple[tuple[int, int, int, int], tuple[int, int, int, int]]]:
    """Tile grid of an (h, w) image: for each tile ((y0, y1, x0, x1) its core, (ty0, ty1, tx0, tx1)
    the core grown by ``margin_px`` on each side, clipped to the image). Cores start on multiples
    of ``tile_px`` and cover the image exactly once."""
    for y0 in range(0, h, tile_px):
        for x0 in range(0, w, tile_px):
            y1, x1 = min(y0 + tile_px, h), min(x0 + tile_px, w)
            yield (y0, y1, x0, x1), (max(y0 - margin_px, 0), min(y1 + margin_px, h),
                                     max(x0 - margin_px, 0), min(x1 + margin_px, w))


def decide_u8(prob_u8: np.ndarray, threshold_u8: int, min_area_px: int, low_u8: int | None = None):
    """Decision of one class on its uint8 map: pixels >= ``threshold_u8`` (with ``low_u8`` below
    it: hysteresis, pixels >= low_u8 8-connected to a pixel >= threshold_u8), then connected
    components below ``min_area_px`` removed.

    Returns (mask bool, labels int32, stats, kept label ids)."""
    hi = int(threshold_u8)
    lo = hi if low_u8 is None else min(int(low_u8), hi)
    binary = cv2.threshold(np.ascontiguousarray(prob_u8, np.uint8), lo - 1, 1, cv2.THRESH_BINARY)[1]
    n, labels, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8, ltype=cv2.CV_32S)
    keep = stats[:, cv2.CC_STAT_AREA] >= min_area_px
    if lo < hi:
        keep &= np.bincount(labels[prob_u8 >= hi], minlength=n) > 0
    keep[0] = False
    drop = np.flatnonzero(~keep[1:]) + 1
    if len(drop) > 64:
        return keep[labels], labels, stats, np.flatnonzero(keep)
    mask = binary.view(bool)  # few components to drop: clear them inside their boxes
    for i in drop:
        x, y, w, h = (int(v) for v in stats[i, :4])
        box = mask[y:y + h, x:x + w]
        box[labels[y:y + h, x:x + w] == i] = False
    return mask, labels, stats, np.flatnonzero(keep)
