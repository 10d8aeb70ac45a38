"""Accuracy of a mosaic against ground-truth frame-to-wall homographies (benchmarks and tests).

All inputs are plain arrays: ``H_est[i]`` frame px -> mosaic px, ``H_gt[i]`` frame px -> wall
(canvas) px. Frames missing from ``H_est`` are simply not scored.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ._pairs import footprint, overlap_fraction


def _apply(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    p = np.c_[pts, np.ones(len(pts))] @ H.T
    return p[:, :2] / p[:, 2:3]


def _grid(size_wh: tuple[int, int], nx: int, ny: int) -> np.ndarray:
    w, h = size_wh
    xs, ys = np.meshgrid(np.linspace(0, w - 1, nx), np.linspace(0, h - 1, ny))
    return np.c_[xs.ravel(), ys.ravel()]


@dataclass(frozen=True)
class Misalignment:
    rmse_px: float
    p95_px: float
    max_px: float
    n_pairs: int

    def as_row(self) -> str:
        return f"{self.rmse_px:.2f} / {self.p95_px:.2f} / {self.max_px:.2f}"


def _stats(err: list[np.ndarray], n_pairs: int) -> Misalignment:
    if not err:
        return Misalignment(float("nan"), float("nan"), float("nan"), 0)
    e = np.concatenate(err)
    return Misalignment(float(np.sqrt(np.mean(e**2))), float(np.percentile(e, 95)), float(e.max()), n_pairs)


def misalignment(
    H_est: dict[int, np.ndarray],
    H_gt: dict[int, np.ndarray],
    size_wh: tuple[int, int],
    *,
    group_of: dict[int, int] | None = None,
    neighbour_gap: int = 2,
    min_overlap: float = 0.1,
) -> tuple[Misalignment, Misalignment]:
    """(neighbours, cross-pass): distance in the mosaic between the two placements of the same
    wall point seen by two overlapping frames. Neighbours are at most ``neighbour_gap`` apart in time."""
    frames = sorted(f for f in H_est if f in H_gt)
    polys = {f: footprint(H_gt[f], size_wh) for f in frames}
    grid = _grid(size_wh, 16, 12)
    w, h = size_wh
    near, far = [], []
    n_near = n_far = 0
    for a, i in enumerate(frames):
        for j in frames[a + 1 :]:
            if group_of is not None and group_of.get(i) != group_of.get(j):
                continue
            if np.linalg.norm(polys[i].mean(0) - polys[j].mean(0)) > np.hypot(w, h):
                continue
            if overlap_fraction(polys[i], polys[j]) < min_overlap:
                continue
            pj = _apply(np.linalg.inv(H_gt[j]) @ H_gt[i], grid)
            inside = (pj[:, 0] >= 0) & (pj[:, 0] <= w - 1) & (pj[:, 1] >= 0) & (pj[:, 1] <= h - 1)
            if inside.sum() < 4:
                continue
            e = np.linalg.norm(_apply(H_est[i], grid[inside]) - _apply(H_est[j], pj[inside]), axis=1)
            if j - i <= neighbour_gap:
                near.append(e)
                n_near += 1
            else:
                far.append(e)
                n_far += 1
    return _stats(near, n_near), _stats(far, n_far)


@dataclass(frozen=True)
class GlobalShape:
    rms_px: float
    max_px: float
    scale: float  # wall px per mosaic px of the best similarity
    scale_error: float  # relative to the frames' mean true scale
    similarity: np.ndarray  # 2x3 mosaic px -> wall px


def global_shape(H_est: dict[int, np.ndarray], H_gt: dict[int, np.ndarray], size_wh: tuple[int, int]) -> GlobalShape:
    """Fit one similarity mosaic -> wall over grid points of every frame; the residual is the
    mosaic's distortion of the wall's shape."""
    frames = sorted(f for f in H_est if f in H_gt)
    grid = _grid(size_wh, 5, 4)
    X = np.concatenate([_apply(H_est[f], grid) for f in frames])
    Y = np.concatenate([_apply(H_gt[f], grid) for f in frames])
    mx, my = X.mean(0), Y.mean(0)
    Xc, Yc = X - mx, Y - my
    U, S, Vt = np.linalg.svd(Yc.T @ Xc)
    D = np.diag([1, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / (Xc**2).sum())
    t = my - s * R @ mx
    res = np.linalg.norm((s * (R @ X.T)).T + t - Y, axis=1)
    c = np.array([[size_wh[0] / 2, size_wh[1] / 2]])

    def local_scale(H):
        J = np.array([_apply(H, c + d)[0] - _apply(H, c)[0] for d in ([1, 0], [0, 1])]).T
        return np.sqrt(abs(np.linalg.det(J)))

    expected = np.mean([local_scale(H_gt[f]) for f in frames]) / np.mean([local_scale(H_est[f]) for f in frames])
    M = np.c_[s * R, t]
    return GlobalShape(float(np.sqrt(np.mean(res**2))), float(res.max()), s, float(s / expected - 1), M)


def mosaic_ssim(mosaic_bgra: np.ndarray, canvas: np.ndarray, similarity: np.ndarray) -> tuple[float, float]:
    """(SSIM over the covered part of the wall, covered fraction of the canvas) after mapping the
    mosaic onto the wall with ``similarity`` (2x3, mosaic px -> wall px)."""
    from skimage.metrics import structural_similarity

    ch, cw = canvas.shape[:2]
    warped = cv2.warpAffine(mosaic_bgra, similarity, (cw, ch), flags=cv2.INTER_LINEAR)
    mask = warped[..., 3] > 250
    mask = cv2.erode(mask.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    g_est = cv2.cvtColor(warped[..., :3], cv2.COLOR_BGR2GRAY)
    g_gt = canvas if canvas.ndim == 2 else cv2.cvtColor(canvas, cv2.COLOR_BGR2GRAY)
    _, smap = structural_similarity(g_gt, g_est, data_range=255, full=True, gaussian_weights=True, sigma=1.5, use_sample_covariance=False)
    return (float(smap[mask].mean()) if mask.any() else float("nan")), float(mask.mean())


def covered_fraction(mosaic_bgra: np.ndarray, similarity: np.ndarray, H_gt: dict[int, np.ndarray], size_wh, canvas_wh) -> float:
    """Share of the wall the true frames imaged that the mosaic covers."""
    cw, ch = canvas_wh
    seen = np.zeros((ch, cw), np.uint8)
    for H in H_gt.values():
        cv2.fillConvexPoly(seen, np.round(footprint(H, size_wh)).astype(np.int32), 1)
    warped = cv2.warpAffine(mosaic_bgra[..., 3], similarity, (cw, ch), flags=cv2.INTER_NEAREST)
    return float(((warped > 0) & (seen > 0)).sum() / max(seen.sum(), 1))


@dataclass(frozen=True)
class CornerError:
    median_px: float
    max_px: float
    n_frames: int


def corner_error(H_est: dict[int, np.ndarray], H_gt: dict[int, np.ndarray], size_wh: tuple[int, int]) -> CornerError:
    """The synthetic sweeps' accuracy protocol: every frame's four corners placed by the mosaic,
    one similarity (mosaic -> wall, least squares over all corners) applied, then the distance of
    each corner to its true wall position (median and max over all corners, wall px)."""
    frames = sorted(f for f in H_est if f in H_gt)
    w, h = size_wh
    corners = np.array([[0, 0], [w, 0], [w, h], [0, h]], float)
    X = np.concatenate([_apply(H_est[f], corners) for f in frames])
    Y = np.concatenate([_apply(H_gt[f], corners) for f in frames])
    mx, my = X.mean(0), Y.mean(0)
    U, S, Vt = np.linalg.svd((Y - my).T @ (X - mx))
    D = np.diag([1, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / ((X - mx) ** 2).sum())
    err = np.linalg.norm((s * (R @ (X - mx).T)).T + my - Y, axis=1)
    return CornerError(float(np.median(err)), float(err.max()), len(frames))


def coverage_error(
    covered: np.ndarray, origin_px: np.ndarray, H_live: dict[int, np.ndarray], H_gt: dict[int, np.ndarray],
    usable: set[int], size_wh: tuple[int, int],
) -> tuple[float, float]:
    """A live coverage map against the truth: (share of the surveyed wall where the map is wrong,
    covered or not; share the truth covers). ``covered`` is the map (picture px = mosaic px -
    ``origin_px``), ``H_live`` frame px -> live mosaic px, ``H_gt`` frame px -> wall px, ``usable``
    the frames that truly imaged at usable sharpness. The wall is put on the map by one similarity
    fitted between the frame centres."""
    frames = sorted(f for f in H_live if f in H_gt)
    c = np.array([[size_wh[0] / 2, size_wh[1] / 2]])
    A = np.concatenate([_apply(H_gt[f], c) for f in frames])
    B = np.concatenate([_apply(H_live[f], c) for f in frames])
    ma, mb = A.mean(0), B.mean(0)
    U, S, Vt = np.linalg.svd((B - mb).T @ (A - ma))
    D = np.diag([1, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / ((A - ma) ** 2).sum())
    truth = np.zeros(covered.shape, np.uint8)
    seen = np.zeros(covered.shape, np.uint8)
    for f, H in H_gt.items():
        q = (s * (R @ (footprint(H, size_wh) - ma).T)).T + mb - origin_px
        cv2.fillConvexPoly(seen, np.round(q).astype(np.int32), 1)
        if f in usable:
            cv2.fillConvexPoly(truth, np.round(q).astype(np.int32), 1)
    area = max(int(seen.sum()), 1)
    return float((covered != (truth > 0)).sum() / area), float(truth.sum() / area)


def coverage_error_sim(live, frames: list, max_blur_px: float = 2.0) -> tuple[float, float]:
    """A live mosaic fed a simulated sweep's frames (``frames``: the sweep's FrameRecords it was fed,
    in order) against the simulator's truth: each frame's true texture-to-frame homography, usable
    when its true motion blur is at most ``max_blur_px``. Returns :func:`coverage_error`'s pair."""
    H_gt = {k: np.linalg.inv(f.truth.H_wall_px_to_frame) for k, f in enumerate(frames)}
    usable = {k for k, f in enumerate(frames) if (f.truth.motion_blur_px or 0.0) <= max_blur_px}
    H_live = {p.index: p.H for p in live.placements if p.placed}
    return coverage_error(live.covered(), live.origin_px, H_live, H_gt, usable, tuple(live.frame_wh))

