"""From frames to placed groups: features, pair selection, pairwise and global registration."""

from __future__ import annotations

import contextlib
import os
from collections import Counter, defaultdict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Callable, Protocol

import cv2
import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree

from ._blas import with_one_blas_thread
from ._blend import seam_size
from ._align import AlignParams, Camera, Correspondences, Odometry, align_group, quick_layout
from ._features import Features, detect_features, to_gray
from ._homography import MatchParams, PairFailure, PairMatch, match_pair
from ._pairs import layout_pairs, short_links, temporal_pairs
from ._vignetting import THUMB_WH, Vignetting, VignettingAccumulator


class FrameError(Exception):
    """A frame that cannot be used (unreadable, truncated, wrong size): the message is the reason."""


class FrameSource(Protocol):
    """What the mosaicer reads frames through; I/O stays in the adapter."""

    def __len__(self) -> int: ...

    def name(self, i: int) -> str: ...

    def load(self, i: int) -> np.ndarray:
        """BGR or grey uint8 image of frame ``i``; raises :class:`FrameError` with a reason."""
        ...


class MotionPrior(Protocol):
    """Optional extras of a source that knows where the camera was (a sweep with vehicle states)."""

    def skip_reason(self, i: int) -> str:
        """Non-empty if frame ``i`` is not part of the wall survey (e.g. taken while landed)."""
        ...

    def centre_px(self, i: int) -> np.ndarray | None:
        """Predicted frame-centre position, in pixels of a common wall-aligned frame, or None."""
        ...

    tolerance_px: float  # how far a registration may disagree with the prediction


@dataclass(frozen=True)
class RegisterParams:
    detector: str = "sift"
    max_features: int = 1500
    # frames detected reduced by this: half the SIFT time; validation sweeps (generated, 512x384, seeds 5, 6):
    # scale 1: 9.1 s CPU, corner error 0.055 / 0.338 px; 0.625: 6.1 s, 0.053 / 0.277 px
    detect_scale: float = 0.625
    focal_px: float | None = None  # known camera focal length: enables metric rectification
    principal_px: tuple[float, float] | None = None  # principal point (default: the frame centre)
    temporal_window: int = 2
    layout_rounds: int = 2
    min_overlap: float = 0.15
    candidates_per_frame: int = 2
    low_texture_features: int = 150  # fewer keypoints than this make a frame texture-poor
    low_texture_side_px: int = 640  # texture-poor frames are detected equalised at most this long
    low_texture_share: float = 0.1  # this share of texture-poor frames switches the sweep to low-texture detection
    texture_sample: int = 64  # evenly spaced frames detected first to estimate that share (each frame then decoded once)
    texture_quick: int = 8  # the sample's first, evenly spaced: when half of them are texture-poor, so is the sweep
    keyframe_step: float = 0.05  # of the frame diagonal: closer frames are attached, not aligned
    bridge_budget: int = 400  # unguided matches allowed for joining disconnected groups
    pair_outlier_px: float = 3.0  # pairs whose correspondences disagree more after global alignment are dropped
    match: MatchParams = MatchParams()
    align: AlignParams = AlignParams()
    seed: int = 0
    workers: int = 0  # threads for features and matching; 0: one per core (at most 4)


@dataclass
class Group:
    """A connected set of frames with their homographies (frame px -> group mosaic px)."""

    frames: list[int]
    H: dict[int, np.ndarray]
    rms_px: float
    keyframes: list[int] = field(default_factory=list)  # the frames registered globally and blended
    model: str = "homography"  # global model of the keyframes: "pose" (K [r1 r2 t]) or "homography"
    camera: Camera | None = None  # intrinsics the pose model used or found; H maps pixels undistorted with it
    note: str = ""  # why the pose model was not kept
    odometry: dict | None = None  # the pose model's odometry prior: used or why not (``_align.odometry_record``)

    def __post_init__(self) -> None:
        if not self.keyframes:
            self.keyframes = list(self.frames)


@dataclass
class Registration:
    size_wh: tuple[int, int]
    groups: list[Group]
    unplaced: dict[int, str]
    pairs: list[PairMatch]
    failures: list[PairFailure]
    vignetting: Vignetting | None
    n_features: dict[int, int] = field(default_factory=dict)
    thumbnails: dict[int, np.ndarray] = field(default_factory=dict)  # frame at the blend's seam scale (decoded once)


Progress = Callable[[str, int, int], None]


def _components(nodes: list[int], edges: list[PairMatch]) -> list[list[int]]:
    idx = {f: k for k, f in enumerate(nodes)}
    if not edges:
        return [[f] for f in nodes]
    rows = [idx[e.i] for e in edges]
    cols = [idx[e.j] for e in edges]
    g = csr_matrix((np.ones(len(edges)), (rows, cols)), shape=(len(nodes), len(nodes)))
    _, labels = connected_components(g, directed=False)
    comps: dict[int, list[int]] = defaultdict(list)
    for f, lab in zip(nodes, labels):
        comps[lab].append(f)
    return sorted(comps.values(), key=lambda c: (-len(c), c[0]))


def _initial_layout(comp: list[int], edges: list[PairMatch]) -> dict[int, np.ndarray]:
    """Chain pairwise homographies along a maximum spanning tree (weights: inlier counts)."""
    if len(comp) == 1:
        return {comp[0]: np.eye(3)}
    idx = {f: k for k, f in enumerate(comp)}
    by_key = {}
    rows, cols, wts = [], [], []
    for e in edges:
        if e.i in idx and e.j in idx:
            rows.append(idx[e.i])
            cols.append(idx[e.j])
            wts.append(1.0 / (1 + e.n_inliers))  # minimum spanning tree of 1/inliers
            by_key[(e.i, e.j)] = e.H
    g = csr_matrix((wts, (rows, cols)), shape=(len(comp), len(comp)))
    tree = minimum_spanning_tree(g)
    tree = tree + tree.T
    root = len(comp) // 2
    order, parent = breadth_first_order(tree, root, directed=False, return_predecessors=True)
    H = {comp[root]: np.eye(3)}
    for k in order[1:]:
        child, par = comp[k], comp[parent[k]]
        if (child, par) in by_key:
            c2p = by_key[(child, par)]
        else:
            c2p = np.linalg.inv(by_key[(par, child)])
        Hc = H[par] @ c2p
        H[child] = Hc / Hc[2, 2]
    return H


def _select_keyframes(
    valid: list[int], accepted: list[PairMatch], size_wh: tuple[int, int], step: float
) -> tuple[list[int], dict[int, tuple[int, np.ndarray]], dict[tuple[int, int], np.ndarray]]:
    """Greedy keyframes along the chain of neighbour pairs: a frame becomes a keyframe when its
    centre is more than ``step`` of the diagonal from the last keyframe's (or the chain breaks).
    Returns (keyframes, attached frame -> (keyframe, H frame px -> keyframe px), priors for pairs
    of consecutive keyframes). Thinning is skipped (nothing attached) unless it removes >= 30 %."""
    pair_h = {(e.i, e.j): e.H for e in accepted}
    diag = float(np.hypot(*size_wh))
    c = np.array([size_wh[0] / 2, size_wh[1] / 2, 1.0])
    keys = [valid[0]]
    attach: dict[int, tuple[int, np.ndarray]] = {}
    priors: dict[tuple[int, int], np.ndarray] = {}
    H_prev_key = np.eye(3)  # previous frame px -> current keyframe px
    for a, b in zip(valid, valid[1:]):
        H_ab = pair_h.get((a, b))
        if H_ab is None:
            keys.append(b)
            H_prev_key = np.eye(3)
            continue
        H_b_key = H_prev_key @ np.linalg.inv(H_ab)
        H_b_key /= H_b_key[2, 2]
        p = H_b_key @ c
        if np.linalg.norm(p[:2] / p[2] - c[:2]) > step * diag:
            priors[(keys[-1], b)] = np.linalg.inv(H_b_key)  # keyframe px -> b px
            keys.append(b)
            H_prev_key = np.eye(3)
        else:
            attach[b] = (keys[-1], H_b_key)
            H_prev_key = H_b_key
    if len(attach) < 0.3 * len(valid):
        return list(valid), {}, {}
    return keys, attach, priors


def _disagrees_with_motion(pair: PairMatch, prior, size_wh: tuple[int, int]) -> str:
    """Reason if a pair's homography moves the frame centre far from what the vehicle's motion
    predicts (false matches on a camera-fixed pattern, such as vignetting or the on-board light,
    give the identity while the vehicle moved)."""
    ci, cj = prior.centre_px(pair.i), prior.centre_px(pair.j)
    if ci is None or cj is None:
        return ""
    c = np.array([size_wh[0] / 2, size_wh[1] / 2, 1.0])
    p = np.linalg.inv(pair.H) @ c  # frame j's centre in frame i's pixels
    seen = p[:2] / p[2] - c[:2]
    predicted = cj - ci
    if np.linalg.norm(seen - predicted) > prior.tolerance_px:
        return f"disagrees with the vehicle's motion by {np.linalg.norm(seen - predicted):.0f} px"
    return ""


def _odometry_candidates(
    comps: list[list[int]], prior, size_wh: tuple[int, int], tried: set[tuple[int, int]], per_pair: int = 8
) -> list[tuple[int, int]]:
    """Pairs across disconnected groups that the vehicle's positions put over the same wall
    (nearest predicted centres first), when the source knows them."""
    diag = float(np.hypot(*size_wh))
    located = []
    for c in comps:
        fs = [f for f in c if prior.centre_px(f) is not None]
        located.append((np.array(fs, dtype=int), np.array([prior.centre_px(f) for f in fs]).reshape(-1, 2)))
    out: list[tuple[int, int]] = []
    for b in range(1, len(comps)):
        for a in range(b):
            (fa, ca), (fb, cb) = located[a], located[b]
            if not len(fa) or not len(fb):
                continue
            d = np.linalg.norm(ca[:, None, :] - cb[None, :, :], axis=2)
            ia, ib = np.nonzero(d < 0.5 * diag)
            picked = 0
            for k in np.argsort(d[ia, ib]):
                key = (int(min(fa[ia[k]], fb[ib[k]])), int(max(fa[ia[k]], fb[ib[k]])))
                if key not in tried and key not in out:
                    out.append(key)
                    picked += 1
                    if picked == per_pair:
                        break
    return out


def _bridge_candidates(
    comps: list[list[int]], feats: dict[int, Features], tried: set[tuple[int, int]], budget: int,
    keyframes: int = 4, per_component: int = 24,
) -> list[tuple[int, int]]:
    """Unguided pairs that may join disconnected groups (no common layout predicts them): a few
    well-textured keyframes of each smaller group, spread along it, against evenly spaced frames of
    the larger. Well-textured: at least as many features as its ``3 k``-th best frame, ties kept, so
    that where the detector's cap gives every frame the same count the keyframes still spread over
    the whole group (they were its first frames: on a rendered sweep over a wall photo, all in the
    pass that cannot overlap the other group)."""

    def spread(frames: list[int], k: int, textured: bool) -> list[int]:
        if textured and len(frames) > k * 3:
            least = sorted((len(feats[f]) for f in frames), reverse=True)[k * 3 - 1]
            frames = sorted(f for f in frames if len(feats[f]) >= least)
        if len(frames) <= k:
            return frames
        return [frames[int(round(t))] for t in np.linspace(0, len(frames) - 1, k)]

    out: list[tuple[int, int]] = []
    for b in range(len(comps) - 1, 0, -1):
        for a in range(b):
            for fb in spread(comps[b], keyframes, True):
                for fa in spread(comps[a], per_component, False):
                    key = (min(fa, fb), max(fa, fb))
                    if key not in tried:
                        out.append(key)
            if len(out) >= budget:
                return out[:budget]
    return out


def _correspondences(edges: list[PairMatch], k: int, rng: np.random.Generator) -> Correspondences:
    fi, fj, P, Q = [], [], [], []
    for e in edges:
        n = e.n_inliers
        sel = rng.choice(n, size=min(k, n), replace=False) if n > k else np.arange(n)
        fi.append(np.full(len(sel), e.i))
        fj.append(np.full(len(sel), e.j))
        P.append(e.src[sel])
        Q.append(e.dst[sel])
    if not edges:
        z = np.zeros((0, 2))
        return Correspondences(np.zeros(0, int), np.zeros(0, int), z, z)
    return Correspondences(np.concatenate(fi), np.concatenate(fj), np.concatenate(P).astype(float), np.concatenate(Q).astype(float))


@dataclass
class _Extracted:
    """What the features step gives: features of the usable frames, the rest with a reason."""

    size_wh: tuple[int, int] | None
    feats: dict[int, Features]
    unplaced: dict[int, str]
    vignetting: Vignetting | None
    thumbnails: dict[int, np.ndarray]


@contextlib.contextmanager
def _opencv_threads_per_worker(workers: int):
    """OpenCV's own threads held to one while ``workers`` (> 1) threads of ours call it: SIFT's
    pyramid and the matching otherwise start a pool per call, and the two pools oversubscribe the
    cores (the 752x480 scaling sweep's features: 64 -> 59 ms a frame on 2 cores, the same
    keypoints). Restored on exit; a no-op for one worker."""
    before = cv2.getNumThreads()
    if workers > 1:
        cv2.setNumThreads(1)
    try:
        yield
    finally:
        if workers > 1:
            cv2.setNumThreads(before)


def _texture_sample(n: int, k: int) -> list[int]:
    """Up to ``k`` evenly spaced frames (all of them when there are no more than ``k``)."""
    return list(range(n)) if n <= k else sorted({int(round(t)) for t in np.linspace(0, n - 1, k)})


def extract_features(source: FrameSource, prior, params: RegisterParams, workers: int, progress: Progress | None) -> _Extracted:
    """Load every frame once and detect its features (threads: OpenCV releases the GIL); frames
    off the survey, unreadable or of another size get a reason. When >= ``low_texture_share`` of
    the frames are texture-poor, every frame is detected on equalised images with a sensitive
    detector: mixing the two preprocessings frame by frame breaks matching at the boundary.

    The share is first estimated on ``texture_sample`` evenly spaced frames, detected (and kept
    in memory) before the others, so the remaining frames are decoded and detected once, with the
    preprocessing chosen (the 752x480 scaling sweeps are texture-poor: detecting every frame twice
    doubled their feature time). The sample's first ``texture_quick`` frames (evenly spaced) go
    first: when half of them are texture-poor the sweep is taken as such without the rest of the
    sample's normal detection (Haltbrekken's 30 ROV frames, all poor: 8 normal detections of
    0.3 s, not 30). Should the whole sweep then cross the threshold the sample missed, every frame
    is detected again.

    A frame the normal detector leaves with fewer features than a pair needs
    (``match.min_inliers``), while the low-texture one finds enough, would be lost: one such
    frame also switches the sweep (validation sweep vt_original_train_196, 8 % texture-poor:
    4 of 165 frames lost and 2.17 px max corner error; switched, 165 placed, 1.72 px)."""
    n = len(source)
    feats: dict[int, Features] = {}
    unplaced: dict[int, str] = {}
    size_wh: tuple[int, int] | None = None
    vig = VignettingAccumulator()
    thumbs: dict[int, np.ndarray] = {}
    kept: dict[int, np.ndarray] = {}  # the sample's grey frames, for a second detection without decoding
    rescuable: set[int] = set()  # frames too poor for the normal detector that the low-texture one can register
    done = 0

    def detect(gray: np.ndarray, mode: str) -> Features:
        return detect_features(gray, detector=params.detector, max_features=params.max_features, scale=params.detect_scale,
                               low_texture_side_px=params.low_texture_side_px, mode=mode)

    def extract(i: int, mode: str, keep: bool = False):
        why = prior.skip_reason(i) if prior is not None else ""
        if why:
            return i, why, None, None
        try:
            img = source.load(i)
        except FrameError as err:
            return i, str(err), None, None
        gray = to_gray(img)
        small = cv2.resize(gray, THUMB_WH, interpolation=cv2.INTER_AREA)
        seam = cv2.resize(img, seam_size((img.shape[1], img.shape[0])), interpolation=cv2.INTER_AREA)
        feats = detect(gray, mode)
        rescue = (not keep and mode == "normal" and len(feats) < params.match.min_inliers  # the sample's: texture_poor
                  and len(detect(gray, "low_texture")) >= params.match.min_inliers)
        return i, "", (img.shape[1], img.shape[0]), (small, seam, feats, gray if keep else None, rescue)

    def take(results) -> None:
        nonlocal size_wh, done
        for i, err, wh, out in results:
            done += 1
            if progress:
                progress("features", done, n)
            if err:
                unplaced[i] = err
                continue
            if size_wh is None:
                size_wh = wh
            elif wh != size_wh:
                unplaced[i] = f"size {wh[0]}x{wh[1]} differs from the sweep's {size_wh[0]}x{size_wh[1]}"
                continue
            vig.add_thumbnail(out[0])
            thumbs[i] = out[1]
            feats[i] = out[2]
            if out[3] is not None:
                kept[i] = out[3]
            if out[4]:
                rescuable.add(i)

    def texture_poor(fs: dict[int, Features]) -> bool:
        if params.low_texture_share >= 1:
            return False
        poor = sum(len(f) < params.low_texture_features for f in fs.values())
        if poor >= max(2, params.low_texture_share * len(fs)):
            return True
        for i in kept:  # the sample's frames, checked only when the share alone does not decide
            if i in fs and len(fs[i]) < params.match.min_inliers and len(detect(kept[i], "low_texture")) >= params.match.min_inliers:
                rescuable.add(i)
        return any(i in fs for i in rescuable)

    sample = _texture_sample(n, params.texture_sample)
    quick = [sample[k] for k in _texture_sample(len(sample), params.texture_quick)]
    in_sample = set(quick)
    with _opencv_threads_per_worker(workers), ThreadPoolExecutor(max_workers=workers) as pool:
        take(pool.map(lambda i: extract(i, "normal", keep=True), quick))
        poor = sum(len(f) < params.low_texture_features for f in feats.values())
        if not (len(feats) >= 2 and 2 * poor >= len(feats)):  # not clearly texture-poor: the whole sample
            rest = [i for i in sample if i not in in_sample]
            take(pool.map(lambda i: extract(i, "normal", keep=True), rest))
            in_sample.update(rest)
        mode = "low_texture" if texture_poor(feats) else "normal"
        if mode == "low_texture":
            for i, f in zip(sorted(kept), pool.map(lambda i: detect(kept[i], "low_texture"), sorted(kept))):
                feats[i] = f
        kept.clear()
        take(pool.map(lambda i: extract(i, mode), [i for i in range(n) if i not in in_sample]))
        if mode == "normal" and texture_poor(feats):  # the sample missed it: every frame again
            for i, err, wh, out in pool.map(lambda i: extract(i, "low_texture"), sorted(feats)):
                if progress:
                    progress("features (low texture)", i + 1, n)
                feats[i] = out[2]
    return _Extracted(size_wh, feats, unplaced, vig.result() if size_wh else None, thumbs)


@dataclass
class _Pairs:
    """Pair registration with its bookkeeping: accepted pairs, failures, pairs tried."""

    feats: dict[int, Features]
    size_wh: tuple[int, int]
    prior: object
    params: RegisterParams
    workers: int
    progress: Progress | None
    accepted: list[PairMatch] = field(default_factory=list)
    failures: list[PairFailure] = field(default_factory=list)
    tried: set[tuple[int, int]] = field(default_factory=set)

    def one(self, pair: tuple[int, int], priors: dict[tuple[int, int], np.ndarray]) -> PairMatch | PairFailure:
        i, j = pair
        rng = np.random.default_rng([self.params.seed, i, j])  # same result whatever the thread order
        res = match_pair(i, j, self.feats[i], self.feats[j], self.size_wh, params=self.params.match, prior_H=priors.get((i, j)), rng=rng)
        if res and self.prior is not None:
            why = _disagrees_with_motion(res, self.prior, self.size_wh)
            if why:
                return PairFailure(i, j, why, res.n_matches)
        return res

    def attempt(self, pairs: list[tuple[int, int]], priors: dict[tuple[int, int], np.ndarray] | None = None) -> int:
        """Register ``pairs`` (in threads); returns how many were accepted."""
        priors = priors or {}
        self.tried.update(pairs)
        before = len(self.accepted)
        with _opencv_threads_per_worker(self.workers), ThreadPoolExecutor(max_workers=self.workers) as pool:
            for k, res in enumerate(pool.map(lambda p: self.one(p, priors), pairs)):
                if self.progress:
                    self.progress("matching", k + 1, len(pairs))
                (self.accepted if res else self.failures).append(res)
        return len(self.accepted) - before


def chained_priors(frames: list[int], pairs: list[tuple[int, int]], accepted: list[PairMatch]) -> dict[tuple[int, int], np.ndarray]:
    """For pairs (frames[a], frames[b]) further apart than neighbours, the homography a -> b chained
    through the accepted pairs of consecutive frames between them (none where a link is missing)."""
    step = {(e.i, e.j): e.H for e in accepted}
    pos = {f: k for k, f in enumerate(frames)}
    out = {}
    for i, j in pairs:
        H = np.eye(3)
        for k in range(pos[i], pos[j]):
            h = step.get((frames[k], frames[k + 1]))
            if h is None:
                break
            H = h @ H
        else:
            if pos[j] - pos[i] > 1:
                out[(i, j)] = H / H[2, 2]
    return out


def attempt_temporal(frames: list[int], pairs: _Pairs, params: RegisterParams) -> None:
    """Temporal neighbour pairs: consecutive frames unguided, then those further apart guided by
    the chain of consecutive pairs between them (a 1500x1500 unguided match cost about twice a
    guided one)."""
    temporal = [(frames[a], frames[b]) for a, b in temporal_pairs(len(frames), params.temporal_window)]
    pos = {f: k for k, f in enumerate(frames)}
    pairs.attempt([p for p in temporal if pos[p[1]] - pos[p[0]] == 1])
    rest = [p for p in temporal if pos[p[1]] - pos[p[0]] > 1]
    pairs.attempt(rest, chained_priors(frames, rest, pairs.accepted))


def layout_rounds(frames: list[int], pairs: _Pairs, params: RegisterParams, rng: np.random.Generator) -> None:
    """Pass-to-pass candidates from the current layout of each group (chained pair homographies,
    from the second round a quick pose fit), ranked by predicted overlap, matched with the
    layout's prediction as a guide."""
    size_wh = pairs.size_wh
    for round_ in range(params.layout_rounds):
        new: list[tuple[int, int]] = []
        priors = {}
        for comp in _components(frames, pairs.accepted):
            if len(comp) < 2:
                continue
            H = _initial_layout(comp, pairs.accepted)
            if round_ > 0 and len(comp) >= 3:
                comp_edges = [e for e in pairs.accepted if e.i in H]
                H = quick_layout(H, _correspondences(comp_edges, params.align.points_per_pair, rng), size_wh,
                                 focal_px=params.focal_px, pair_H={(e.i, e.j): e.H for e in comp_edges}, params=params.align)
            linked = short_links([(e.i, e.j) for e in pairs.accepted if e.i in H])
            for i, j, _ov in layout_pairs(H, size_wh, tried=pairs.tried, linked=linked, min_overlap=params.min_overlap, per_frame=params.candidates_per_frame):
                new.append((i, j))
                priors[(i, j)] = np.linalg.inv(H[j]) @ H[i]
        if not new:
            break
        pairs.attempt(new, priors)


def bridge_groups(frames: list[int], pairs: _Pairs, params: RegisterParams, rng: np.random.Generator) -> None:
    """Join disconnected groups: pairs the odometry proposes, else unguided keyframe pairs, within
    ``bridge_budget``; each success is followed by layout rounds."""
    budget = params.bridge_budget
    while budget > 0:
        comps = [c for c in _components(frames, pairs.accepted) if len(c) >= 2]
        if len(comps) < 2:
            break
        cand = _odometry_candidates(comps, pairs.prior, pairs.size_wh, pairs.tried) if pairs.prior is not None else []
        cand = cand or _bridge_candidates(comps, pairs.feats, pairs.tried, budget)
        if not cand:
            break
        budget -= len(cand)
        if not pairs.attempt(cand):
            break
        layout_rounds(frames, pairs, params, rng)


def odometry_of(prior, frames: list[int]) -> Odometry | None:
    """The odometry a source with vehicle states offers the pose adjustment (``MotionPrior.centre_px`` of
    every frame, its noise ``odometry_noise_px`` and ``odometry_drift``), or None."""
    noise, drift = getattr(prior, "odometry_noise_px", None), getattr(prior, "odometry_drift", None)
    if prior is None or noise is None or drift is None:
        return None
    centres = {f: c for f in frames if (c := prior.centre_px(f)) is not None}
    return Odometry(centres, float(noise), float(drift)) if len(centres) >= 3 else None


def align_groups(frames: list[int], edges: list[PairMatch], failures: list[PairFailure], size_wh: tuple[int, int],
                 params: RegisterParams, rng: np.random.Generator, odometry: Odometry | None = None) -> tuple[list[Group], list[PairMatch]]:
    """Global alignment of each connected group (:func:`align_group`); pairs inconsistent with it
    by > ``pair_outlier_px`` RMS are dropped (added to ``failures``) and the groups aligned again,
    with the camera the first alignment settled (:func:`settled_camera`): the intrinsics are the
    sweep's, found once on all its pairs, and self-calibrating again after a few pairs are dropped cost
    the NPU drone scene 16 s of its 36 for the same verdict."""
    groups: list[Group] = []
    camera: Camera | None = None
    align, settled_note = params.align, ""
    for attempt in range(3):
        groups = []
        dropped = False
        for comp in _components(frames, edges):
            if len(comp) < 2:
                continue
            comp_set = set(comp)
            comp_edges = [e for e in edges if e.i in comp_set]
            res = align_group(_initial_layout(comp, edges), _correspondences(comp_edges, params.align.points_per_pair, rng), size_wh,
                              focal_px=params.focal_px, principal_px=params.principal_px,
                              pair_H={(e.i, e.j): e.H for e in comp_edges}, camera=camera, odometry=odometry, params=align)
            bad = {key for key, r in res.per_pair_rms_px.items() if r > params.pair_outlier_px}
            if bad:
                for e in comp_edges:
                    if (e.i, e.j) in bad:
                        failures.append(PairFailure(e.i, e.j, f"inconsistent with the global alignment ({res.per_pair_rms_px[(e.i, e.j)]:.1f} px)", e.n_matches))
                edges = [e for e in edges if (e.i, e.j) not in bad]
                dropped = True
            note = settled_note if (res.model == "pose" and camera is not None) or not align.pose_model else res.note
            groups.append(Group(sorted(comp), res.H, res.rms_px, model=res.model, camera=res.camera, note=note,
                                odometry=res.odometry))
        if not dropped:
            break
        if attempt == 0 and params.align.pose_model:
            camera, settled_note = settled_camera(groups, size_wh, params)
            if camera is None:  # no focal length given and no group self-calibrated: free homographies from here
                align = replace(align, pose_model=False)
    return groups, edges


def settled_camera(groups: list[Group], size_wh: tuple[int, int], params: RegisterParams) -> tuple[Camera | None, str]:
    """The camera a first alignment settled, and its note: the largest group's that kept the pose
    model (self-calibrated, or a given focal length it found contradicting the images), else the given
    focal length; None where no focal length was given and no group's self-calibration fitted (later
    alignments then keep free homographies)."""
    posed = [g for g in groups if g.model == "pose" and g.camera is not None]
    if posed:
        best = max(posed, key=lambda g: len(g.frames))
        return best.camera, best.note
    if params.focal_px:
        w, h = size_wh
        cx, cy = params.principal_px if params.principal_px is not None else (w / 2, h / 2)
        return Camera(float(params.focal_px), cx, cy), ""
    tried = max((g for g in groups if g.note), key=lambda g: len(g.frames), default=None)
    return None, f"the sweep's first alignment: {tried.note}" if tried else ""


def attach_frames(groups: list[Group], attach: dict[int, tuple[int, np.ndarray]]) -> None:
    """Frames thinned out as near-duplicates join their keyframe's group through their chain."""
    for g in groups:
        extra = [f for f, (k, _) in attach.items() if k in g.H]
        for f in extra:
            k, H_f_k = attach[f]
            h = g.H[k] @ H_f_k
            g.H[f] = h / h[2, 2]
        g.keyframes = sorted(g.frames)
        g.frames = sorted(g.frames + extra)


def unplaced_reasons(frames: list[int], groups: list[Group], failures: list[PairFailure], feats: dict[int, Features],
                     params: RegisterParams) -> dict[int, str]:
    """Why each frame that is in no group stayed out: too little texture, its pairs' most common failure, or no overlap."""
    placed = {f for g in groups for f in g.frames}
    reasons: dict[int, list[str]] = defaultdict(list)
    for fl in failures:
        reasons[fl.i].append(fl.reason)
        reasons[fl.j].append(fl.reason)
    out = {}
    for f in frames:
        if f in placed:
            continue
        why = reasons.get(f)
        if len(feats[f]) < params.match.min_inliers:
            out[f] = f"too few features ({len(feats[f])}): texture too poor to register"
        elif why:
            # ties go to the first failure met (a set's order changed with the process's string hashing)
            out[f] = "no overlapping frame could be registered: " + Counter(why).most_common(1)[0][0]
        else:
            out[f] = "no overlapping frame"
    return out


@with_one_blas_thread
def register(
    source: FrameSource,
    *,
    params: RegisterParams = RegisterParams(),
    progress: Progress | None = None,
) -> Registration:
    """Place every frame it can; the rest go to ``unplaced`` with a reason. Never raises on bad frames.

    Steps: :func:`extract_features`; temporal neighbour pairs; keyframes (:func:`_select_keyframes`);
    :func:`layout_rounds`; :func:`bridge_groups`; :func:`align_groups`; :func:`attach_frames`;
    :func:`unplaced_reasons`."""
    rng = np.random.default_rng(params.seed)
    prior = source if hasattr(source, "centre_px") and hasattr(source, "skip_reason") else None
    workers = params.workers or min(os.cpu_count() or 1, 4)
    ex = extract_features(source, prior, params, workers, progress)
    if ex.size_wh is None:
        return Registration((0, 0), [], ex.unplaced, [], [], None)
    all_valid = valid = sorted(ex.feats)
    pairs = _Pairs(ex.feats, ex.size_wh, prior, params, workers, progress)
    attempt_temporal(valid, pairs, params)

    # A slow vehicle at 10 Hz gives frames a few pixels apart: align and blend keyframes only,
    # and attach the frames between them through their chain of neighbour homographies.
    keys, attach, key_priors = _select_keyframes(valid, pairs.accepted, ex.size_wh, params.keyframe_step)
    chain_pairs: list[PairMatch] = []
    if attach:
        keyset = set(keys)
        chain_pairs = [e for e in pairs.accepted if not (e.i in keyset and e.j in keyset)]
        pairs.accepted[:] = [e for e in pairs.accepted if e.i in keyset and e.j in keyset]
        valid = keys
        key_temporal = [(valid[a], valid[b]) for a, b in temporal_pairs(len(valid), params.temporal_window)]
        pairs.attempt([p for p in key_temporal if p not in pairs.tried], key_priors)

    layout_rounds(valid, pairs, params, rng)
    bridge_groups(valid, pairs, params, rng)
    groups, edges = align_groups(valid, list(pairs.accepted), pairs.failures, ex.size_wh, params, rng, odometry_of(prior, all_valid))
    attach_frames(groups, attach)
    unplaced = {**ex.unplaced, **unplaced_reasons(all_valid, groups, pairs.failures, ex.feats, params)}
    groups.sort(key=lambda g: (-len(g.frames), g.frames[0]))
    return Registration(
        ex.size_wh, groups, dict(sorted(unplaced.items())), edges + chain_pairs, pairs.failures, ex.vignetting,
        {f: len(ex.feats[f]) for f in all_valid}, ex.thumbnails,
    )
