"""Screening of register candidates: what is left out of the register, and why.

Three rules, applied in this order to every candidate ``build_defects`` found; each one left out is
kept as a ``Suppressed`` row (class, place, reason) so the report can say what it dropped:

1. **Outside the survey.** The centroid must lie inside the surveyed wall region (the survey's
   ``region_wall_m``, else the simulated wall's texture, else the mosaic's extent), on an imaged
   mosaic pixel, and not below the tank top (``v < tank_top_v_m``: the floor-wall seam).
2. **Seams and plate edges.** A crack candidate whose pixels lie on a straight line (RMS distance
   to the fitted line at most ``seam_straight_rms_m``) is a seam or plate edge when it is itself at
   least ``seam_length_m`` long, or when the crack probability stays high along the line beyond
   both its ends: a long straight edge gives the detector a ridge that only its strongest stretches
   turn into detections. Along ``seam_extension_m`` on each side, the fraction of mosaic pixels on
   the line whose crack probability (its maximum within 3 px across the line) is at least
   ``seam_prob`` must reach ``seam_support``, along the best of the lines within 6 degrees and
   2 px of the fitted one (a short piece fixes a long edge's direction only to a few degrees).
   A real crack meanders (its fit residual is
   centimetres) and the line through a straight stretch of it leaves the crack within centimetres.
3. **Confirmation across frames.** A candidate that keyframes saw (its whole box inside their
   footprint: a defect the frame border cuts may not be detected on that frame; each keyframe is
   detected on its own, undistorted) must be found by at least ``confirm_fraction`` of them,
   rounded up and at least one, within ``confirm_tolerance_m``. A candidate no keyframe saw whole
   stands on the mosaic's detection and is marked "mosaic only".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ._register import Defect, RegisterParams


@dataclass(frozen=True)
class Suppressed:
    cls: str
    centroid_wall_m: tuple[float, float]
    area_m2: float
    length_m: float | None
    rule: str  # "outside", "seam", "unconfirmed"
    reason: str

    def to_json(self) -> dict:
        return {"class": self.cls, "centroid_wall_m": [round(self.centroid_wall_m[0], 3), round(self.centroid_wall_m[1], 3)],
                "area_m2": round(self.area_m2, 6), "length_m": None if self.length_m is None else round(self.length_m, 3),
                "rule": self.rule, "reason": self.reason}


def _pixels(d: Defect, mask: np.ndarray) -> np.ndarray:
    """(N, 2) x, y mosaic pixels of the class mask inside the candidate's outline."""
    x, y, w, h = d.bbox_mosaic_xywh
    fill = np.zeros((h + 2, w + 2), np.uint8)
    poly = np.asarray(d.polygon_mosaic_px, np.int32) - np.array([x - 1, y - 1])
    cv2.fillPoly(fill, [poly], 1)
    cv2.polylines(fill, [poly], True, 1)
    sub = mask[max(0, y - 1):y + h + 1, max(0, x - 1):x + w + 1]
    fill = fill[: sub.shape[0], : sub.shape[1]]
    ys, xs = np.nonzero(sub & (fill > 0))
    return np.c_[xs + max(0, x - 1), ys + max(0, y - 1)].astype(float)


def line_fit(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float, float]:
    """Total least squares line through ``pts``: (centre, unit direction, RMS residual px,
    t_min, t_max along the direction)."""
    c = pts.mean(0)
    _, _, vt = np.linalg.svd(pts - c, full_matrices=False)
    d = vt[0]
    n = np.array([-d[1], d[0]])
    t = (pts - c) @ d
    r = (pts - c) @ n
    return c, d, float(math.sqrt(np.mean(r ** 2))), float(t.min()), float(t.max())


def ridge_support(ridge: np.ndarray, valid: np.ndarray, c, d, t0: float, t1: float, ext_px: float, level: float) -> float | None:
    """Fraction of imaged pixels on the line beyond both ends (``ext_px`` each side) where
    ``ridge`` (crack probability, max-filtered across the line) reaches ``level``; None when less
    than a third of that extension is imaged."""
    ts = np.r_[np.arange(t0 - ext_px, t0 - 3.0), np.arange(t1 + 3.0, t1 + ext_px)]
    if len(ts) == 0:
        return None
    p = np.asarray(c) + np.outer(ts, d)
    H, W = valid.shape
    xi, yi = np.round(p[:, 0]).astype(int), np.round(p[:, 1]).astype(int)
    inside = (xi >= 0) & (yi >= 0) & (xi < W) & (yi < H)
    xi, yi = xi[inside], yi[inside]
    on = valid[yi, xi]
    if on.sum() < len(ts) / 3:
        return None
    return float(np.mean(ridge[yi[on], xi[on]] >= level))


def best_ridge_support(ridge, valid, c, d, t0: float, t1: float, ext_px: float, level: float,
                       angles_deg=tuple(range(-6, 7)), offsets_px=(-2, -1, 0, 1, 2)) -> float | None:
    """``ridge_support`` of the best line through the detection: its fitted direction turned by up
    to 6 degrees and moved by up to 2 px across (a 5 cm piece fixes the direction of a 3 m edge
    only to a few degrees; at 30 cm, 4 degrees is 2 cm off the edge)."""
    a0 = math.atan2(d[1], d[0])
    best = None
    for da in angles_deg:
        dd = np.array([math.cos(a0 + math.radians(da)), math.sin(a0 + math.radians(da))])
        n = np.array([-dd[1], dd[0]])
        for off in offsets_px:
            s = ridge_support(ridge, valid, np.asarray(c) + n * off, dd, t0, t1, ext_px, level)
            if s is not None and (best is None or s > best):
                best = s
    return best


def screen_defects(
    defects: list[Defect],
    masks: dict[str, np.ndarray],
    probs: dict[str, np.ndarray],
    m_per_px: float,
    region_wall_m: tuple[float, float, float, float],
    tank_top_v_m: float,
    valid: np.ndarray,
    *,
    params: RegisterParams = RegisterParams(),
) -> tuple[list[Defect], list[Suppressed]]:
    """The candidates that pass the three rules (module docstring), and the others with why."""
    u0, v0, u1, v1 = region_wall_m
    kept: list[Defect] = []
    dropped: list[Suppressed] = []
    ridge = None

    def drop(d: Defect, rule: str, reason: str) -> None:
        dropped.append(Suppressed(d.cls, d.centroid_wall_m, d.area_m2, d.length_m, rule, reason))

    for d in defects:
        u, v = d.centroid_wall_m
        pts = _pixels(d, masks[d.cls]) if d.cls in masks and d.polygon_mosaic_px else np.zeros((0, 2))
        if len(pts):
            cx, cy = pts.mean(0)
        else:
            x, y, w, h = d.bbox_mosaic_xywh
            cx, cy = x + w / 2, y + h / 2
        if v < tank_top_v_m:
            drop(d, "outside", f"below the tank top (v {v:.3f} m < {tank_top_v_m:.2f} m)")
            continue
        if not (u0 <= u <= u1 and v0 <= v <= v1):
            drop(d, "outside", f"outside the surveyed region u {u0:.2f}-{u1:.2f} m, v {v0:.2f}-{v1:.2f} m")
            continue
        yi, xi = min(max(int(round(cy)), 0), valid.shape[0] - 1), min(max(int(round(cx)), 0), valid.shape[1] - 1)
        if not valid[yi, xi]:
            drop(d, "outside", "centre on a part of the mosaic no frame imaged")
            continue
        if d.cls == "crack":
            if len(pts) >= 5:
                c, dv, rms_px, t0, t1 = line_fit(pts)
                rms_m = rms_px * m_per_px
                length_m = (t1 - t0) * m_per_px
                if rms_m <= params.seam_straight_rms_m:
                    if length_m >= params.seam_length_m:
                        drop(d, "seam", f"straight ({rms_m * 1000:.1f} mm RMS off a line) and {length_m * 100:.0f} cm long: a seam or plate edge")
                        continue
                    if ridge is None and d.cls in probs:
                        ridge = cv2.dilate(probs[d.cls], np.ones((7, 7), np.uint8))
                    if ridge is not None:
                        s = best_ridge_support(ridge, valid, c, dv, t0, t1, params.seam_extension_m / m_per_px, params.seam_prob * 255)
                        if s is not None and s >= params.seam_support:
                            drop(d, "seam", f"straight ({rms_m * 1000:.1f} mm RMS off a line) and the crack response continues along the line "
                                            f"({100 * s:.0f} % of {100 * params.seam_extension_m:.0f} cm each side): a seam or plate edge")
                            continue
        if len(d.keyframes_seen) >= params.confirm_min_seen:
            need = max(1, math.ceil(params.confirm_fraction * len(d.keyframes_seen) - 1e-9))
            if len(d.keyframes_detected) < need:
                drop(d, "unconfirmed", f"found by {len(d.keyframes_detected)} of the {len(d.keyframes_seen)} keyframes that saw it (needs {need})")
                continue
        kept.append(d)
    return kept, dropped


def confirmation_text(params: RegisterParams = RegisterParams()) -> str:
    """The confirmation rule in words, for the report."""
    pct = int(round(100 * params.confirm_fraction))
    return (f"an entry that keyframes saw whole (its box inside the frame) is kept when at least {pct} % of them (rounded up, at least one) "
            f"found it on their own undistorted frame within {params.confirm_tolerance_m * 100:.0f} cm; an entry no keyframe saw whole rests "
            "on the mosaic's detection (marked \"mosaic only\")")


@dataclass(frozen=True)
class Precision:
    """How finely the register's figures can be given. Positions: the wall fit's RMS residual
    (mosaic against odometry; 2 mosaic pixels without a fit), shown to the mm below 3 mm, to the
    cm below 3 cm, else to 10 cm. Areas: the change of moving an outline by one mosaic pixel
    (perimeter x pixel size), shown in cm² to 1 cm² (0.1 cm² for entries whose uncertainty is
    below 1 cm²); lengths to the cm."""

    position_sigma_m: float
    position_step_m: float
    pixel_m: float
    source: str

    @classmethod
    def of(cls, m_per_px: float, fit_rms_m: float | None) -> "Precision":
        sigma = float(fit_rms_m) if fit_rms_m else 2.0 * m_per_px
        step = 0.001 if sigma < 0.003 else 0.01 if sigma < 0.03 else 0.1
        src = "wall fit RMS (mosaic against odometry)" if fit_rms_m else "two mosaic pixels (no wall fit)"
        return cls(sigma, step, m_per_px, src)

    @property
    def position_decimals(self) -> int:
        return max(0, int(round(-math.log10(self.position_step_m))))

    def pos(self, x: float) -> str:
        return f"{x:.{self.position_decimals}f}"

    def area_sigma_m2(self, d: Defect) -> float:
        p = np.asarray(d.polygon_wall_m, float)
        per = float(np.linalg.norm(np.diff(np.vstack([p, p[:1]]), axis=0), axis=1).sum()) if len(p) >= 2 else 0.0
        return per * self.pixel_m

    def area_cm2(self, d: Defect) -> str:
        a, s = d.area_m2 * 1e4, self.area_sigma_m2(d) * 1e4
        return f"{a:.0f} ± {max(s, 1):.0f}" if s >= 1 else f"{a:.1f} ± {s:.1f}"

    def length_cm(self, d: Defect) -> str:
        return "" if d.length_m is None else f"{d.length_m * 100:.0f}"

    def to_json(self) -> dict:
        return {"position_sigma_m": round(self.position_sigma_m, 4), "position_step_m": self.position_step_m,
                "position_source": self.source, "area": "outline moved by one mosaic pixel (perimeter x pixel size), cm²",
                "pixel_m": round(self.pixel_m, 5), "length_step_m": 0.01}
