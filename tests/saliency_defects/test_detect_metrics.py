"""Scores: tolerance precision/recall, saliency curves."""

import numpy as np

from inspect_pipe.saliency_defects._metrics import best_f, mask_prf, saliency_curves, tolerance_counts


def test_tolerance_counts_accept_a_two_pixel_shift_only():
    gt = np.zeros((40, 40), bool)
    gt[20, 5:35] = True
    pred = np.zeros_like(gt)
    pred[22, 5:35] = True  # 2 px off: inside the tolerance
    assert mask_prf(pred, gt, tol=2) == (1.0, 1.0, 1.0)
    pred3 = np.zeros_like(gt)
    pred3[23, 5:35] = True  # 3 px off: outside
    p, r, f = mask_prf(pred3, gt, tol=2)
    assert p == 0.0 and r == 0.0
    assert mask_prf(pred, gt, tol=0)[2] == 0.0


def test_threshold_sweep_finds_the_separating_level():
    gt = np.zeros((50, 50), bool)
    gt[10:20, 10:20] = True
    prob = np.where(gt, 0.8, 0.3).astype(np.float32)
    f, t = best_f(tolerance_counts(prob, gt, tol=0))
    assert f == 1.0
    assert round(0.3 * 255) < t <= round(0.8 * 255)


def test_saliency_curves_auc_of_perfect_and_inverted_maps():
    gt = np.zeros((30, 30), bool)
    gt[:10] = True
    _, _, auc = saliency_curves(gt.astype(np.float32), gt)
    assert auc == 1.0
    _, _, auc_inv = saliency_curves((~gt).astype(np.float32), gt)
    assert auc_inv == 0.0
