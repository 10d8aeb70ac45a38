"""Metric rectification of a mosaic with a calibrated camera.

Images of a plane alone fix a mosaic only up to one global homography; the gauge of the global
alignment (mean tilt zero) is right only on average. With the camera's focal length known, each
frame's wall-to-image homography must be ``K [r1 r2 t]``: ``K^-1 M_i`` has orthogonal columns of
equal norm. We find the one projective correction ``G`` (perspective, shear, anisotropy: the part
a similarity cannot express) that best makes every frame satisfy this (Zhang-style constraints,
two per frame, over the whole sweep).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares


def _G(p: np.ndarray, centre: np.ndarray, scale: float) -> np.ndarray:
    m, k, g, h = p
    C = np.array([[1 / scale, 0, -centre[0] / scale], [0, 1 / scale, -centre[1] / scale], [0, 0, 1]])
    core = np.array([[1, m, 0], [0, 1 + k, 0], [g, h, 1]])
    return np.linalg.inv(C) @ core @ C


def rectify(
    H: dict[int, np.ndarray], size_wh: tuple[int, int], focal_px: float, principal: tuple[float, float] | None = None
) -> tuple[dict[int, np.ndarray], float]:
    """Return homographies corrected by the best ``G`` and the RMS of the orthogonality residual
    (0 = perfectly consistent with a pinhole camera of that focal length viewing a plane)."""
    w, h = size_wh
    cx, cy = principal if principal is not None else (w / 2, h / 2)
    K = np.array([[focal_px, 0, cx], [0, focal_px, cy], [0, 0, 1]])
    Kinv = np.linalg.inv(K)
    frames = sorted(H)
    centres = np.array([(H[f] @ [w / 2, h / 2, 1])[:2] / (H[f] @ [w / 2, h / 2, 1])[2] for f in frames])
    centre = centres.mean(axis=0)
    scale = float(max(np.ptp(centres, axis=0).max(), max(w, h)))
    Hinv = [np.linalg.inv(H[f]) for f in frames]

    def residuals(p):
        G = _G(p, centre, scale)
        Ginv = np.linalg.inv(G)
        out = []
        for Hi in Hinv:
            B = Kinv @ Hi @ Ginv
            b1, b2 = B[:, 0], B[:, 1]
            n1, n2 = np.linalg.norm(b1), np.linalg.norm(b2)
            out += [b1 @ b2 / (n1 * n2), (n1 - n2) / (n1 + n2) * 2]
        return np.array(out)

    sol = least_squares(residuals, np.zeros(4), method="lm", x_scale=[0.01, 0.01, 0.01, 0.01])
    G = _G(sol.x, centre, scale)
    out = {}
    for f in frames:
        g = G @ H[f]
        out[f] = g / g[2, 2]
    return out, float(np.sqrt(np.mean(sol.fun**2)))
