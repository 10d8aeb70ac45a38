"""Sweeps (``inspect_pipe.capture`` format) as mosaic input, and the mosaic-to-wall geometry.

A sweep adds what a folder of images lacks: the camera's intrinsics (frames are undistorted
before registration, and the mosaic is rectified to the wall plane) and the vehicle's state at
each exposure. From those:

- ``m_per_px``: metres of wall per mosaic pixel: the scale of ``wall_from_mosaic``; the camera's
  scale (focal length and the estimated distance of the camera to the wall: front sonar, less the
  camera's forward offset on the body) or, with the smooth-drift fit, within 0.5 % of it;
- ``wall_from_mosaic``: the 3x3 map from mosaic pixels to wall metres (u right from the wall's left
  edge, v up from the floor) of the surveyed wall (the survey plan's, or the simulated wall the
  vehicle faced; positions reach the hold frame through the plan's take-off tie): a similarity
  fitted robustly (Huber) between the point of the wall straight ahead of each camera (the foot of
  the camera centre, from the frame's pose over the wall plane) in the mosaic and the wall point
  the vehicle's position estimate puts there. Odometry drifts and the mosaic does not, so the
  mosaic fixes the shape and odometry places it. When the sweep starts on the ground (its first
  state sample says landed), the position estimate starts at the take-off point: its drift is then
  a smooth curve from zero at that sample (``_smooth_drift_fit``), fitted jointly with the
  similarity, whose scale is held near the camera's (``m_per_px`` below) within 0.5 %; the frames
  taken while taking off, registered to the mosaic for this fit only (``take_off_frames``), tell
  the drift along the wall between lift-off and the first placed frame. Without
  that start the drift is a straight line with a free offset and the scale is the camera's
  (``_linear_drift_fit``). The residual is reported.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ._io import read_image
from ._register import FrameError


# The position estimate's error between two frames (1 sigma): a noise plus a share of the path flown between them.
# Measured on the demo flight (seed 5; estimate against the simulator's truth, in the wall plane): between
# consecutive frames (1.9 cm apart) median 3.5 mm, p90 7.9 mm; 10 frames (19 cm) 12.6 / 20.9 mm; 50 frames
# (85 cm) 49 / 68 mm: about 3 mm + 5.5 % of the path at the median.
ODOMETRY_NOISE_M = 0.004
ODOMETRY_DRIFT = 0.05


class SweepSource:
    """Frames of a sweep, undistorted with the sweep's camera model."""

    SURVEY_STATES = ("flying", "descending")  # fsm states whose frames belong to the wall survey

    def __init__(self, sweep, *, motion_tolerance_m: float = 0.35) -> None:
        self.sweep = sweep
        cam = sweep.meta.camera
        self.K = np.asarray(cam.K, float)
        self.dist = np.asarray(cam.dist, float).ravel()
        self._maps = None
        cam_t = np.asarray(sweep.meta.cam_to_body.t, float)
        dists = [f.dist_front_m - cam_t[0] for f in sweep.frames if f.dist_front_m is not None]
        # metres per frame pixel at the sweep's typical distance: converts odometry to pixels
        self._m_per_px = float(np.median(dists)) / self.focal_px if dists else None
        self.tolerance_px = motion_tolerance_m / self._m_per_px if self._m_per_px else float("inf")
        # the odometry's noise, for the pose adjustment's prior (``_align.pose_prior``)
        self.odometry_noise_px = ODOMETRY_NOISE_M / self._m_per_px if self._m_per_px else None
        self.odometry_drift = ODOMETRY_DRIFT

    def skip_reason(self, i: int) -> str:
        fsm = self.sweep.frames[i].fsm
        if fsm is not None and fsm not in self.SURVEY_STATES:
            return f"taken while the vehicle was {fsm}: not part of the wall survey"
        return ""

    def centre_px(self, i: int) -> np.ndarray | None:
        """Odometry's prediction of where the frame centre is on the wall, in frame pixels
        (x right = wall u, y down = -wall v)."""
        f = self.sweep.frames[i]
        if f.position_m is None or self._m_per_px is None:
            return None
        meta = self.sweep.meta
        u, v = meta.wall_frame().to_wall(meta.to_hold(f.position_m))[0]
        return np.array([u, -v]) / self._m_per_px

    def __len__(self) -> int:
        return len(self.sweep.frames)

    def name(self, i: int) -> str:
        return self.sweep.frames[i].image

    def load(self, i: int) -> np.ndarray:
        why = getattr(self.sweep, "corrupt", {}).get(i)
        if why:  # read_sweep(verify=True) found its checksum wrong
            raise FrameError(why)
        img = read_image(self.sweep.frames[i].image_path)
        if not np.any(self.dist):
            return img
        h, w = img.shape[:2]
        if self._maps is None or self._maps[0].shape[:2] != (h, w):
            self._maps = cv2.initUndistortRectifyMap(self.K, self.dist, None, self.K, (w, h), cv2.CV_32FC1)
        return cv2.remap(img, self._maps[0], self._maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    @property
    def focal_px(self) -> float:
        return float((self.K[0, 0] + self.K[1, 1]) / 2)

    @property
    def principal_px(self) -> tuple[float, float]:
        return float(self.K[0, 2]), float(self.K[1, 2])


#: How far along the wall a take-off frame's registration may move it from where odometry puts
#: it (the odometry gained up to 3 cm over the take-off second on 16 simulated flights; a false
#: match on the plain lower wall moved a frame 51 cm).
TAKE_OFF_TOLERANCE_M = 0.10
#: Two registrations of a take-off frame (to two of the next frames) must place its centre within
#: this of each other: a false match on the plain lower wall rarely agrees with another.
TAKE_OFF_AGREE_M = 0.01


def take_off_frames(source: SweepSource, H: dict[int, np.ndarray], *, links: int = 3) -> dict[int, np.ndarray]:
    """Frames taken while taking off, before the first placed frame, registered to the mosaic
    for the wall map's fit only (frame px -> mosaic px): newest first, each to the best of the
    ``links`` next frames already placed or registered; the chain stops at the first frame that
    registers to none (the camera sinks below the wall's texture) or that moves along the wall
    more than ``TAKE_OFF_TOLERANCE_M`` from where odometry puts it (the altitude is not checked:
    the sonar is clamped or lags in the climb), or whose two best registrations place it more than
    ``TAKE_OFF_AGREE_M`` apart. They are what tells the drift between lift-off and the first
    placed frame."""
    from ._features import detect_features, to_gray
    from ._homography import match_pair

    frames = source.sweep.frames
    first = next((f for f in frames if f.position_m is not None), None)
    if not H or source._m_per_px is None or first is None or first.fsm != "landed":
        return {}  # only the fit from the take-off point (``_smooth_drift_fit``) uses them
    t_first = min(frames[i].t_s for i in H)
    later = sorted(H, key=lambda i: frames[i].t_s)[:links]
    todo = sorted((i for i, f in enumerate(frames) if f.fsm == "taking_off" and f.t_s < t_first), key=lambda i: -frames[i].t_s)
    feats: dict[int, object] = {}

    def features(i: int):
        if i not in feats:
            try:
                feats[i] = detect_features(to_gray(source.load(i)))
            except FrameError:
                feats[i] = None
        return feats[i]

    placed = dict(H)
    out: dict[int, np.ndarray] = {}
    tol_px = TAKE_OFF_TOLERANCE_M / source._m_per_px
    agree_px = TAKE_OFF_AGREE_M / source._m_per_px
    img_wh = (source.sweep.meta.width, source.sweep.meta.height)
    c = np.array([img_wh[0] / 2, img_wh[1] / 2, 1.0])
    for k in todo:
        fk = features(k)
        ck = source.centre_px(k)
        found = []  # (inliers, placement) of each link that registers and agrees with odometry along the wall
        for j in later:
            fj = features(j)
            if fk is None or fj is None:
                continue
            m = match_pair(k, j, fk, fj, img_wh)
            if not m:
                continue
            cj = source.centre_px(j)
            if ck is not None and cj is not None:
                p = np.linalg.inv(m.H) @ c  # frame j's centre in frame k's pixels
                if abs((p[0] / p[2] - c[0]) - (cj[0] - ck[0])) > tol_px:
                    continue
            found.append((m.n_inliers, placed[j] @ m.H))
        found.sort(key=lambda x: -x[0])
        if len(found) < 2:
            break
        (_, h1), (_, h2) = found[:2]
        p1, p2 = h1 @ c, h2 @ c
        if np.linalg.norm(p1[:2] / p1[2] - p2[:2] / p2[2]) > agree_px:
            break
        placed[k] = out[k] = h1
        later = [k] + later[: links - 1]
    return out


@dataclass(frozen=True)
class WallGeometry:
    m_per_px: float
    wall_from_mosaic: np.ndarray  # 3x3
    rms_m: float  # residual between mosaic-placed frame centres and odometry
    max_m: float
    free_scale_m_per_px: float  # scale a free similarity fit would choose: a consistency check
    n_frames: int
    drift_m_per_s: tuple[float, float] = (0.0, 0.0)  # odometry drift rate found in (u, v)
    wall: str = "fore_transverse_bulkhead"  # the surveyed wall whose frame (u, v) is (inspect_pipe.ship.Wall)
    wall_note: str | None = None  # a hold dimension the wall frame lacked
    method: str = ("scale from focal length and wall distance; rotation, offset and the odometry's linear drift fitted "
                   "(Huber) between frame centres in the mosaic and the vehicle's position estimates")
    take_off_frames: tuple[int, ...] = ()  # frames taken while taking off that the fit used (along the wall only)

    def to_json(self) -> dict:
        return {
            "m_per_px": self.m_per_px,
            "wall_from_mosaic": self.wall_from_mosaic.tolist(),
            "wall": self.wall,
            "wall_frame_note": self.wall_note,
            "wall_fit": {
                "method": self.method,
                "odometry_drift_m_per_s": [round(d, 5) for d in self.drift_m_per_s],
                "rms_m": round(self.rms_m, 4),
                "max_m": round(self.max_m, 4),
                "free_scale_m_per_px": self.free_scale_m_per_px,
                "n_frames": self.n_frames,
                "take_off_frames": list(self.take_off_frames),
            },
        }


#: The smooth-drift fit (chosen on simulated demo flights: walls of seeds 5, 11 and 12, one flight
#: each; docs/mosaic.md): odometry noise (each axis) in the air and on the ground, the drift's knots,
#: the spread of its second difference per knot (how fast the velocity bias may change), the
#: scale's spread about the camera's.
ODOMETRY_SD_M = 0.005
GROUND_SD_M = 0.002  # the drift seen while landed (each sample)
DRIFT_KNOT_S = 2.0
DRIFT_CURVATURE_SD_M = 0.0033
SCALE_SD = 0.005
HUBER_M = 0.05


def _foot_px(h: np.ndarray, K: np.ndarray) -> np.ndarray | None:
    """The frame pixel that sees the foot of the camera centre on the wall (the wall point straight
    ahead of the camera, along the plane's normal), from ``h`` (frame px -> mosaic px) of a pose
    model (``h^-1 ~ K [r1 r2 t] A``, ``A`` a similarity of the wall plane); None when ``h`` is no
    such pose (free homographies)."""
    B = np.linalg.inv(K) @ np.linalg.inv(h)
    n1, n2 = np.linalg.norm(B[:, 0]), np.linalg.norm(B[:, 1])
    if n1 <= 0 or n2 <= 0:
        return None
    r1, r2 = B[:, 0] / n1, B[:, 1] / n2
    if abs(n1 / n2 - 1) > 0.02 or abs(r1 @ r2) > 0.02:
        return None
    n = np.cross(r1, r2)
    if abs(n[2]) < 0.5:  # the wall seen at more than 60 degrees: keep the principal point
        return None
    p = K @ (n if n[2] > 0 else -n)
    return p / p[2]


def _ground_drift(sweep, to_wall_u) -> np.ndarray | None:
    """(N, 2) [t, u drift] of the sweep's first state samples while the vehicle stood landed at the
    take-off point, where the position estimate is initialised: the estimate's change along the wall
    there is its drift alone (the first row is (t0, 0)). None when the first state sample is not
    landed (the sweep started in the air)."""
    rows = []
    for f in sweep.frames:
        if f.position_m is None:
            continue
        if f.fsm != "landed":
            break
        rows.append((float(f.t_s), to_wall_u(f.position_m)))
    if not rows:
        return None
    g = np.array(rows, float)
    g[:, 1] -= g[0, 1]
    return g


def wall_geometry(sweep, H: dict[int, np.ndarray], focal_px: float, principal_px: tuple[float, float],
                  take_off: dict[int, np.ndarray] | None = None) -> WallGeometry | None:
    """Mosaic -> wall map for the placed frames ``H`` (frame px -> mosaic px), or None when the
    sweep carries no position or wall distance estimates. ``take_off``: frames taken while taking
    off, registered to the mosaic for the fit only (``take_off_frames``); they tell the drift along
    the wall between lift-off and the first placed frame, not the altitude."""
    meta = sweep.meta
    cam_t = np.asarray(meta.cam_to_body.t, float)
    frame = meta.wall_frame()  # the surveyed wall (survey plan, or the simulated wall faced)
    a = frame.facing_heading_rad  # the vehicle faces the wall: the camera's offset turned with it
    cam_offset = np.array([cam_t[0] * np.cos(a) - cam_t[1] * np.sin(a), cam_t[0] * np.sin(a) + cam_t[1] * np.cos(a), cam_t[2]])
    K = np.array([[focal_px, 0.0, principal_px[0]], [0.0, focal_px, principal_px[1]], [0.0, 0.0, 1.0]])
    c = np.array([principal_px[0], principal_px[1], 1.0])

    def pairs(frames: dict[int, np.ndarray]):
        mos, wall, times = [], [], []
        for i, h in frames.items():
            f = sweep.frames[i]
            if f.position_m is None:
                continue
            foot = _foot_px(h, K)
            p = h @ (c if foot is None else foot)
            mos.append(p[:2] / p[2])
            wall.append(frame.to_wall(meta.to_hold(f.position_m)[0] + cam_offset)[0])
            times.append(f.t_s)
        return np.array(mos).reshape(-1, 2), np.array(wall).reshape(-1, 2), np.array(times, float)

    dists = [sweep.frames[i].dist_front_m - cam_t[0] for i in H if sweep.frames[i].dist_front_m is not None]
    M, W, t = pairs(H)
    if not dists or len(M) < 3:
        return None
    m_per_px = float(np.mean(dists) / focal_px)
    ground = _ground_drift(sweep, lambda p: float(frame.to_wall(meta.to_hold(p)[0] + cam_offset)[0, 0]))
    used: tuple[int, ...] = ()
    if ground is not None and ground[0, 0] <= t.min():
        Ma, Wa, ta = pairs(take_off or {})
        used = tuple(sorted(i for i in (take_off or {}) if sweep.frames[i].position_m is not None))
        L, tr, drift, r, free = _smooth_drift_fit(M, W, t, ground, m_per_px, along=(Ma, Wa[:, 0], ta))
        scale = float(np.sqrt(abs(np.linalg.det(L))))
        method = ("similarity fitted (Huber) between the wall points straight ahead of the cameras in the mosaic and the "
                  "vehicle's position estimates, with the odometry's drift along the wall a smooth curve from zero at take-off "
                  "(the drift seen while landed included; its slope free at lift-off) and the altitude as measured; frames "
                  "taken while taking off registered for the fit along the wall; scale within 0.5 % of focal length and "
                  "wall distance")
    else:
        L, tr, drift, r, free = _linear_drift_fit(M, W, t, m_per_px)
        scale = m_per_px
        method = WallGeometry.method
    T = np.eye(3)
    T[:2, :2], T[:2, 2] = L, tr
    return WallGeometry(scale, T, float(np.sqrt(np.mean(r**2))), float(r.max()), free, len(M), tuple(float(d) for d in drift),
                        frame.wall.value, meta.wall_frame_note(), method, used)


_F = np.diag([1.0, -1.0])  # mosaic rows run down, wall v runs up


def _procrustes(M: np.ndarray, Wt: np.ndarray, weights: np.ndarray, scale: float | None):
    wsum = weights.sum()
    mc = (weights[:, None] * M).sum(0) / wsum
    wc = (weights[:, None] * Wt).sum(0) / wsum
    A = ((weights[:, None] * (_F @ (Wt - wc).T).T).T @ (M - mc))  # cross-covariance
    U, S, Vt = np.linalg.svd(A)
    D = np.diag([1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    if scale is None:
        scale = float(np.trace(np.diag(S) @ D) / (weights * ((M - mc) ** 2).sum(1)).sum())
    L = scale * _F @ R
    return L, wc - L @ mc, scale


def _linear_drift_fit(M: np.ndarray, W: np.ndarray, t: np.ndarray, m_per_px: float):
    """Odometry = truth + offset + drift * (t - t0), the scale the camera's: the mosaic knows the
    true relative layout, so the drift rate is observable wherever the sweep revisits the wall
    (pass to pass). Alternate: Procrustes (fixed scale) on drift-corrected positions, then the
    drift rate by least squares; Huber weights throughout. -> (L, t, drift (u, v) m/s, residuals,
    the scale a free fit chooses)."""
    dt = t - t.min()
    drift = np.zeros(2)
    w = np.ones(len(M))
    span = float(np.ptp(dt))
    for _ in range(30):
        Wc = W - np.outer(dt, drift)
        L, tr, _ = _procrustes(M, Wc, w, m_per_px)
        r_vec = W - ((M @ L.T) + tr)  # what odometry adds to the mosaic's placement
        if span > 1.0:
            A = np.c_[np.ones(len(dt)), dt] * np.sqrt(w)[:, None]
            coef, *_ = np.linalg.lstsq(A, r_vec * np.sqrt(w)[:, None], rcond=None)
            drift = coef[1]
        r = np.linalg.norm(W - np.outer(dt, drift) - ((M @ L.T) + tr), axis=1)
        w = np.where(r <= HUBER_M, 1.0, HUBER_M / np.maximum(r, 1e-12))
    _, _, free = _procrustes(M, W - np.outer(dt, drift), np.ones(len(M)), None)
    r = np.linalg.norm(W - np.outer(dt, drift) - ((M @ L.T) + tr), axis=1)
    return L, tr, drift, r, free


def _smooth_drift_fit(M: np.ndarray, W: np.ndarray, t: np.ndarray, ground: np.ndarray, m_per_px: float,
                      along: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None):
    """Odometry = truth + drift(t) with drift(t0) = 0 at the first state sample, on the ground: the
    position estimate starts at the take-off point and its error grows from there, not necessarily
    linearly (a velocity bias that changes). The drift is piecewise linear along u (the integrated
    speed; v is the measured altitude, which does not drift: a drift term along v would trade with
    the scale, since a lawnmower climbs as time goes on) on knots at ``t0``, at lift-off (the last
    sample on the ground) and every ``DRIFT_KNOT_S`` after it; its second differences are held
    small (``DRIFT_CURVATURE_SD_M``) except at lift-off, where a velocity error may set in at once
    (the simulator's take-off, the PX4Flow scaled by its clamped sonar, gave the estimate 2 cm in
    the second before the first frame was placed; with knots from ``t0`` the drift seen on the
    ground held it near zero until the first knot after take-off). The mosaic's
    relative layout makes the drift's shape observable, the take-off start and the drift seen while
    still landed (``ground``: (t, u drift) rows, ``_ground_drift``) fix its level. One weighted linear
    least-squares problem in the similarity ``[[a, -b], [b, a]] F`` (its scale held within
    ``SCALE_SD`` of ``m_per_px`` along the direction a first Procrustes fit finds), its offset and
    the drift; Huber weights. ``along``: (mosaic px (N, 2), wall u (N,), t (N,)) of frames that
    tell u only (registered while taking off: their altitude is the clamped or lagging sonar's).
    -> (L, t, mean drift rate (u, 0) m/s, residuals of ``M``'s frames, the scale a fit without the
    scale prior chooses)."""
    n = len(M)
    m = M @ _F.T
    t0 = float(ground[0, 0])
    dt = t - t0
    # Knots at t0, at lift-off (the last sample on the ground) and every DRIFT_KNOT_S after it.
    lift = float(ground[-1, 0] - t0)
    if lift > 0.0:
        knots = np.r_[0.0, np.arange(lift, max(float(dt.max()), lift) + DRIFT_KNOT_S, DRIFT_KNOT_S)]
    else:
        knots = np.arange(0.0, dt.max() + DRIFT_KNOT_S, DRIFT_KNOT_S)

    def hat(x: np.ndarray) -> np.ndarray:  # drift at times x (from t0) from the knot values, drift(t0) = 0
        D = np.zeros((len(x), len(knots)))
        j = np.clip(np.searchsorted(knots, x, side="right") - 1, 0, len(knots) - 2)
        fr = np.clip((x - knots[j]) / np.diff(knots)[j], 0.0, 1.0)
        D[np.arange(len(x)), j] = 1 - fr
        D[np.arange(len(x)), j + 1] = fr
        return D[:, 1:]

    if along is not None and len(along[0]):
        ma = np.asarray(along[0], float) @ _F.T
        ua, ta = np.asarray(along[1], float), np.asarray(along[2], float) - t0
    else:
        ma, ua, ta = np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    na = len(ma)
    k = len(knots) - 1

    def u_rows(mm: np.ndarray, tt: np.ndarray) -> np.ndarray:
        nn = len(mm)
        return np.c_[mm[:, :1], -mm[:, 1:], np.ones((nn, 1)), np.zeros((nn, 1)), hat(tt)]

    Au = u_rows(m, dt)
    Av = np.c_[m[:, 1:], m[:, :1], np.zeros((n, 1)), np.ones((n, 1)), np.zeros((n, k))]
    Aa = u_rows(ma, ta).reshape(na, 4 + k)
    A = np.r_[Au, Av, Aa] / ODOMETRY_SD_M
    y = np.r_[W[:, 0], W[:, 1], ua] / ODOMETRY_SD_M
    npar = A.shape[1]
    curv = []
    for q in range(len(knots) - 2):  # second differences of the knot values, drift(knot 0) = 0
        if lift > 0.0 and q == 0:
            continue  # the drift's slope may change at lift-off: no prior there
        row = np.zeros(npar)
        for jj, cf in ((q, 1.0), (q + 1, -2.0), (q + 2, 1.0)):
            if jj >= 1:
                row[4 + jj - 1] = cf / DRIFT_CURVATURE_SD_M
        curv.append(row)
    curv = np.array(curv).reshape(-1, npar)
    G = np.zeros((len(ground), npar))  # the drift seen on the ground
    G[:, 4:4 + k] = hat(ground[:, 0] - t0) / GROUND_SD_M
    curv = np.r_[curv, G]
    curv_q = np.r_[np.zeros(len(curv) - len(G)), ground[:, 1] / GROUND_SD_M]
    # the scale prior along the rotation a first fit finds (a, b) ~ s (cos, sin)
    L0, _, _ = _procrustes(M, W, np.ones(n), m_per_px)
    c0, s0 = (L0 @ _F)[0, 0] / m_per_px, (L0 @ _F)[1, 0] / m_per_px
    prior = np.zeros((1, npar))
    prior[0, :2] = np.array([c0, s0]) / (SCALE_SD * m_per_px)

    def solve(w: np.ndarray, with_prior: bool) -> np.ndarray:
        sw = np.sqrt(np.r_[w[:n], w[:n], w[n:]])[:, None]
        P = np.r_[curv, prior] if with_prior else curv
        q = np.r_[curv_q, [1.0 / SCALE_SD]] if with_prior else curv_q
        x, *_ = np.linalg.lstsq(np.r_[A * sw, P], np.r_[y * sw[:, 0], q], rcond=None)
        return x

    w = np.ones(n + na)
    for _ in range(20):
        x = solve(w, True)
        r = np.hypot(Au @ x - W[:, 0], Av @ x - W[:, 1])
        ra = np.abs(Aa @ x - ua)
        w = np.where(np.r_[r, ra] <= HUBER_M, 1.0, HUBER_M / np.maximum(np.r_[r, ra], 1e-12))
    xf = solve(w, False)
    a, b, tu, tv = x[:4]
    L = np.array([[a, -b], [b, a]]) @ _F
    end = float(dt.max()) if dt.max() > 0 else 1.0
    drift_u = float(np.interp(dt.max(), knots, np.r_[0.0, x[4:4 + k]])) / end
    return L, np.array([tu, tv]), (drift_u, 0.0), r, float(np.hypot(xf[0], xf[1]))


def control_point_geometry(sweep, H: dict[int, np.ndarray], odometry: WallGeometry | None) -> tuple[WallGeometry | None, list[str]]:
    """The survey plan's control points (a pixel of a named frame and the wall point it shows)
    tie the mosaic to the wall: two or more fix rotation, scale and offset (a similarity, least
    squares); one only shifts the odometry's placement. Returns (the geometry, None without usable
    points; a warning for each point left out: its image not in the sweep, or not placed)."""
    plan = sweep.meta.survey_plan
    if plan is None or not plan.control_points:
        return None, []
    by_name = {}
    for i, f in enumerate(sweep.frames):
        by_name.setdefault(f.image, i)
        by_name.setdefault(Path(f.image).name, i)
    K, dist = np.asarray(sweep.meta.K, float), np.asarray(sweep.meta.dist, float)
    mos, wall, unused = [], [], []
    for k, cp in enumerate(plan.control_points):
        i = by_name.get(cp.image, by_name.get(Path(cp.image).name))
        if i is None or i not in H:
            why = "is not a frame of the sweep" if i is None else "was not placed in the main mosaic"
            unused.append(f"survey plan control_points.{k}: image {cp.image!r} {why}; the point is not used")
            continue
        und = cv2.undistortPoints(np.array([[cp.pixel]], np.float64), K, dist, P=K).reshape(2)
        q = H[i] @ np.array([und[0], und[1], 1.0])
        mos.append(q[:2] / q[2])
        wall.append(cp.wall_m)
    if not mos:
        return None, unused
    M, Wm = np.array(mos, float), np.array(wall, float)
    F = np.diag([1.0, -1.0])
    meta = sweep.meta
    if len(M) == 1:
        if odometry is None:
            return None, unused + ["survey plan control_points: one usable point and no odometry fix no scale; the points are not used"]
        T = odometry.wall_from_mosaic.copy()
        p = T @ np.array([M[0, 0], M[0, 1], 1.0])
        T[:2, 2] += Wm[0] - p[:2] / p[2]
        return WallGeometry(odometry.m_per_px, T, 0.0, 0.0, odometry.free_scale_m_per_px, 1, odometry.drift_m_per_s,
                            odometry.wall, odometry.wall_note, odometry.method + "; offset from 1 control point of the survey plan"), unused
    mc, wc = M.mean(0), Wm.mean(0)
    A = (F @ (Wm - wc).T) @ (M - mc)
    U, S, Vt = np.linalg.svd(A)
    D = np.diag([1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    scale = float(np.trace(np.diag(S) @ D) / ((M - mc) ** 2).sum())
    L = scale * F @ R
    t = wc - L @ mc
    r = np.linalg.norm(Wm - (M @ L.T + t), axis=1)
    T = np.eye(3)
    T[:2, :2], T[:2, 2] = L, t
    return WallGeometry(scale, T, float(np.sqrt(np.mean(r ** 2))), float(r.max()), scale, len(M), (0.0, 0.0),
                        meta.wall_frame().wall.value, meta.wall_frame_note(),
                        f"similarity fitted to {len(M)} control points of the survey plan (residual over the points)"), unused


def is_sweep(path: Path) -> bool:
    return (Path(path) / "sweep.json").is_file()
