"""Scores used by training (operating point), tests and the benchmark.

All threshold sweeps are done with histograms over 256 probability levels, so one pass over an
image gives the counts at every threshold. Probability maps are uint8 (0..255) or float in [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ._core import to_u8  # noqa: F401  (the one uint8 conversion, re-exported for the benches)

LEVELS = 256


def _disc(radius: float) -> np.ndarray:
    r = int(np.floor(radius))
    yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
    return (xx * xx + yy * yy <= radius * radius + 1e-9).astype(np.uint8)


def _cum_ge(values: np.ndarray) -> np.ndarray:
    """counts[t] = number of ``values`` >= t, for t in 0..255 (values uint8)."""
    h = np.bincount(values.ravel(), minlength=LEVELS)[:LEVELS]
    return np.cumsum(h[::-1])[::-1].astype(np.int64)


@dataclass
class ToleranceCounts:
    """Counts at the 256 thresholds t (decision: prob_u8 >= t), summable over images.

    ``tp_pred[t]``: detected pixels within ``tol`` px of a GT pixel; ``n_pred[t]``: detected
    pixels; ``tp_gt[t]``: GT pixels within ``tol`` px of a detection; ``n_gt``: GT pixels.
    """

    tp_pred: np.ndarray
    n_pred: np.ndarray
    tp_gt: np.ndarray
    n_gt: int

    def __add__(self, other: "ToleranceCounts") -> "ToleranceCounts":
        return ToleranceCounts(
            self.tp_pred + other.tp_pred,
            self.n_pred + other.n_pred,
            self.tp_gt + other.tp_gt,
            self.n_gt + other.n_gt,
        )

    def prf(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Precision, recall and F per threshold (arrays of 256)."""
        p = self.tp_pred / np.maximum(self.n_pred, 1)
        r = self.tp_gt / max(self.n_gt, 1)
        f = 2 * p * r / np.maximum(p + r, 1e-12)
        p = np.where(self.n_pred > 0, p, 1.0)
        return p, r, f


def tolerance_counts(prob: np.ndarray, gt: np.ndarray, tol: float = 2.0) -> ToleranceCounts:
    """Tolerance-based precision/recall counts of ``prob`` against boolean ``gt`` (H, W).

    tol = 0 gives strict pixel counts. A GT pixel counts as found at threshold t when the largest
    probability within ``tol`` px (Euclidean) is >= t; a detected pixel is correct when a GT pixel
    lies within ``tol`` px.
    """
    p8 = to_u8(prob)
    g = gt.astype(bool)
    if tol > 0:
        k = _disc(tol)
        near_gt = cv2.dilate(g.astype(np.uint8), k).astype(bool)
        pmax = cv2.dilate(p8, k)
    else:
        near_gt, pmax = g, p8
    n_pred = _cum_ge(p8)
    tp_pred = _cum_ge(p8[near_gt])
    tp_gt = _cum_ge(pmax[g])
    return ToleranceCounts(tp_pred, n_pred, tp_gt, int(g.sum()))


def mask_prf(mask: np.ndarray, gt: np.ndarray, tol: float = 0.0) -> tuple[float, float, float]:
    """Precision, recall, F of a binary decision ``mask`` against ``gt``."""
    c = tolerance_counts(mask.astype(bool).astype(np.uint8) * 255, gt, tol)
    p, r, f = c.prf()
    return float(p[255]), float(r[255]), float(f[255])


def best_f(counts: ToleranceCounts, lo: int = 1, hi: int = 255) -> tuple[float, int]:
    """(max F, threshold level lo..hi achieving it): with the full range 1..255, the ODS figure
    when counts are summed; operating points use the core's OPERATING_RANGE_U8."""
    _, _, f = counts.prf()
    t = int(np.argmax(f[lo:hi + 1]) + lo)
    return float(f[t]), t


def saliency_curves(prob: np.ndarray, gt: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Salient-object protocol for one image: min-max normalise, then precision and recall at
    256 thresholds and the pixel ROC-AUC. Returns (P[256], R[256], auc)."""
    p = prob.astype(np.float32)
    lo, hi = float(p.min()), float(p.max())
    p8 = np.zeros(p.shape, np.uint8) if hi <= lo else np.rint((p - lo) / (hi - lo) * 255).astype(np.uint8)
    g = gt.astype(bool)
    tp = _cum_ge(p8[g])
    fp = _cum_ge(p8[~g])
    n_pos, n_neg = int(g.sum()), int((~g).sum())
    prec = tp / np.maximum(tp + fp, 1)
    rec = tp / max(n_pos, 1)
    if n_pos == 0 or n_neg == 0:
        auc = float("nan")
    else:
        # AUC from the two histograms: P(score_pos > score_neg) + 0.5 P(equal)
        hp = np.bincount(p8[g], minlength=LEVELS).astype(np.float64)
        hn = np.bincount(p8[~g], minlength=LEVELS).astype(np.float64)
        below = np.concatenate([[0.0], np.cumsum(hn)[:-1]])
        auc = float((hp * (below + 0.5 * hn)).sum() / (n_pos * n_neg))
    return prec, rec, auc


def max_fbeta(precisions: list[np.ndarray], recalls: list[np.ndarray], beta2: float = 0.3) -> float:
    """Max over thresholds of F-beta of the image-averaged precision and recall curves."""
    p = np.mean(precisions, axis=0)
    r = np.mean(recalls, axis=0)
    f = (1 + beta2) * p * r / np.maximum(beta2 * p + r, 1e-12)
    return float(f.max())


def state_confusion(pred: np.ndarray, gt: np.ndarray, n_states: int = 4) -> np.ndarray:
    """(n_states, n_states) pixel counts, rows the true condition state, columns the predicted
    one (0 none / good, 1 fair, 2 poor, 3 severe); summable over images."""
    idx = gt.astype(np.int64).ravel() * n_states + pred.astype(np.int64).ravel()
    return np.bincount(idx, minlength=n_states * n_states)[: n_states * n_states].reshape(n_states, n_states)


def state_f1(conf: np.ndarray) -> np.ndarray:
    """Per-pixel F1 of each state from a confusion matrix (index 0 is 'none')."""
    tp = np.diag(conf).astype(np.float64)
    denom = conf.sum(0) + conf.sum(1)
    return np.where(denom > 0, 2 * tp / np.maximum(denom, 1), 0.0)
