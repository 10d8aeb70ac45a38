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
    Hinv = np.array([np.linalg.inv(H[f]) for f in frames])

    def residuals(p):
        Ginv = np.linalg.inv(_G(p, centre, scale))
        B = Kinv @ Hinv @ Ginv
        b1, b2 = B[:, :, 0], B[:, :, 1]
        n1, n2 = np.linalg.norm(b1, axis=1), np.linalg.norm(b2, axis=1)
        return np.concatenate([(b1 * b2).sum(1) / (n1 * n2), (n1 - n2) / (n1 + n2) * 2])

    sol = least_squares(residuals, np.zeros(4), method="lm", x_scale=[0.01, 0.01, 0.01, 0.01])
    G = _G(sol.x, centre, scale)
    out = {}
    for f in frames:
        g = G @ H[f]
        out[f] = g / g[2, 2]
    return out, float(np.sqrt(np.mean(sol.fun**2)))


def focals_from_homography(H: np.ndarray) -> tuple[float | None, float | None]:
    """OpenCV's ``detail::focalsFromHomography`` (Shum & Szeliski), for a pair homography in
    centred pixel coordinates, assuming a camera rotating about its centre. (The Python binding of
    the OpenCV function drops its output arguments, so the formula is restated here.)"""
    h = (H / H[2, 2]).ravel()

    def pick(d1: float, d2: float, v1: float, v2: float) -> float | None:
        if v1 < v2:
            v1, v2 = v2, v1
        if v1 > 0 and v2 > 0:
            return float(np.sqrt(v1 if abs(d1) > abs(d2) else v2))
        return float(np.sqrt(v1)) if v1 > 0 else None

    with np.errstate(divide="ignore", invalid="ignore"):
        d1, d2 = h[6] * h[7], (h[7] - h[6]) * (h[7] + h[6])
        f1 = pick(d1, d2, -(h[0] * h[1] + h[3] * h[4]) / d1, (h[0] ** 2 + h[3] ** 2 - h[1] ** 2 - h[4] ** 2) / d2)
        d1, d2 = h[0] * h[3] + h[1] * h[4], h[0] ** 2 + h[1] ** 2 - h[3] ** 2 - h[4] ** 2
        f0 = pick(d1, d2, -h[2] * h[5] / d1, (h[5] ** 2 - h[2] ** 2) / d2)
    ok = lambda v: v if v is not None and np.isfinite(v) else None  # noqa: E731
    return ok(f0), ok(f1)


def estimate_focal(pair_H: list[np.ndarray], size_wh: tuple[int, int]) -> float | None:
    """OpenCV's ``estimateFocal``: the median of sqrt(f0 f1) over the pairs where both are found."""
    w, h = size_wh
    C = np.array([[1, 0, w / 2], [0, 1, h / 2], [0, 0, 1.0]])
    Cinv = np.linalg.inv(C)
    found = []
    for H in pair_H:
        f0, f1 = focals_from_homography(Cinv @ H @ C)
        if f0 and f1:
            found.append(np.sqrt(f0 * f1))
    return float(np.median(found)) if found else None


def focal_from_layout(
    H: dict[int, np.ndarray], size_wh: tuple[int, int], principal: tuple[float, float] | None,
    f_range: tuple[float, float], seeds: tuple[float, ...] = (),
) -> tuple[float, float]:
    """Self-calibration from a sweep's frame -> mosaic homographies: the focal length whose
    metric rectification leaves the smallest pinhole-consistency residual (a log-spaced scan,
    plus ``seeds``, then a bounded 1-D refinement). Returns (focal px, residual)."""
    from scipy.optimize import minimize_scalar

    cand = sorted({*np.geomspace(f_range[0], f_range[1], 13), *(s for s in seeds if f_range[0] <= s <= f_range[1])})
    res = [rectify(H, size_wh, f, principal)[1] for f in cand]
    k = int(np.argmin(res))
    lo, hi = np.log(cand[max(k - 1, 0)]), np.log(cand[min(k + 1, len(cand) - 1)])
    if hi - lo < 1e-9:
        return float(cand[k]), float(res[k])
    sol = minimize_scalar(lambda lf: rectify(H, size_wh, float(np.exp(lf)), principal)[1], bounds=(lo, hi), method="bounded",
                          options={"xatol": 1e-3})
    return (float(np.exp(sol.x)), float(sol.fun)) if sol.fun <= res[k] else (float(cand[k]), float(res[k]))
