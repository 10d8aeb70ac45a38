"""Robust homography between two frames, with a test that rejects false matches.

Rust texture repeats: a ratio test and RANSAC alone can lock onto a self-similar patch. A pair is
accepted only if (1) enough inliers survive USAC/MAGSAC, (2) they are a large enough share of the
ratio-test matches, (3) they spread over the overlap instead of sitting in one corner, (4) the
homography is a plausible view change of a wall (bounded scale, shear and perspective) and, when
a prior placement is known, (5) it agrees with that prior.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from ._blas import one_blas_thread

from ._features import Features


@dataclass(frozen=True)
class MatchParams:
    ratio: float = 0.8
    ransac_px: float = 2.0
    min_inliers: int = 30
    min_inlier_ratio: float = 0.2
    min_spread: float = 0.04  # inlier hull area / frame area
    max_scale_change: float = 1.6
    max_perspective: float = 2e-3  # |h31|, |h32| in pixels^-1 after normalisation
    prior_tolerance: float = 0.25  # of the frame diagonal, when a prior is given
    guided_radius: float = 0.15  # of the frame diagonal: search window around the prior's prediction


@dataclass(frozen=True)
class PairMatch:
    """Accepted pair: ``H`` maps pixels of frame ``i`` to frame ``j``; ``src``/``dst`` are inliers."""

    i: int
    j: int
    H: np.ndarray
    src: np.ndarray
    dst: np.ndarray
    n_matches: int

    def __bool__(self) -> bool:
        return True

    @property
    def n_inliers(self) -> int:
        return len(self.src)


@dataclass(frozen=True)
class PairFailure:
    """A pair that could not be registered, with the reason (falsy)."""

    i: int
    j: int
    reason: str
    n_matches: int = 0
    extra: dict = field(default_factory=dict)

    def __bool__(self) -> bool:
        return False


def _knn_ratio(fa: Features, fb: Features, ratio: float, outside: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Ratio-test matches; with ``outside`` (na, nb; float32, 0 for a candidate, inf for none) only
    the candidates compete, and a lone candidate is kept (the spatial gate already vouches for it)."""
    if not len(fa) or not len(fb):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    if fa.binary:
        return _knn_ratio_hamming(fa, fb, ratio, outside)
    # L2 through one matrix product: |a - b|^2 = |a|^2 + |b|^2 - 2 a.b. SIFT's descriptors are integers 0-255 with
    # |a| about 512, so every term is an integer below 2^24 and float32 holds it exactly: the same two nearest
    # neighbours as brute force (cv2.batchDistance, identical on all 737 pairs of synth_rust_sweep), 4x faster.
    # The product is OpenBLAS's, held to the calling thread (one_blas_thread: its own threads spin-wait, 15 ms a
    # 540x540 product on the shared 2 cores): 4x faster again than cv2.gemm (840x840x128: 1.6 against 7.5 ms)
    da, db = fa.desc.astype(np.float32), fb.desc.astype(np.float32)
    with one_blas_thread():
        M = np.matmul(da, db.T * np.float32(-2.0))
    M += np.einsum("ij,ij->i", db, db)[None, :]
    if outside is not None:
        cv2.add(M, outside, dst=M)
    rows = np.arange(len(da))
    i0 = M.argmin(axis=1)
    m0 = M[rows, i0].astype(np.float64)
    if M.shape[1] > 1:
        M[rows, i0] = np.inf
        m1 = M[rows, M.argmin(axis=1)].astype(np.float64)
    else:
        m1 = np.full(len(da), np.inf)
    na = np.einsum("ij,ij->i", da, da).astype(np.float64)
    d0, d1 = np.maximum(m0 + na, 0.0), np.maximum(m1 + na, 0.0)
    two = np.isfinite(d1)
    keep = two & (d0 < ratio * ratio * d1)
    if outside is not None:
        keep |= ~two & np.isfinite(d0)
    qa = np.flatnonzero(keep)
    return qa.astype(np.int64), i0[qa].astype(np.int64)


def _knn_ratio_hamming(fa: Features, fb: Features, ratio: float, outside: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Binary descriptors (ORB, AKAZE): brute force through ``cv2.batchDistance``."""
    mask = None if outside is None else (outside == 0).view(np.uint8)
    dist, idx = cv2.batchDistance(fa.desc, fb.desc, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=2, mask=mask)
    dist = dist.astype(np.float64)
    two = idx[:, 1] >= 0
    keep = two & (dist[:, 0] < ratio * dist[:, 1])
    if mask is not None:
        keep |= ~two & (idx[:, 0] >= 0)
    qa = np.flatnonzero(keep)
    return qa.astype(np.int64), idx[qa, 0].astype(np.int64)


def _guided_subsets(fa: Features, fb: Features, prior_H: np.ndarray, size_wh: tuple[int, int], radius: float):
    """Keypoints of each frame that the prior puts inside the other, and the spatial gate: float32
    (na, nb), 0 where frame b's keypoint is within ``radius`` of where the prior puts a's, else inf."""
    w, h = size_wh
    pred = cv2.perspectiveTransform(fa.xy.reshape(-1, 1, 2).astype(np.float64), prior_H).reshape(-1, 2)
    back = cv2.perspectiveTransform(fb.xy.reshape(-1, 1, 2).astype(np.float64), np.linalg.inv(prior_H)).reshape(-1, 2)
    m = radius
    sa = np.flatnonzero((pred[:, 0] > -m) & (pred[:, 0] < w + m) & (pred[:, 1] > -m) & (pred[:, 1] < h + m))
    sb = np.flatnonzero((back[:, 0] > -m) & (back[:, 0] < w + m) & (back[:, 1] > -m) & (back[:, 1] < h + m))
    # squared distances as one small matrix product, [x, y, |p|^2, 1] . [-2x', -2y', 1, |q|^2], in float32 about the
    # frame centre (|p|^2 < 2^19: the gate's edge exact to 1e-5 px), then 0 / inf by a threshold
    c = np.array([w / 2, h / 2])
    pa, pb = pred[sa] - c, fb.xy[sb].astype(np.float64) - c
    A = np.column_stack([pa, (pa * pa).sum(1), np.ones(len(pa))]).astype(np.float32)
    B = np.column_stack([-2 * pb, np.ones(len(pb)), (pb * pb).sum(1)]).astype(np.float32)
    d2 = cv2.gemm(A, B, 1.0, None, 0.0, flags=cv2.GEMM_2_T)
    _, outside = cv2.threshold(d2, radius * radius, np.inf, cv2.THRESH_BINARY)
    return sa, sb, outside


def usac_params(threshold_px: float, seed: int) -> cv2.UsacParams:
    """OpenCV's USAC_MAGSAC settings, seeded: ``cv2.setRNGSeed`` does not reach USAC's own
    generator, ``UsacParams.randomGeneratorState`` does."""
    p = cv2.UsacParams()
    p.threshold = threshold_px
    p.confidence = 0.999
    p.maxIterations = 5000
    p.randomGeneratorState = seed
    p.sampler = cv2.SAMPLING_UNIFORM
    p.score = cv2.SCORE_METHOD_MAGSAC
    p.loMethod = cv2.LOCAL_OPTIM_SIGMA
    p.loIterations = 10
    p.loSampleSize = 50
    p.final_polisher = cv2.MAGSAC
    p.final_polisher_iterations = 10
    p.isParallel = False
    return p


def plausible_homography(H: np.ndarray, size_wh: tuple[int, int], params: MatchParams) -> str:
    """Empty string if ``H`` is a plausible frame-to-frame view change of a wall, else the reason."""
    if not np.all(np.isfinite(H)) or abs(H[2, 2]) < 1e-12:
        return "degenerate homography"
    H = H / H[2, 2]
    det = np.linalg.det(H[:2, :2])
    if det <= 0:
        return "homography flips the image"
    scale = np.sqrt(det)
    if not (1 / params.max_scale_change <= scale <= params.max_scale_change):
        return f"implausible scale change {scale:.2f}"
    sv = np.linalg.svd(H[:2, :2], compute_uv=False)
    if sv[0] / sv[1] > 1.5:
        return f"implausible shear/anisotropy {sv[0] / sv[1]:.2f}"
    if np.max(np.abs(H[2, :2])) > params.max_perspective:
        return "implausible perspective"
    w, h = size_wh
    corners = np.array([[0, 0, 1], [w, 0, 1], [w, h, 1], [0, h, 1]], float).T
    if np.any((H @ corners)[2] <= 0):
        return "homography maps the frame through infinity"
    return ""


def match_pair(
    i: int,
    j: int,
    fa: Features,
    fb: Features,
    size_wh: tuple[int, int],
    *,
    params: MatchParams = MatchParams(),
    prior_H: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
) -> PairMatch | PairFailure:
    """Register frame ``i`` to frame ``j`` from their features.

    ``prior_H`` (i -> j), when given, is the placement predicted by the current layout; a
    homography that moves the frame centre further than ``prior_tolerance`` of the diagonal from
    it is rejected as a false match.
    """
    if len(fa) < params.min_inliers or len(fb) < params.min_inliers:
        return PairFailure(i, j, f"too few features ({min(len(fa), len(fb))})")
    if prior_H is None:
        qa, tb = _knn_ratio(fa, fb, params.ratio)
    else:  # guided: only candidates near where the prior puts them
        sa, sb, gate = _guided_subsets(fa, fb, prior_H, size_wh, params.guided_radius * float(np.hypot(*size_wh)))
        if len(sa) < params.min_inliers or len(sb) < params.min_inliers:
            return PairFailure(i, j, f"too few features in the predicted overlap ({min(len(sa), len(sb))})")
        sub_a = Features(fa.xy[sa], fa.desc[sa], fa.binary)
        sub_b = Features(fb.xy[sb], fb.desc[sb], fb.binary)
        qa, tb = _knn_ratio(sub_a, sub_b, params.ratio, gate)
        qa, tb = sa[qa], sb[tb]
    if len(qa) < params.min_inliers:
        return PairFailure(i, j, f"too few matches ({len(qa)})", len(qa))
    src, dst = fa.xy[qa], fb.xy[tb]
    seed = int(rng.integers(2**31)) if rng is not None else 0
    H, mask = cv2.findHomography(src, dst, usac_params(params.ransac_px, seed))
    if H is None or mask is None:
        return PairFailure(i, j, "no homography found", len(qa))
    inl = mask.ravel().astype(bool)
    n_in = int(inl.sum())
    if n_in < params.min_inliers:
        return PairFailure(i, j, f"too few inliers ({n_in})", len(qa))
    if n_in < params.min_inlier_ratio * len(qa):
        return PairFailure(i, j, f"inlier ratio {n_in / len(qa):.2f} too low (repetitive texture?)", len(qa))
    why = plausible_homography(H, size_wh, params)
    if why:
        return PairFailure(i, j, why, len(qa))
    w, h = size_wh
    hull = cv2.convexHull(src[inl].astype(np.float32))
    if cv2.contourArea(hull) < params.min_spread * w * h:
        return PairFailure(i, j, "inliers bunched in a small patch", len(qa))
    if prior_H is not None:
        c = np.array([w / 2, h / 2, 1.0])
        p, q = H @ c, prior_H @ c
        if np.hypot(*(p[:2] / p[2] - q[:2] / q[2])) > params.prior_tolerance * np.hypot(w, h):
            return PairFailure(i, j, "disagrees with the predicted layout", len(qa))
    return PairMatch(i, j, H / H[2, 2], src[inl], dst[inl], len(qa))
