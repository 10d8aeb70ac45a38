"""Image -> per-class probability maps -> decisions -> regions; tiled for large images."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ._core import TILE_PX, decide_u8, tiles, to_u8
from ._features import ALIGN, SUPPORT_PX, FeatureStack, check_image, compute_features
from ._model import (
    ClassModel,
    DefectModel,
    class_logit,
    context_reach_px,
    sigmoid,
    to_full_res,
)

#: Default tile core size: the core's TILE_PX (768 px, a multiple of ALIGN). A tile of 768 + 2 x
#: 448 px holds the crack class's 7 full-resolution float32 maps, corrosion's 22 at half
#: resolution and the shared pyramids at once: a few hundred MB, independent of the image size.
#: Images of at most this many tile areas are processed whole (see class_probabilities_u8).
WHOLE_TILES = 5.5


#: Condition states of corrosion (AASHTO, as labelled in the VT corrosion set); the severity map
#: holds 0 (no corrosion) or 1 + the index here.
SEVERITY_STATES = ("fair", "poor", "severe")


@dataclass(frozen=True)
class Region:
    """One connected defect region of a class's decision mask (pixel coordinates, x right, y down)."""

    cls: str
    polygon_px: tuple[tuple[int, int], ...]  # outer boundary, simplified to 1 px
    area_px: int
    confidence: float  # mean defect probability over the region's pixels, 0..1
    bbox_xywh: tuple[int, int, int, int]
    #: Corrosion regions of an engine with a condition-state head (onnx, fused): the share of the
    #: region's pixels in each state, fair / poor / severe; None otherwise (saliency engine, cracks).
    state_fractions: tuple[float, float, float] | None = None

    @property
    def severity(self) -> str | None:
        """The region's condition state: the state of most of its pixels (fair | poor | severe)."""
        if self.state_fractions is None:
            return None
        return SEVERITY_STATES[int(np.argmax(self.state_fractions))]

    def to_json(self) -> dict:
        doc = {
            "class": self.cls,
            "polygon_px": [list(p) for p in self.polygon_px],
            "area_px": self.area_px,
            "confidence": round(self.confidence, 4),
            "bbox_xywh": list(self.bbox_xywh),
        }
        if self.state_fractions is not None:
            doc["severity"] = {"state": self.severity,
                               "fractions": {k: round(float(v), 4) for k, v in zip(SEVERITY_STATES, self.state_fractions)}}
        return doc


@dataclass(frozen=True)
class Detection:
    """Result for one image. ``prob``: (H, W) uint8, 0..255 = P(defect of any requested class),
    the largest of the class maps; ``mask``: (H, W) bool, union of the class decisions;
    ``severity``: (H, W) uint8 condition state of the decided corrosion pixels (0 none, 1 fair,
    2 poor, 3 severe), None when the engine has no condition-state head or corrosion was not
    asked for."""

    prob: np.ndarray
    mask: np.ndarray
    class_probs: dict[str, np.ndarray]
    regions: tuple[Region, ...]
    severity: np.ndarray | None = None


def _margin_px(model: DefectModel, kinds) -> int:
    m = max(
        SUPPORT_PX
        + 2**c.level * (sum(context_reach_px(st.names) for st in c.stages[1:]) + int(np.ceil(4 * c.smooth_sigma_px)) + 1)
        for c in (model.classes[k] for k in kinds)
    )
    return int(np.ceil(m / ALIGN) * ALIGN)


def class_features(image: np.ndarray, cms) -> dict[int, FeatureStack]:
    """The feature stacks the class models ``cms`` need: one per pyramid level, each holding the
    union of those classes' features (computed once, shared between classes)."""
    names: dict[int, list[str]] = {}
    for cm in cms:
        lst = names.setdefault(cm.level, [])
        lst += [n for n in cm.feature_names if n not in lst]
    shared: dict = {}  # pyramids and centre-surround maps, computed once for both levels
    return {lv: compute_features(image, ns, level=lv, shared=shared) for lv, ns in sorted(names.items())}


def class_logits(image: np.ndarray, cms, *, naive: bool = False) -> dict[str, np.ndarray]:
    """Final logit map (H, W) float32 at the image's resolution of each class model in ``cms``."""
    fss = class_features(image, cms)
    hw = image.shape[:2]
    return {cm.name: to_full_res(class_logit(fss[cm.level], cm, naive=naive), hw, cm.level) for cm in cms}


def class_probabilities(image: np.ndarray, model: DefectModel, kinds, *, naive: bool = False) -> dict[str, np.ndarray]:
    """P(defect of class k | features) for each k in ``kinds``, (H, W) float32, whole image at once."""
    zs = class_logits(image, [model.classes[k] for k in kinds], naive=naive)
    return {k: sigmoid(zs[k]) for k in kinds}


def class_probabilities_u8(
    image: np.ndarray, model: DefectModel, kinds, *, tile_px: int = TILE_PX
) -> dict[str, np.ndarray]:
    """Like :func:`class_probabilities` but uint8 and processed in overlapping tiles when the
    image is larger than WHOLE_TILES tiles, so memory stays bounded; tile cores are aligned to the
    pyramid grid, so the result equals whole-image processing up to float rounding except within
    the margin of the image's own border effects."""
    h, w = image.shape[:2]
    if tile_px % ALIGN:
        raise ValueError(f"tile_px must be a multiple of {ALIGN}")
    # tiles cost their margins (2-4x the pixels at 768 px), so a frame up to WHOLE_TILES tile
    # areas (3 Mpx at the default) is processed at once: ~0.5 GB, still bounded
    if h * w <= WHOLE_TILES * tile_px * tile_px:
        return {k: to_u8(p) for k, p in class_probabilities(image, model, kinds).items()}
    m = _margin_px(model, kinds)
    out = {k: np.zeros((h, w), np.uint8) for k in kinds}
    for (y0, y1, x0, x1), (ty0, ty1, tx0, tx1) in tiles(h, w, tile_px, m):
        tile = np.ascontiguousarray(image[ty0:ty1, tx0:tx1])
        probs = class_probabilities(tile, model, kinds)
        for k, p in probs.items():
            out[k][y0:y1, x0:x1] = to_u8(p[y0 - ty0 : y1 - ty0, x0 - tx0 : x1 - tx0])
        del probs, tile
    return out


def decide(prob_u8: np.ndarray, cm: ClassModel) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Decision mask of one class: the core's :func:`decide_u8` with hysteresis (pixels >= the
    low threshold 8-connected to a pixel >= the threshold), components below ``min_area_px``
    removed.

    Returns (mask bool, labels int32, stats, kept label ids)."""
    hi = int(np.ceil(cm.threshold * 255))
    return decide_u8(prob_u8, hi, cm.min_area_px, int(np.ceil(cm.low_threshold * 255)))


def regions_of(cls: str, prob_u8: np.ndarray, labels: np.ndarray, stats: np.ndarray, ids,
               states: np.ndarray | None = None) -> list[Region]:
    """One :class:`Region` per kept component id; with ``states`` (a condition-state map, 1..3 on
    the region's pixels) each region gets the share of each state."""
    regions = []
    if len(ids) == 0:
        return regions
    # mean probability of every component: inside each box when the boxes cover at most the image
    # once, else in one pass over the image in row bands (bounded temporaries on mosaics)
    boxes = int((stats[ids, cv2.CC_STAT_WIDTH].astype(np.int64) * stats[ids, cv2.CC_STAT_HEIGHT]).sum())
    sums = None
    if boxes > labels.size:
        sums = np.zeros(stats.shape[0])
        band = max(1, (1 << 20) // max(labels.shape[1], 1))
        for y0 in range(0, labels.shape[0], band):
            sums += np.bincount(labels[y0 : y0 + band].ravel(), weights=prob_u8[y0 : y0 + band].ravel(),
                                minlength=stats.shape[0])
    for i in ids:
        x, y, w, h, area = (int(v) for v in stats[i])
        inside = labels[y : y + h, x : x + w] == i
        roi = inside.view(np.uint8)
        contours, _ = cv2.findContours(roi, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE, offset=(x, y))
        c = max(contours, key=cv2.contourArea)
        poly = cv2.approxPolyDP(c, 1.0, True).reshape(-1, 2).tolist()
        total = float(sums[i]) if sums is not None else float(prob_u8[y : y + h, x : x + w][inside].sum(dtype=np.int64))
        conf = total / (area * 255.0)
        fr = None
        if states is not None:
            n = np.bincount(states[y : y + h, x : x + w][inside], minlength=4)[1:4].astype(np.float64)
            fr = tuple(float(v) for v in n / max(n.sum(), 1))
        regions.append(Region(cls, tuple((a, b) for a, b in poly), area, conf, (x, y, w, h), fr))
    return regions


def detect(
    image: np.ndarray,
    model: DefectModel,
    *,
    kinds: tuple[str, ...] = ("corrosion", "crack"),
    tile_px: int = TILE_PX,
) -> Detection:
    """Detect defects of the classes ``kinds`` in an 8-bit BGR (or grey) image (H, W[, 3]).

    Raises ValueError for an unusable image, an unknown class, or a colour class on a grey image.
    """
    check_image(image)
    for k in kinds:
        if k not in model.classes:
            raise ValueError(f"model has no class {k!r} (has {', '.join(model.classes)})")
    grey = image.ndim == 2 or image.shape[2] == 1
    for k in kinds:
        if grey and model.classes[k].needs_colour:
            raise ValueError(f"one-channel image: {k} needs colour")
    probs = class_probabilities_u8(image, model, kinds, tile_px=tile_px)
    h, w = image.shape[:2]
    mask = np.zeros((h, w), bool)
    regions: list[Region] = []
    for k in kinds:
        m, labels, stats, ids = decide(probs[k], model.classes[k])
        mask |= m
        del m
        regions += regions_of(k, probs[k], labels, stats, ids)
        del labels
    prob = probs[kinds[0]].copy() if len(kinds) == 1 else np.maximum.reduce([probs[k] for k in kinds])
    return Detection(prob, mask, probs, tuple(regions))
