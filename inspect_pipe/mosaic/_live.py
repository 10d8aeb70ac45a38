"""Live mosaic: each frame placed as it is captured, a low-resolution mosaic and a coverage map.

Pure and incremental: ``LiveMosaic.add_frame(image, state)`` places one frame and returns a
:class:`Placement`; ``mosaic()`` and ``coverage()`` give the current pictures. The batch mosaicer
refines everything afterwards; this one has to keep up with 10 frames a second on one core, so it
works on frames reduced to ``work_px`` on their longer side, with ORB features and a similarity
(4 degrees of freedom: a camera facing a wall at a steady distance, which drifts far less than a
free homography chained frame to frame). Each frame is matched to the last keyframe (a frame
that moved more than ``keyframe_step`` of the work-frame diagonal from the one before), so a
hovering vehicle does not accumulate error; when that fails, to the previous placed frame; when
that fails, to the keyframes nearest where the recent motion puts the camera (relocalisation);
when that fails too and the vehicle's state gives a position, the frame is placed by odometry. A new
keyframe is also matched to the nearest keyframe of an earlier stretch (the pass before): when
that succeeds its placement wins, so drift along a pass stops at the next pass. Each new keyframe's
scale and rotation are pulled part of the way to the sweep's level (the first frame's, the scale
following the distance to the wall when the state gives it), so the small errors of each match do
not add up along the chain (see :meth:`LiveMosaic._level`).

Coverage: a mosaic cell is *covered* when a placed frame imaged it at usable resolution (frame
scale within ``scale_range`` of the sweep's median) and sharpness (variance of the Laplacian of
the work frame against its half-size copy, see :func:`sharpness`, at least ``min_sharpness`` of
the recent frames' upper quartile: motion blur and defocus fall below). Gaps are cells inside the area the sweep has spanned that no usable frame covered.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np


@dataclass(frozen=True)
class LiveParams:
    work_px: int = 320  # frames are reduced to this on their longer side
    mosaic_scale: float = 0.25  # mosaic px per full-frame px
    features: int = 800  # 500 lost track at a 37 %-overlap pass change (500/600 placed), 800: 596/600, 29 ms p95 CPU
    fast_threshold: int = 5  # ORB corner threshold: low, so smooth corroded plate still gives corners
    min_inliers: int = 20
    ransac_px: float = 3.0  # in work-frame pixels
    keyframe_step: float = 0.1  # of the work-frame diagonal
    recent_keys: int = 8  # keyframes this recent are not loop-closure candidates
    loop_radius: float = 0.4  # of the frame diagonal: how near an earlier keyframe must be predicted
    relocalise_keys: int = 4  # after a failure, this many keyframes nearest the extrapolated position are tried
    scale_range: float = 1.5  # usable if the frame's scale is within this factor of the sweep's median
    min_sharpness: float = 0.5  # usable if Laplacian variance >= this share of the recent frames' upper quartile
    sharp_window: int = 40  # recent frames whose upper quartile the sharpness is judged against when too few saw the same wall
    sharp_radius: float = 0.35  # frames placed within this share of the frame diagonal saw the same wall
    min_sharpness_recent: float = 0.3  # and never below this share of the recent frames' upper quartile
    stall_s: float = 1.0  # a gap between frames longer than this is a stalled stream
    warmup: int = 5  # frames judged (usable or not) once this many are placed: the medians need them
    margin_px: int = 256  # the canvas grows by at least this many mosaic px
    seed: int = 0
    equalise: bool = True  # local contrast (CLAHE) before ORB: a smooth, dull plate still gives corners
    level_gain: float = 0.3  # a new keyframe's scale and rotation are pulled this share of the way to the level (see _level)


def sharpness(gray: np.ndarray) -> float:
    """Fine-scale detail against detail one octave coarser: variance of the Laplacian of the
    image over that of its half-size copy. Blur lowers it; the wall's own texture, which varies
    along a sweep, scales both and cancels."""
    fine = float(cv2.Laplacian(gray, cv2.CV_32F).var())
    coarse = float(cv2.Laplacian(cv2.pyrDown(gray), cv2.CV_32F).var())
    return fine / max(coarse, 1e-6)


@dataclass(frozen=True)
class Placement:
    """Where one frame went: ``H`` maps full-frame pixels to live-mosaic pixels (None if unplaced)."""

    index: int
    H: np.ndarray | None
    how: str  # "first", "keyframe", "previous", "loop" (an earlier pass), "relocalised", "odometry" or "unplaced"
    usable: bool  # counts toward coverage (resolution and sharpness)
    sharpness: float
    ms: float  # wall time spent in add_frame
    cpu_ms: float  # CPU time of the calling thread in add_frame (what one free core would take)
    problem: str = ""  # one line, e.g. a stalled stream or a frame that could not be placed

    @property
    def placed(self) -> bool:
        return self.H is not None


@dataclass
class _Frame:
    index: int
    kp: np.ndarray  # (N, 2) work-frame px
    desc: np.ndarray
    H: np.ndarray  # work-frame px -> mosaic px


@dataclass
class LiveMosaic:
    """Incremental mosaic of a sweep of ``frame_wh`` frames (see the module docstring)."""

    frame_wh: tuple[int, int]
    params: LiveParams = field(default_factory=LiveParams)
    m_per_px: float | None = None  # wall metres per full-frame px, if known (for odometry placement)

    def __post_init__(self) -> None:
        w, h = self.frame_wh
        self._k = min(1.0, self.params.work_px / max(w, h))  # work px per frame px
        self._work_wh = (max(int(round(w * self._k)), 1), max(int(round(h * self._k)), 1))
        self._orb = cv2.ORB_create(nfeatures=self.params.features, fastThreshold=self.params.fast_threshold, edgeThreshold=15, patchSize=15)
        self._matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
        self._clahe = cv2.createCLAHE(clipLimit=3.0, tileGridSize=(4, 4))
        self._canvas = np.zeros((0, 0, 3), np.uint8)
        self._cover = np.zeros((0, 0), np.uint8)  # 1: seen, 2: seen usable
        self._origin = np.zeros(2)  # mosaic px of canvas pixel (0, 0)
        self._key: _Frame | None = None
        self._keys: list[_Frame] = []
        self._prev: _Frame | None = None
        self._sharp: list[float] = []
        self._centres: list[np.ndarray] = []  # mosaic centre of every placed frame, beside _sharp
        self._scales: list[float] = []
        self._last_t: float | None = None
        self._last_pos: tuple[np.ndarray, np.ndarray] | None = None  # (position m, H) of the last placed frame
        self._pending: list[tuple] = []  # placed frames of the warm-up, painted once judged
        self._usable_of: dict[int, bool] = {}
        self._level_ref: tuple[float, float | None] | None = None  # (scale, distance to the wall) of the first frame
        self.placements: list[Placement] = []
        self.problems: list[str] = []

    # ----- placing -----

    def add_frame(self, image: np.ndarray, state: dict | None = None) -> Placement:
        """Place one frame. ``state`` (optional): ``t_s`` (capture time, for stall detection) and
        ``position_m`` (x, y, z in the vehicle's odometry frame; y right-to-left, z up along the wall)."""
        t0, c0 = time.perf_counter(), time.thread_time()
        index = len(self.placements)
        problem = ""
        t_s = (state or {}).get("t_s")
        if t_s is not None and self._last_t is not None and t_s - self._last_t > self.params.stall_s:
            problem = f"live stream stalled: no frame for {t_s - self._last_t:.1f} s before frame {index}"
        if t_s is not None:
            self._last_t = t_s
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
        work = cv2.resize(gray, self._work_wh, interpolation=cv2.INTER_AREA)
        sharp = sharpness(work)
        kps, desc = self._orb.detectAndCompute(self._clahe.apply(work) if self.params.equalise else work, None)
        kp = np.array([k.pt for k in kps], np.float32).reshape(-1, 2)
        cur = _Frame(index, kp, desc if desc is not None else np.zeros((0, 32), np.uint8), np.eye(3))
        how = "unplaced"
        H = None
        if self._prev is None and self._key is None:
            H, how = self._first_H(), "first"
        else:
            for ref, name in ((self._key, "keyframe"), (self._prev, "previous")):
                if ref is None or (name == "previous" and ref is self._key):
                    continue
                S = self._match(cur, ref)
                if S is not None:
                    H, how = ref.H @ S, name
                    break
            if H is None:
                H = self._relocalise(cur, index)
                how = "relocalised" if H is not None else how
            if H is None:
                H = self._by_odometry(state)
                how = "odometry" if H is not None else how
            if H is None and sum(p.placed for p in self.placements) < self.params.warmup:
                # nothing worth keeping yet (a featureless first view: the floor, plain paint): start again here
                self._restart(index)
                H, how = self._first_H(), "first"
        usable = False
        if H is not None:
            cur.H = H
            if self._key is None or self._moved(cur, self._key):
                closed = self._close_loop(cur)
                if closed is not None:  # placed against an earlier pass: the chain's drift stops here
                    H = cur.H = closed
                    how = "loop"
                if how == "first":
                    d = (state or {}).get("dist_front_m")
                    self._level_ref = (float(np.sqrt(abs(np.linalg.det(H[:2, :2])))), float(d) if d else None)
                elif how != "odometry":
                    H = cur.H = self._level(H, state)
                self._key = cur
                self._keys.append(cur)
            self._prev = cur
            self._sharp.append(sharp)
            self._scales.append(float(np.sqrt(abs(np.linalg.det(H[:2, :2])))))
            self._centres.append(self._centre(cur))
            small = cv2.resize(image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR), self._work_wh,
                               interpolation=cv2.INTER_AREA)[..., :3]
            self._pending.append((index, small, H, sharp, self._scales[-1], self._centres[-1]))
            if len(self._sharp) >= self.params.warmup:
                for k, sm, Hk, sh, sc, ce in self._pending:
                    ok = self._usable(sh, sc, ce)
                    self._paint(sm, Hk, ok)
                    self._usable_of[k] = ok
                self._pending = []
            usable = self._usable_of.get(index, False)
            pos = (state or {}).get("position_m")
            if pos is not None:
                self._last_pos = (np.asarray(pos, float), H)
        else:
            problem = problem or f"frame {index} could not be placed (no match to the last frames and no position)"
        if problem:
            self.problems.append(problem)
        p = Placement(index, None if H is None else H @ np.diag([self._k, self._k, 1.0]), how, usable, sharp,
                      1000 * (time.perf_counter() - t0), 1000 * (time.thread_time() - c0), problem)
        self.placements.append(p)
        return p

    def _level(self, H: np.ndarray, state: dict | None) -> np.ndarray:
        """Pull a new keyframe's scale and rotation a share ``level_gain`` of the way to the sweep's
        level, keeping where its centre lies. Each match's small scale and rotation error would
        otherwise add up along the chain of keyframes (a random walk: on a 240-frame sweep, frames
        ended 4-5 % too large or small, or turned, and the coverage map's edges moved with them); the
        camera holds its distance to the wall and its mount is level, so the first frame's scale
        (times this distance / first distance, when the state gives the distance to the wall) and
        rotation are the level. Relative placements stay as measured."""
        a = self.params.level_gain
        if a <= 0 or self._level_ref is None:
            return H
        s0, d0 = self._level_ref
        d = (state or {}).get("dist_front_m")
        target = s0 * (float(d) / d0) if d and d0 else s0  # farther: each frame covers more wall, more mosaic px
        s = float(np.sqrt(abs(np.linalg.det(H[:2, :2]))))
        th = float(np.arctan2(H[1, 0] - H[0, 1], H[0, 0] + H[1, 1]))
        s2, th2 = float(np.exp((1 - a) * np.log(s) + a * np.log(target))), (1 - a) * th
        R = s2 * np.array([[np.cos(th2), -np.sin(th2)], [np.sin(th2), np.cos(th2)]])
        c = np.array([self._work_wh[0] / 2, self._work_wh[1] / 2, 1.0])
        m = (H @ c)[:2] / (H @ c)[2]
        return np.vstack([np.hstack([R, (m - R @ c[:2])[:, None]]), [0, 0, 1.0]])

    def _usable(self, sharp: float, scale: float, centre: np.ndarray) -> bool:
        """Sharp enough against the frames that saw the same wall (placed within ``sharp_radius`` of
        the frame diagonal: the same texture, so a smoother stretch of plate is not mistaken for
        blur), or the recent frames when fewer than 4 did; and never far below the recent frames (a
        long run of blurred frames has only blurred neighbours)."""
        recent = float(np.percentile(self._sharp[-self.params.sharp_window:], 75))
        d = np.linalg.norm(np.asarray(self._centres) - centre, axis=1)
        radius = self.params.sharp_radius * np.hypot(*self._work_wh) * float(np.median(self._scales[-50:]))
        near = np.asarray(self._sharp)[d <= radius]
        ref = float(np.percentile(near, 75)) if len(near) >= 4 else recent
        med_scale = float(np.median(self._scales[-200:]))
        return sharp >= self.params.min_sharpness * ref and sharp >= self.params.min_sharpness_recent * recent and (
            1 / self.params.scale_range <= scale / med_scale <= self.params.scale_range)

    def usable(self, index: int) -> bool:
        """Whether frame ``index`` counted toward coverage (frames of the warm-up are judged late)."""
        return self._usable_of.get(index, False)

    def _restart(self, index: int) -> None:
        """Drop the few frames placed so far (fewer than ``warmup``) and start the mosaic again."""
        note = f"dropped: frame {index} matched none of the first frames and the live mosaic started again there"
        self.placements = [Placement(p.index, None, "unplaced", False, p.sharpness, p.ms, p.cpu_ms, p.problem or note)
                           if p.placed else p for p in self.placements]
        self._canvas = np.zeros((0, 0, 3), np.uint8)
        self._cover = np.zeros((0, 0), np.uint8)
        self._origin = np.zeros(2)
        self._key, self._prev, self._last_pos, self._level_ref = None, None, None, None
        self._keys, self._sharp, self._scales, self._pending, self._centres = [], [], [], [], []
        self._usable_of = {}

    def _first_H(self) -> np.ndarray:
        s = self.params.mosaic_scale / self._k  # mosaic px per work px
        return np.diag([s, s, 1.0])

    def _match(self, cur: _Frame, ref: _Frame) -> np.ndarray | None:
        """Similarity cur work px -> ref work px, or None."""
        if len(cur.kp) < self.params.min_inliers or len(ref.kp) < self.params.min_inliers:
            return None
        m = self._matcher.match(cur.desc, ref.desc)
        if len(m) < self.params.min_inliers:
            return None
        src = cur.kp[[x.queryIdx for x in m]]
        dst = ref.kp[[x.trainIdx for x in m]]
        cv2.setRNGSeed(self.params.seed)
        A, inl = cv2.estimateAffinePartial2D(src, dst, method=cv2.RANSAC, ransacReprojThreshold=self.params.ransac_px,
                                             maxIters=500, confidence=0.99, refineIters=5)
        if A is None or inl is None or int(inl.sum()) < self.params.min_inliers:
            return None
        s = np.sqrt(abs(np.linalg.det(A[:, :2])))
        if not 0.67 <= s <= 1.5:
            return None
        return np.vstack([A, [0, 0, 1]])

    def _centre(self, f: _Frame) -> np.ndarray:
        v = f.H @ np.array([self._work_wh[0] / 2, self._work_wh[1] / 2, 1.0])
        return v[:2] / v[2]

    def _relocalise(self, cur: _Frame, index: int) -> np.ndarray | None:
        """After a failure: match the keyframes nearest to where the recent motion (last placed
        frames' velocity, extrapolated over the frames since, at most 3) puts the camera now; after
        5 failures in a row, one of them a frame, in turn."""
        placed = []
        for p in reversed(self.placements):  # the last two placed, however long ago (not only among the last 30)
            if p.placed:
                placed.insert(0, p)
                if len(placed) == 2:
                    break
        if not self._keys or len(placed) < 2:
            return None
        c = np.array([self.frame_wh[0] / 2, self.frame_wh[1] / 2, 1.0])
        (i0, a), (i1, b) = [(p.index, p.H @ c) for p in placed[-2:]]
        a, b = a[:2] / a[2], b[:2] / b[2]
        guess = b + (b - a) / max(i1 - i0, 1) * min(index - i1, 3)  # not further: after a turn the old motion misleads
        d = np.array([np.linalg.norm(self._centre(k) - guess) for k in self._keys])
        near = np.argsort(d)[: 2 * self.params.relocalise_keys]
        lost = index - i1 - 1  # frames not placed since the last placed one
        # lost for long: one keyframe a frame, in turn among the nearest, so a lost track costs no more than a placed frame
        tries = near[: self.params.relocalise_keys] if lost < 5 else [near[lost % len(near)]]
        for k in tries:
            S = self._match(cur, self._keys[k])
            if S is not None:
                return self._keys[k].H @ S
        return None

    def _close_loop(self, cur: _Frame) -> np.ndarray | None:
        """Match a new keyframe to the nearest keyframe of an earlier stretch (not among the last
        ``recent_keys``) that the current placement puts over the same wall; its placement then wins."""
        old = self._keys[: -self.params.recent_keys] if len(self._keys) > self.params.recent_keys else []
        if not old:
            return None
        c = self._centre(cur)
        d = np.array([np.linalg.norm(self._centre(k) - c) for k in old])
        scale = np.sqrt(abs(np.linalg.det(cur.H[:2, :2])))
        k = int(np.argmin(d))
        if d[k] > self.params.loop_radius * np.hypot(*self._work_wh) * scale:
            return None
        S = self._match(cur, old[k])
        return None if S is None else old[k].H @ S

    def _moved(self, cur: _Frame, key: _Frame) -> bool:
        c = np.array([self._work_wh[0] / 2, self._work_wh[1] / 2, 1.0])
        a, b = cur.H @ c, key.H @ c
        step = np.hypot(*(a[:2] / a[2] - b[:2] / b[2])) / np.sqrt(abs(np.linalg.det(key.H[:2, :2])))
        return step > self.params.keyframe_step * np.hypot(*self._work_wh)

    def _by_odometry(self, state: dict | None) -> np.ndarray | None:
        """Shift the last placed frame by the vehicle's motion along the wall (needs ``m_per_px``)."""
        pos = (state or {}).get("position_m")
        if pos is None or self._last_pos is None or not self.m_per_px:
            return None
        d = np.asarray(pos, float) - self._last_pos[0]
        s = self.params.mosaic_scale / self.m_per_px  # mosaic px per metre
        T = np.array([[1, 0, -d[1] * s], [0, 1, -d[2] * s], [0, 0, 1.0]])  # y left -> x right, z up -> y down
        return T @ self._last_pos[1]

    # ----- pictures -----

    def _paint(self, small: np.ndarray, H: np.ndarray, usable: bool) -> None:
        w, h = self._work_wh
        q = cv2.perspectiveTransform(np.float32([[0, 0], [w, 0], [w, h], [0, h]]).reshape(-1, 1, 2), H).reshape(-1, 2)
        self._grow(q)
        T = np.array([[1, 0, -self._origin[0]], [0, 1, -self._origin[1]], [0, 0, 1.0]])
        x0, y0 = np.maximum(np.floor(q.min(0) - self._origin).astype(int), 0)
        x1, y1 = np.ceil(q.max(0) - self._origin).astype(int) + 1
        x1, y1 = min(x1, self._canvas.shape[1]), min(y1, self._canvas.shape[0])
        if x1 <= x0 or y1 <= y0:
            return
        R = np.array([[1, 0, -x0], [0, 1, -y0], [0, 0, 1.0]]) @ T @ H
        warped = cv2.warpPerspective(small, R, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        # the frame's footprint, its corners rounded to the nearest cell and the cells on its edge included (the
        # rule every footprint is drawn by, the truth's too); a warped mask would leave out the outer half cell
        mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.fillConvexPoly(mask, np.round(q - self._origin - (x0, y0)).astype(np.int32), 1)
        mask = mask > 0
        roi = self._canvas[y0:y1, x0:x1]
        cov = self._cover[y0:y1, x0:x1]
        # a usable frame paints over anything; an unusable one only over what no usable frame covered
        paint = mask if usable else mask & (cov < 2)
        roi[paint] = warped[paint]
        cov[mask] = np.maximum(cov[mask], 2 if usable else 1)

    def _grow(self, q: np.ndarray) -> None:
        lo, hi = q.min(0), q.max(0)
        H_, W_ = self._cover.shape
        if H_ and lo[0] >= self._origin[0] and lo[1] >= self._origin[1] and hi[0] < self._origin[0] + W_ and hi[1] < self._origin[1] + H_:
            return
        m = self.params.margin_px
        if not H_:
            new_lo, new_hi = np.floor(lo) - m, np.ceil(hi) + m
        else:
            new_lo = np.minimum(self._origin, np.floor(lo) - m)
            new_hi = np.maximum(self._origin + [W_, H_], np.ceil(hi) + m)
        size = (new_hi - new_lo).astype(int)
        canvas = np.zeros((size[1], size[0], 3), np.uint8)
        cover = np.zeros((size[1], size[0]), np.uint8)
        if H_:
            ox, oy = (self._origin - new_lo).astype(int)
            canvas[oy : oy + H_, ox : ox + W_] = self._canvas
            cover[oy : oy + H_, ox : ox + W_] = self._cover
        self._canvas, self._cover, self._origin = canvas, cover, new_lo

    def mosaic(self) -> np.ndarray:
        """The low-resolution mosaic so far (BGR; black where nothing was seen)."""
        return self._canvas.copy()

    @property
    def origin_px(self) -> np.ndarray:
        """Mosaic coordinates of the pictures' pixel (0, 0): picture px = mosaic px - origin."""
        return self._origin.copy()

    def covered(self) -> np.ndarray:
        """Boolean map over the mosaic: imaged at usable resolution and sharpness."""
        return self._cover == 2

    def gaps(self) -> np.ndarray:
        """Boolean map: inside the area the sweep spanned (the hull of everything seen), not covered."""
        seen = (self._cover > 0).astype(np.uint8)
        if not seen.any():
            return np.zeros_like(seen, bool)
        pts = cv2.findNonZero(seen)
        hull = np.zeros_like(seen)
        cv2.fillConvexPoly(hull, cv2.convexHull(pts), 1)
        return (hull > 0) & (self._cover < 2)

    def coverage(self) -> np.ndarray:
        """The coverage map as a picture: the mosaic dimmed where covered, gaps in red, nothing elsewhere."""
        out = np.zeros_like(self._canvas)
        cov = self.covered()
        out[cov] = (self._canvas[cov] // 2 + np.array([0, 96, 0], np.uint8))
        out[self.gaps()] = (0, 0, 255)
        return out

    def summary(self) -> dict:
        """Counts for a status line: frames placed, by how, usable, covered and gap area (mosaic px)."""
        hows: dict[str, int] = {}
        for p in self.placements:
            hows[p.how] = hows.get(p.how, 0) + 1
        ms = [p.ms for p in self.placements]
        return {"frames": len(self.placements), "placed": sum(p.placed for p in self.placements), "how": hows,
                "usable": sum(self._usable_of.values()), "covered_px": int(self.covered().sum()),
                "gap_px": int(self.gaps().sum()), "p95_ms": float(np.percentile(ms, 95)) if ms else 0.0,
                "p95_cpu_ms": float(np.percentile([p.cpu_ms for p in self.placements], 95)) if ms else 0.0,
                "problem": self.problems[-1] if self.problems else ""}
