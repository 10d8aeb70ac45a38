"""Global alignment: all frames of a group placed jointly over every matched pair.

Two frame models share one solver:

- ``pose`` (the default when a group has >= 5 frames): each frame is a camera pose relative to the
  wall plane with shared intrinsics, ``H_i = K [r1 r2 t_i]`` (wall -> image). Six parameters a frame
  (a rotation update and the translation), plus the shared focal length when it is not given and
  radial distortion ``k1, k2`` when no calibration is given. Each frame then keeps the shape a
  pinhole camera over a plane can give it, so errors cannot accumulate into shear or anisotropy
  along the sweep the way free homographies drift.
- ``homography``: a free 8-parameter homography a frame, kept where the pose model fails.

Residuals are in image space, by pairwise transfer through the plane: each inlier correspondence
(p in frame i, q in frame j) gives ``transfer_i->j(p) - q`` and ``transfer_j->i(q) - p`` in pixels.
Transfer was chosen over wall points as parameters because it leaves only the camera parameters
(6 a frame) as unknowns: the trust-region steps are solved over ~1k unknowns instead of ~50k, and
nothing has to be triangulated first. The solver is ``scipy.optimize.least_squares`` (trust region
reflective, LSMR steps, Huber loss at 2 px so a false match costs linearly).
The Jacobian is built by forward differences done per frame role, vectorised over all
correspondences (a row depends on two frames and the intrinsics only), as a sparse matrix with
exactly that pattern. The unknowns are preconditioned by a sparse factorisation of the Gauss-Newton
matrix at the start (:func:`_preconditioner`): unpreconditioned, LSMR needed about one iteration per
unknown for a step (a sweep is a long chain whose slow bending modes are nearly free), so the
adjustment grew with the square of the sweep (a 2,000-frame sweep did not finish in 26 min); with
it a step takes tens of iterations whatever the length.

Gauge: image residuals do not see a similarity of the wall plane (pose model: the reference
frame's in-plane rotation and translation are held) or any homography of the mosaic (homography
model: the reference frame's homography is held). The result is then expressed in mosaic pixels of
the frames' mean scale, centred where the initial layout put the reference frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares


@dataclass(frozen=True)
class AlignParams:
    points_per_pair: int = 40
    loss: str = "huber"  # robust loss of scipy's least_squares
    loss_scale_px: float = 2.0  # residuals beyond this cost linearly (RANSAC keeps inliers to 2 px; 1 px: paint sweep 0.50 / 2.21 px corner error, 2 px: 0.31 / 1.68)
    max_nfev: int = 20
    restart_nfev: int = 10  # evaluations before the preconditioner is rebuilt where the adjustment got (see _solve)
    # the pose adjustment with a fixed focal length: synth_rust_sweep converges in < 10 evaluations, the 800-frame
    # sweep of two 400-frame passes needs about 40 from its similarity start (0.88 px RMS after 20, 0.31 after 40)
    # A fit stopped by this cap is accepted on its RMS while frames held by few pairs may still be far off
    # (validation sweep vt_original_train_173, 12 correspondences a pair: 53 evaluations needed, 40 allowed, 36.8 px
    # corner error at a pass's end, 4.9 px converged): the cap is a guard, not a budget
    pose_max_nfev: int = 100
    ftol: float = 1e-4  # relative cost change that ends the adjustment
    self_calibration_ftol: float = 1e-6  # with the focal length free the valley is flat: follow it further
    self_calibration_max_nfev: int = 60
    # A self-calibrated fit is given up once it is both far off, over stall_ratio x the acceptance limit (see
    # pose_ratio), and stalled, less than stall_progress better than stall_nfev evaluations before. Planar sweeps are
    # within 2.2x after 5 evaluations even from a focal length 3x off, and still moving; the non-planar NPU drone scene
    # sat at 10-33x, 0.02 % better after 5 evaluations, 0.9 % after 60: 7-10 s of CPU each for nothing.
    stall_nfev: int = 5
    stall_ratio: float = 4.0
    stall_progress: float = 0.01
    outlier_px: float = 3.0  # correspondences further off after alignment count as outliers in rms_px
    pose_model: bool = True  # try the pose model (falls back to free homographies where it fails)
    pose_min_frames: int = 5
    # the pose model is kept if its RMS <= pose_ratio x the pairs' own RMS + pose_slack_px. At the true
    # focal length it fits 1.09-1.10x (40-frame synthetic, synth_rust_sweep, synth_rust_paint_sweep);
    # a 3x focal length 4.3x; the non-planar NPU drone and Haltbrekken ROV scenes 1.6-1.8x
    pose_ratio: float = 1.25
    pose_slack_px: float = 0.05
    focal_range: tuple[float, float] = (0.3, 6.0)  # plausible focal lengths, in frame larger sides
    # correspondences a pair in the pose adjustment, spread over the overlap (6 unknowns a frame). 16 validation
    # sweeps (tools/mosaic_validation.py), focal length given: with 12 a pair the max corner error was over 2 px on
    # 173 (36.8 px, the adjustment stopped unconverged; 4.9 converged) and 62 (2.24); with 40, 0.44-1.74 px on all 16
    pose_points_per_pair: int = 40
    # ...within this many correspondences in all (a long sweep's adjustment grows with them: the 2,000-frame sweep's
    # 7,540 pairs at 40 a pair took 2.62 GB and 222 s for pairs and global step, at 12 1.95 GB and 90 s), but never
    # fewer than pose_points_min a pair: 40 a pair up to 1,500 pairs (about 400 frames)
    pose_points_budget: int = 60_000
    pose_points_min: int = 12
    # self-calibration converges on this many a pair, then the poses are polished on pose_points_per_pair at the
    # intrinsics found (with the focal length given, one fit on all is cheaper). Validation sweep 173 self-calibrated:
    # 12: 4.16 px max (goal 4), 20: 3.83, all 40 in one fit: 3.21 at about twice the CPU
    pose_points_first: int = 20
    distortion: bool = True  # refine k1, k2 when no calibration is given
    odometry_prior: bool = True  # the vehicle's odometry, where the source has it, ties consecutive frames' positions
    # the odometry is used only where one similarity maps its displacements onto the start layout's within this share
    # of their variance (axes or scale that contradict the images: the prior would bend the sweep)
    odometry_max_unexplained: float = 0.25


@dataclass(frozen=True)
class Correspondences:
    """Stacked inlier correspondences: rows (frame_i, frame_j, x_i, y_i, x_j, y_j) in pixels."""

    fi: np.ndarray
    fj: np.ndarray
    p: np.ndarray  # (N, 2)
    q: np.ndarray  # (N, 2)

    def within(self, frames) -> "Correspondences":
        keep = np.isin(self.fi, list(frames)) & np.isin(self.fj, list(frames))
        return Correspondences(self.fi[keep], self.fj[keep], self.p[keep], self.q[keep])


@dataclass(frozen=True)
class Odometry:
    """Where the vehicle's odometry put each frame's centre on the wall (``MotionPrior.centre_px``: pixels of a
    wall-aligned frame at the camera's scale), and how far a displacement between two frames can be trusted
    (1 sigma): ``noise_px`` plus ``drift`` of the path flown between them."""

    centre_px: dict[int, np.ndarray]
    noise_px: float
    drift: float


@dataclass(frozen=True)
class _PosePrior:
    """The odometry as residuals of the pose adjustment: for consecutive frames (columns ``ii``, ``jj``), the
    displacement of the camera centre's foot on the wall against the odometry's, mapped into wall units
    (``target``), times ``weight`` (the pairs' noise over the odometry's, so both weigh as their noise says)."""

    ii: np.ndarray
    jj: np.ndarray
    target: np.ndarray  # (n, 2) wall units
    weight: np.ndarray  # (n,)
    scale: float  # wall units per odometry pixel (the similarity's)
    rotation_deg: float


@dataclass(frozen=True)
class Camera:
    """Pinhole with radial distortion (Brown, k1 k2) in pixels."""

    f: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.f, 0, self.cx], [0, self.f, self.cy], [0, 0, 1.0]])

    def max_distortion_px(self, size_wh: tuple[int, int]) -> float:
        """How far the distortion moves the frame's farthest corner."""
        r2 = (max(self.cx, size_wh[0] - self.cx) ** 2 + max(self.cy, size_wh[1] - self.cy) ** 2) / self.f**2
        return float(abs(self.k1 * r2 + self.k2 * r2 * r2) * np.sqrt(r2) * self.f)


IDENTITY_CAMERA = Camera(1.0, 0.0, 0.0)


@dataclass(frozen=True)
class AlignResult:
    H: dict[int, np.ndarray]  # frame -> 3x3, frame pixels (undistorted with ``camera``) -> mosaic pixels
    rms_px: float  # RMS transfer error of the inlier correspondences (<= outlier_px), pixels
    per_pair_rms_px: dict[tuple[int, int], float]
    iterations: int
    model: str = "homography"  # "pose" or "homography"
    camera: Camera | None = None  # pose model: the intrinsics found (or given)
    note: str = ""  # why the pose model was not kept, when it was tried
    odometry: dict | None = None  # pose model with odometry: how it was used (:func:`odometry_record`)


# ----- camera and frame models (pure, vectorised) -----


def _undistort(xy: np.ndarray, cam: Camera) -> np.ndarray:
    """Pixels -> normalised image coordinates, inverting the radial distortion by fixed point."""
    m = np.stack([(xy[:, 0] - cam.cx) / cam.f, (xy[:, 1] - cam.cy) / cam.f], axis=1)
    if cam.k1 == 0.0 and cam.k2 == 0.0:
        return m
    u = m
    for _ in range(6):
        r2 = (u * u).sum(1, keepdims=True)
        u = m / (1 + cam.k1 * r2 + cam.k2 * r2 * r2)
    return u


def _distort(m: np.ndarray, cam: Camera) -> np.ndarray:
    """Normalised image coordinates -> pixels."""
    if cam.k1 != 0.0 or cam.k2 != 0.0:
        r2 = (m * m).sum(1, keepdims=True)
        m = m * (1 + cam.k1 * r2 + cam.k2 * r2 * r2)
    return np.stack([cam.f * m[:, 0] + cam.cx, cam.f * m[:, 1] + cam.cy], axis=1)


def _rodrigues(w: np.ndarray) -> np.ndarray:
    """(n, 3) rotation vectors -> (n, 3, 3) rotation matrices."""
    th = np.linalg.norm(w, axis=1)
    k = w / np.maximum(th, 1e-12)[:, None]
    Kx = np.zeros((len(w), 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2], Kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    Kx[:, 1, 0], Kx[:, 2, 0], Kx[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(th)[:, None, None], np.cos(th)[:, None, None]
    return np.eye(3) + s * Kx + (1 - c) * (Kx @ Kx)


def wall_to_image(model: str, P: np.ndarray, R0: np.ndarray | None) -> np.ndarray:
    """(n, 3, 3) maps from wall (mosaic) coordinates to normalised image coordinates.

    pose: ``P = [w (3), t (3)]``, ``R = R0 @ rodrigues(w)``, map ``[r1 r2 t]``;
    homography: ``P`` holds the 8 free entries of the map (h33 = 1)."""
    if model == "pose":
        R = R0 @ _rodrigues(P[:, :3])
        return np.concatenate([R[:, :, :2], P[:, 3:6, None]], axis=2)
    return np.concatenate([P, np.ones((len(P), 1))], axis=1).reshape(-1, 3, 3)


def _apply_rows(M: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-row 3x3 maps ``M`` (N, 3, 3) applied to homogeneous points (x, y, 1)."""
    m = np.ascontiguousarray(M.reshape(-1, 9).T)  # nine contiguous rows: one pass over M, not nine strided ones
    return m[0] * x + m[1] * y + m[2], m[3] * x + m[4] * y + m[5], m[6] * x + m[7] * y + m[8]


def _transfer(Ainv_src: np.ndarray, A_dst: np.ndarray, cam: Camera, m: np.ndarray) -> np.ndarray:
    """Normalised image coordinates of the source frame (:func:`_undistort`) -> pixels of the destination
    frame, through the wall plane (per-row maps ``A`` wall -> normalised image, ``Ainv`` their inverses)."""
    X, Y, W = _apply_rows(Ainv_src, m[:, 0], m[:, 1])
    u, v, z = _apply_rows(A_dst, X / W, Y / W)
    return _distort(np.stack([u / z, v / z], axis=1), cam)


def _pair_residuals(A_i, Ainv_i, A_j, Ainv_j, cam: Camera, corr: Correspondences,
                    normalised: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(N, 4): symmetric transfer errors in pixels, i->j then j->i (per-row maps and inverses).
    ``normalised``: the correspondences undistorted with ``cam`` (``corr.p``, ``corr.q``), when the caller
    reuses them over many calls at one camera (the Jacobian's columns)."""
    m_p, m_q = normalised if normalised is not None else (_undistort(corr.p, cam), _undistort(corr.q, cam))
    return np.concatenate([_transfer(Ainv_i, A_j, cam, m_p) - corr.q, _transfer(Ainv_j, A_i, cam, m_q) - corr.p], axis=1)


def camera_feet(A: np.ndarray) -> np.ndarray:
    """(n, 2): the point of the wall straight ahead of each camera (the foot of its centre), in wall units,
    from the wall -> normalised image maps ``A = [r1 r2 t]`` (centre ``-R^T t``; the odometry measures it)."""
    return -np.stack([(A[:, :, 0] * A[:, :, 2]).sum(1), (A[:, :, 1] * A[:, :, 2]).sum(1)], axis=1)


def wall_feet(H_wall: dict[int, np.ndarray], K: np.ndarray) -> np.ndarray:
    """(n, 2): :func:`camera_feet` of the frames of ``H_wall`` (frame px -> wall), in sorted frame order."""
    R, t = poses_from_homographies(H_wall, K)
    return camera_feet(np.concatenate([R[:, :, :2], t[:, :, None]], axis=2))


def _prior_residuals(feet_i: np.ndarray, feet_j: np.ndarray, prior: _PosePrior) -> np.ndarray:
    """(n, 2): the feet's displacement against the odometry's, weighted."""
    return (feet_j - feet_i - prior.target) * prior.weight[:, None]


# ----- the problem: parameter vector <-> frames and camera -----


@dataclass(frozen=True)
class _Problem:
    model: str
    frames: list[int]
    ii: np.ndarray  # row -> frame column
    jj: np.ndarray
    corr: Correspondences
    R0: np.ndarray | None
    cam0: Camera
    intrinsics: tuple[str, ...]  # free camera fields ("f", "k1", "k2")
    free: np.ndarray  # bool over the full parameter vector
    cache: dict = field(default_factory=dict, compare=False, repr=False)  # the Jacobian's sparsity

    @property
    def k(self) -> int:
        return 6 if self.model == "pose" else 8

    def unpack(self, x: np.ndarray, full0: np.ndarray) -> tuple[np.ndarray, Camera]:
        full = full0.copy()
        full[self.free] = x
        n = len(self.frames)
        P = full[: n * self.k].reshape(n, self.k)
        vals = dict(zip(self.intrinsics, full[n * self.k :]))
        cam = Camera(vals.get("f", self.cam0.f), self.cam0.cx, self.cam0.cy, vals.get("k1", self.cam0.k1), vals.get("k2", self.cam0.k2))
        return P, cam

    prior: _PosePrior | None = None  # the odometry's rows (pose model only)

    @property
    def n_pair_residuals(self) -> int:
        """The residual vector's first entries are the correspondences' (4 each); the odometry's follow (2 each)."""
        return 4 * len(self.ii)

    def residuals(self, P: np.ndarray, cam: Camera) -> np.ndarray:
        A = wall_to_image(self.model, P, self.R0)
        Ainv = np.linalg.inv(A)
        r = _pair_residuals(A[self.ii], Ainv[self.ii], A[self.jj], Ainv[self.jj], cam, self.corr).ravel()
        if self.prior is None:
            return r
        feet = camera_feet(A)
        return np.r_[r, _prior_residuals(feet[self.prior.ii], feet[self.prior.jj], self.prior).ravel()]

    def _structure(self, ii: np.ndarray, jj: np.ndarray, width: int, intrinsics: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The sparsity of a block of rows, the same at every evaluation: the ``width`` residuals of entry ``n``
        depend on the ``k`` parameters of frames ``ii[n]`` and ``jj[n]`` (and on the free intrinsics, for the
        correspondences). Returns (mask over the (N, width, 2k + m) derivative block of the free columns,
        their column indices, row pointers)."""
        key = ("structure", width)
        if key not in self.cache:
            n, k, N, m = len(self.frames), self.k, len(ii), len(self.intrinsics) if intrinsics else 0
            cols = np.concatenate([ii[:, None] * k + np.arange(k), jj[:, None] * k + np.arange(k),
                                   np.broadcast_to(n * k + np.arange(m), (N, m))], axis=1)
            keep = self.free[cols]
            reduced = np.cumsum(self.free) - 1
            mask = np.broadcast_to(keep[:, None, :], (N, width, 2 * k + m))
            indices = np.broadcast_to(reduced[cols][:, None, :], mask.shape)[mask].astype(np.int32)
            indptr = np.r_[0, np.cumsum(np.repeat(keep.sum(axis=1), width))].astype(np.int32)
            self.cache[key] = (mask, indices, indptr)
        return self.cache[key]

    def jacobian(self, P: np.ndarray, cam: Camera, r0: np.ndarray) -> sp.csr_matrix:
        """Forward differences per frame role (a row depends on frames i, j and the camera only), written
        straight into the fixed sparsity (:meth:`_structure`); the odometry's rows below the correspondences'."""
        k, N, n_free = self.k, len(self.ii), int(self.free.sum())
        r_pairs = r0[: self.n_pair_residuals].reshape(N, 4)
        mask, indices, indptr = self._structure(self.ii, self.jj, 4, True)
        A = wall_to_image(self.model, P, self.R0)
        Ainv = np.linalg.inv(A)
        Ai, Aj, Ai_inv, Aj_inv = A[self.ii], A[self.jj], Ainv[self.ii], Ainv[self.jj]
        mn = (_undistort(self.corr.p, cam), _undistort(self.corr.q, cam))  # the frames' columns share the camera
        block = np.empty((N, 4, 2 * k + len(self.intrinsics)))
        pr = self.prior
        if pr is not None:
            feet = camera_feet(A)
            r_prior = r0[self.n_pair_residuals:].reshape(-1, 2)
            prior_block = np.empty((len(pr.ii), 2, 2 * k))
        for c in range(k):
            h = 1e-7 * max(1.0, float(np.abs(P[:, c]).max()))
            Pp = P.copy()
            Pp[:, c] += h
            Ap = wall_to_image(self.model, Pp, self.R0)
            Ap_inv = np.linalg.inv(Ap)
            block[:, :, c] = (_pair_residuals(Ap[self.ii], Ap_inv[self.ii], Aj, Aj_inv, cam, self.corr, mn) - r_pairs) / h
            block[:, :, k + c] = (_pair_residuals(Ai, Ai_inv, Ap[self.jj], Ap_inv[self.jj], cam, self.corr, mn) - r_pairs) / h
            if pr is not None:
                feet_p = camera_feet(Ap)
                prior_block[:, :, c] = (_prior_residuals(feet_p[pr.ii], feet[pr.jj], pr) - r_prior) / h
                prior_block[:, :, k + c] = (_prior_residuals(feet[pr.ii], feet_p[pr.jj], pr) - r_prior) / h
        for m, name in enumerate(self.intrinsics):
            val = getattr(cam, name)
            h = 1e-6 * max(1.0, abs(val)) if name == "f" else 1e-7
            camp = Camera(**{**cam.__dict__, name: val + h})
            block[:, :, 2 * k + m] = (_pair_residuals(Ai, Ai_inv, Aj, Aj_inv, camp, self.corr) - r_pairs) / h
        J = sp.csr_matrix((block[mask], indices, indptr), shape=(4 * N, n_free))
        if pr is None:
            return J
        mask, indices, indptr = self._structure(pr.ii, pr.jj, 2, False)
        return sp.vstack([J, sp.csr_matrix((prior_block[mask], indices, indptr), shape=(2 * len(pr.ii), n_free))], format="csr")


def _preconditioner(J: sp.csr_matrix, r: np.ndarray, f_scale: float):
    """Maps ``M``, ``M^T`` with ``M^T (J^T W J) M = I`` at the start point (``W``: the robust loss's
    weights there): ``M = P U^-1 D^1/2`` from a sparse LU of the Gauss-Newton matrix, factored without
    pivoting in symmetric mode (``P A P^T = L D L^T``, ``U = D L^T``). In the variables ``z`` of
    ``x = x0 + M z`` the problem is well conditioned, so LSMR solves each trust-region step in a few
    iterations instead of about one per unknown."""
    from scipy.sparse.linalg import splu

    w = np.minimum(1.0, f_scale / np.maximum(np.abs(r), 1e-12))  # Huber's weights (IRLS)
    Jw = sp.diags(np.sqrt(w)) @ J
    A = (Jw.T @ Jw).tocsc()
    d = A.diagonal()
    A = (A + sp.diags(1e-9 * np.maximum(d, 1e-12 * max(float(d.max()), 1e-300)))).tocsc()
    lu = splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    s = np.sqrt(np.maximum(lu.U.diagonal(), 1e-300))
    # U alone, as a factorisation of itself (no reordering, no pivoting): its solves run in SuperLU
    tri = splu(lu.U.tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    p = lu.perm_c  # P A P^T = L U with P[p[k], k] = 1: M v = P^T U^-1 D^1/2 v

    def M(v: np.ndarray) -> np.ndarray:
        return tri.solve(s * v)[p]

    def MT(v: np.ndarray) -> np.ndarray:
        w = np.empty_like(v)
        w[p] = v
        return s * tri.solve(w, trans="T")

    return M, MT


def _solve(prob: _Problem, full0: np.ndarray, params: AlignParams, give_up_px: float | None = None) -> tuple[np.ndarray, Camera, int, bool]:
    """Robust sparse least squares from ``full0``; returns (frame parameters, camera, evaluations, usable).
    With ``give_up_px``, the adjustment stops early once it is stalled above that RMS (:func:`_stalled`)."""
    cache: dict = {}

    def fun(x):
        if "x" in cache and np.array_equal(cache["x"], x):
            return cache["r"]
        P, cam = prob.unpack(x, full0)
        r = prob.residuals(P, cam)
        cache["x"], cache["r"] = x.copy(), r
        return r

    def jac(x):
        P, cam = prob.unpack(x, full0)
        r0 = cache["r"] if "x" in cache and np.array_equal(cache["x"], x) else prob.residuals(P, cam)
        return prob.jacobian(P, cam, r0)

    # The preconditioner is exact only where it was built: far from there (a long sweep started far off) LSMR's steps
    # go astray and the adjustment crawls (the 800-frame sweep of two 400-frame passes: 0.49 px RMS after 20
    # evaluations, 0.37 after 60; the optimum is 0.31). So it is rebuilt every ``restart_nfev`` evaluations, the
    # adjustment going on from where it got (0.32 px after 40). A run that converges sooner never restarts.
    x0 = full0[prob.free]
    total, status = 0, 0
    while True:
        sol, M = _solve_from(fun, jac, x0, params, min(params.restart_nfev, params.max_nfev - total),
                             None if give_up_px is None else _stalled(give_up_px, params, total, prob.n_pair_residuals))
        x0 = x0 + M(sol.x)
        total += int(sol.nfev)
        status = int(sol.status)
        if status != 0 or total >= params.max_nfev or not np.all(np.isfinite(x0)):
            break
    P, cam = prob.unpack(x0, full0)
    # 0: max_nfev reached, -2: given up as stalled; both usable, to be judged by their fit
    return P, cam, total, (status >= 0 or status == -2) and bool(np.all(np.isfinite(x0)))


def _stalled(give_up_px: float, params: AlignParams, nfev0: int = 0, n_pair_residuals: int | None = None):
    """A least_squares callback that stops the adjustment once its RMS transfer error (the larger of a
    correspondence's two; the first ``n_pair_residuals`` residuals) is over ``give_up_px`` and less than
    ``stall_progress`` better than ``stall_nfev`` evaluations before: a fit that far off and that slow
    will not be accepted."""
    history: list[tuple[int, float]] = []

    def callback(intermediate_result) -> None:  # the name scipy looks for to pass the whole result
        r = np.asarray(intermediate_result.fun)[:n_pair_residuals].reshape(-1, 4)
        rms = float(np.sqrt(np.mean(np.maximum(r[:, 0] ** 2 + r[:, 1] ** 2, r[:, 2] ** 2 + r[:, 3] ** 2))))
        nfev = nfev0 + int(intermediate_result.nfev)
        history.append((nfev, rms))
        before = [e for n, e in history if n <= nfev - params.stall_nfev]
        if before and rms > give_up_px and rms > (1.0 - params.stall_progress) * before[-1]:
            raise StopIteration  # least_squares ends with status -2 (trf ignores a returned True)

    return callback


def _solve_from(fun, jac, x0: np.ndarray, params: AlignParams, max_nfev: int, callback=None):
    """One trust-region run from ``x0`` in variables preconditioned there; returns (solution, M)."""
    from scipy.sparse.linalg import LinearOperator

    r0 = fun(x0)
    J0 = jac(x0)
    M, MT = _preconditioner(J0, r0, params.loss_scale_px)
    shape = (len(r0), len(x0))

    def fun_z(z):
        return fun(x0 + M(z))

    def jac_z(z):
        J = J0 if not np.any(z) else jac(x0 + M(z))
        JT = J.T.tocsr()  # once, not at every product (converting it each time cost 9 of 87 s on the NPU sequence)
        return LinearOperator(shape, matvec=lambda v: J @ M(np.ravel(v)), rmatvec=lambda u: MT(JT @ np.ravel(u)), dtype=float)

    # LSMR with tight tolerances (inexact steps crawled: 40 evaluations without converging on a
    # 40-frame sweep), bounded: preconditioned, a step takes tens of iterations (synth_rust_sweep).
    # The trust region is in the preconditioned variables, which already carry the Jacobian's scale.
    sol = least_squares(fun_z, np.zeros(len(x0)), jac=jac_z, method="trf", loss=params.loss, f_scale=params.loss_scale_px,
                        max_nfev=max_nfev, tr_solver="lsmr", callback=callback,
                        tr_options={"atol": 1e-10, "btol": 1e-10, "maxiter": 200, "regularize": False}, ftol=params.ftol, xtol=1e-10, gtol=1e-10)
    return sol, M


def _rows(frames: list[int], corr: Correspondences) -> tuple[np.ndarray, np.ndarray]:
    col = {f: k for k, f in enumerate(frames)}
    return np.array([col[f] for f in corr.fi], dtype=np.int64), np.array([col[f] for f in corr.fj], dtype=np.int64)


def _reference(frames: list[int], ii: np.ndarray, jj: np.ndarray) -> int:
    """The best-connected frame's column (it holds the gauge)."""
    counts = np.bincount(np.r_[ii, jj], minlength=len(frames))
    return int(np.argmax(counts))


# ----- the two models -----


def adjust_homographies(H0: dict[int, np.ndarray], corr: Correspondences, *, params: AlignParams = AlignParams()) -> tuple[dict[int, np.ndarray], int]:
    """Free homographies (frame px -> mosaic px) refined jointly; the reference frame's is held."""
    frames = sorted(H0)
    corr = corr.within(frames)
    ii, jj = _rows(frames, corr)
    ref = _reference(frames, ii, jj)
    P0 = np.array([(lambda a: (a / a[2, 2]).ravel()[:8])(np.linalg.inv(H0[f])) for f in frames])
    free = np.ones(P0.size, dtype=bool)
    free[ref * 8 : ref * 8 + 8] = False
    prob = _Problem("homography", frames, ii, jj, corr, None, IDENTITY_CAMERA, (), free)
    P, _, nfev, _ = _solve(prob, P0.ravel(), params)
    A = wall_to_image("homography", P, None)
    return {f: _normalised(np.linalg.inv(A[k])) for k, f in enumerate(frames)}, nfev


def poses_from_homographies(H: dict[int, np.ndarray], K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera rotation (n, 3, 3) and translation (n, 3) of each frame from its frame -> wall
    homography, ``K^-1 H^-1 ~ [r1 r2 t]`` (Zhang), columns made orthonormal (camera in front)."""
    Rs, ts = [], []
    Kinv = np.linalg.inv(K)
    for f in sorted(H):
        B = Kinv @ np.linalg.inv(H[f])
        lam = 2.0 / (np.linalg.norm(B[:, 0]) + np.linalg.norm(B[:, 1]))
        B = B * lam
        if B[2, 2] < 0:
            B = -B
        r3 = np.cross(B[:, 0], B[:, 1])
        U, _, Vt = np.linalg.svd(np.c_[B[:, 0], B[:, 1], r3 / max(np.linalg.norm(r3), 1e-12)])
        R = U @ Vt
        if np.linalg.det(R) < 0:
            R = U @ np.diag([1, 1, -1]) @ Vt
        Rs.append(R)
        ts.append(B[:, 2])
    return np.array(Rs), np.array(ts)


def homographies_from_poses(model_maps: np.ndarray, K: np.ndarray) -> list[np.ndarray]:
    """Frame px -> wall: ``(K [r1 r2 t])^-1`` for each wall -> normalised image map."""
    return [_normalised(np.linalg.inv(K @ A)) for A in model_maps]


def pose_prior(H_wall: dict[int, np.ndarray], cam: Camera, odometry: Odometry, pair_sigma_px: float,
               params: AlignParams) -> tuple[_PosePrior | None, str]:
    """The odometry as a prior of the pose adjustment started from ``H_wall``: the displacement between
    consecutive frames of the group (frame order is time order) that both have an odometry position.

    The odometry's frame and the wall frame of the adjustment differ by a similarity (axes, scale), fitted
    once here, by least squares, between the odometry's displacements and the start layout's camera feet;
    where it leaves more than ``odometry_max_unexplained`` of their variance unexplained, the odometry
    contradicts the images and is not used (returns None and why). Each displacement's sigma is
    ``noise_px + drift x`` the path the odometry flew between the two frames; its residual is weighted
    by ``pair_sigma_px / sigma``, so a correspondence (whose residuals are in pixels with about the pairs'
    RMS as noise) and the odometry each weigh as their noise says."""
    frames = sorted(H_wall)
    have = [f for f in frames if f in odometry.centre_px]
    if len(have) < 3:
        return None, "fewer than 3 frames with an odometry position"
    col = {f: k for k, f in enumerate(frames)}
    fi, fj = np.array(have[:-1]), np.array(have[1:])
    track = sorted(odometry.centre_px)  # every frame the odometry placed, for the path flown between two
    pos = np.array([odometry.centre_px[f] for f in track], float)
    path = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(pos, axis=0), axis=1))]
    at = {f: k for k, f in enumerate(track)}
    d_odo = np.array([odometry.centre_px[j] - odometry.centre_px[i] for i, j in zip(fi, fj)], float)
    flown = np.array([path[at[j]] - path[at[i]] for i, j in zip(fi, fj)])
    feet = wall_feet(H_wall, cam.K)
    ii, jj = np.array([col[f] for f in fi]), np.array([col[f] for f in fj])
    d_img = feet[jj] - feet[ii]
    o, c = d_odo[:, 0] + 1j * d_odo[:, 1], d_img[:, 0] + 1j * d_img[:, 1]
    energy = float(np.sum(np.abs(c) ** 2))
    if float(np.sum(np.abs(o) ** 2)) <= 0 or energy <= 0:
        return None, "the odometry or the images show no motion"
    z = complex(np.sum(c * np.conj(o)) / np.sum(np.abs(o) ** 2))
    unexplained = float(np.sum(np.abs(c - z * o) ** 2)) / energy
    if unexplained > params.odometry_max_unexplained:
        return None, (f"one similarity leaves {100 * unexplained:.0f} % of the odometry's displacements unexplained "
                      f"by the images (limit {100 * params.odometry_max_unexplained:.0f} %)")
    target = z * o
    sigma_wall = abs(z) * np.maximum(odometry.noise_px + odometry.drift * flown, 1e-3)
    weight = max(pair_sigma_px, 0.05) / sigma_wall
    return _PosePrior(ii, jj, np.c_[target.real, target.imag], weight, abs(z), float(np.degrees(np.angle(z)))), ""


def odometry_record(prior: _PosePrior | None, why: str, H_wall: dict[int, np.ndarray], cam: Camera, pair_sigma_px: float) -> dict:
    """What ``mosaic.json`` says of the odometry prior: how many displacements it tied, and how far the
    fitted poses are from them, in the odometry's sigmas (about 1 where the two agree as their noise says)."""
    if prior is None:
        return {"used": False, "why": why}
    feet = wall_feet(H_wall, cam.K)
    r = _prior_residuals(feet[prior.ii], feet[prior.jj], prior) / max(pair_sigma_px, 0.05)  # in sigmas
    dist = np.hypot(r[:, 0], r[:, 1])
    return {"used": True, "displacements": int(len(prior.ii)), "rms_sigma": round(float(np.sqrt(np.mean(dist**2) / 2)), 3),
            "max_sigma": round(float(dist.max()), 2), "scale": round(prior.scale, 5), "rotation_deg": round(prior.rotation_deg, 3)}


def adjust_poses(
    H0: dict[int, np.ndarray], corr: Correspondences, cam0: Camera, *, free_focal: bool, free_distortion: bool,
    params: AlignParams = AlignParams(), give_up_px: float | None = None, prior: _PosePrior | None = None,
) -> tuple[dict[int, np.ndarray], Camera, int, bool]:
    """Pose-model bundle adjustment from homographies ``H0`` (frame px -> a metric wall frame);
    ``give_up_px``: stop early once stalled above that RMS (:func:`_stalled`); ``prior``: the odometry's
    residuals (:func:`pose_prior`, built on the same frames and wall frame)."""
    frames = sorted(H0)
    corr = corr.within(frames)
    ii, jj = _rows(frames, corr)
    ref = _reference(frames, ii, jj)
    R0, t0 = poses_from_homographies(H0, cam0.K)
    n = len(frames)
    P0 = np.c_[np.zeros((n, 3)), t0]
    intrinsics = (("f",) if free_focal else ()) + (("k1", "k2") if free_distortion else ())
    full0 = np.r_[P0.ravel(), [getattr(cam0, name) for name in intrinsics]]
    free = np.ones(full0.size, dtype=bool)
    free[[ref * 6 + 2, ref * 6 + 3, ref * 6 + 4, ref * 6 + 5]] = False  # in-plane rotation and translation
    prob = _Problem("pose", frames, ii, jj, corr, R0, cam0, intrinsics, free, prior=prior)
    P, cam, nfev, ok = _solve(prob, full0, params, give_up_px)
    A = wall_to_image("pose", P, R0)
    H = dict(zip(frames, homographies_from_poses(A, cam.K)))
    return H, cam, nfev, ok


# ----- shared steps -----


def _normalised(H: np.ndarray) -> np.ndarray:
    return H / H[2, 2]


def mean_scale(H: dict[int, np.ndarray], size_wh: tuple[int, int]) -> float:
    """Mean linear scale (mosaic px per frame px) at the frame centres."""
    c = np.array([size_wh[0] / 2, size_wh[1] / 2, 1.0])
    out = []
    for h in H.values():
        w = h[2] @ c
        J = h[:2, :2] * w - np.outer((h @ c)[:2], h[2, :2])
        out.append(np.sqrt(abs(np.linalg.det(J))) / w**2)
    return float(np.mean(out))


def to_mosaic_frame(H: dict[int, np.ndarray], size_wh: tuple[int, int], anchor: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
    """Express homographies in mosaic pixels of the frames' mean scale, with the rotation and
    position ``anchor`` (e.g. the initial layout) gave the frames on average."""
    s = 1.0 / mean_scale(H, size_wh)
    c = np.array([size_wh[0] / 2, size_wh[1] / 2, 1.0])
    frames = sorted(H)
    X = np.array([(lambda v: v[:2] / v[2])(H[f] @ c) for f in frames]) * s
    Y = np.array([(lambda v: v[:2] / v[2])(anchor[f] @ c) for f in frames])
    if len(frames) >= 2:
        U, _, Vt = np.linalg.svd((Y - Y.mean(0)).T @ (X - X.mean(0)))
        R = U @ np.diag([1, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    else:
        R = np.eye(2)
    t = Y.mean(0) - R @ X.mean(0)
    S = np.array([[s * R[0, 0], s * R[0, 1], t[0]], [s * R[1, 0], s * R[1, 1], t[1]], [0, 0, 1]])
    return {f: _normalised(S @ H[f]) for f in frames}


def pair_errors(H: dict[int, np.ndarray], corr: Correspondences) -> np.ndarray:
    """Per-correspondence mapping disagreement, in frame-i pixels: ``H_i^-1 H_j q - p``."""
    corr = corr.within(H)
    frames = sorted(H)
    ii, jj = _rows(frames, corr)
    Hs = np.array([H[f] for f in frames])
    A = np.linalg.inv(Hs)  # mosaic -> frame px
    r = _pair_residuals(A[ii], Hs[ii], A[jj], Hs[jj], IDENTITY_CAMERA, corr)
    return np.maximum(np.hypot(r[:, 0], r[:, 1]), np.hypot(r[:, 2], r[:, 3]))


def _pair_index(corr: Correspondences) -> tuple[np.ndarray, np.ndarray]:
    """(pair keys (K, 2) sorted, each correspondence's row in them): one pass, linear in the correspondences."""
    keys, inverse = np.unique(np.c_[corr.fi, corr.fj].astype(np.int64), axis=0, return_inverse=True)
    return keys.reshape(-1, 2), inverse.ravel()


def per_pair_rms(err: np.ndarray, corr: Correspondences) -> dict[tuple[int, int], float]:
    keys, inv = _pair_index(corr)
    if not len(keys):
        return {}
    ms = np.bincount(inv, weights=err**2, minlength=len(keys)) / np.bincount(inv, minlength=len(keys))
    return {(int(i), int(j)): float(np.sqrt(m)) for (i, j), m in zip(keys, ms)}


def pose_errors(H: dict[int, np.ndarray], cam: Camera, corr: Correspondences) -> np.ndarray:
    """Like :func:`pair_errors`, for homographies of undistorted pixels and a distorting camera."""
    corr = corr.within(H)
    frames = sorted(H)
    ii, jj = _rows(frames, corr)
    Kinv = np.linalg.inv(cam.K)
    A = np.array([Kinv @ np.linalg.inv(H[f]) for f in frames])  # mosaic -> normalised image
    Ainv = np.linalg.inv(A)
    r = _pair_residuals(A[ii], Ainv[ii], A[jj], Ainv[jj], cam, corr)
    return np.maximum(np.hypot(r[:, 0], r[:, 1]), np.hypot(r[:, 2], r[:, 3]))


def _rms(err: np.ndarray, cut: float) -> float:
    used = err[err <= cut]
    return float(np.sqrt(np.mean(used**2))) if len(used) else 0.0


def pairwise_rms(corr: Correspondences, pair_H: dict[tuple[int, int], np.ndarray]) -> float:
    """RMS of the correspondences under their own pair homographies: what no global model can beat."""
    keys, inv = _pair_index(corr)
    have = np.array([(int(i), int(j)) in pair_H for i, j in keys], dtype=bool)
    if not have.any():
        return 0.0
    Hs = np.array([pair_H[(int(i), int(j))] if h else np.eye(3) for (i, j), h in zip(keys, have)])
    sel = have[inv]
    p = np.einsum("nij,nj->ni", Hs[inv[sel]], np.c_[corr.p[sel], np.ones(int(sel.sum()))])
    err = np.hypot(*(p[:, :2] / p[:, 2:3] - corr.q[sel]).T)
    return float(np.sqrt(np.mean(err**2)))


def _spread(points: np.ndarray, k: int) -> np.ndarray:
    """Indices of ``k`` of ``points`` (N, 2) spread over their extent: greedy farthest-point sampling
    from the point farthest from their centroid."""
    n = len(points)
    if n <= k:
        return np.arange(n)
    d = np.linalg.norm(points - points.mean(axis=0), axis=1)
    pick = [int(np.argmax(d))]
    d = np.linalg.norm(points - points[pick[0]], axis=1)
    for _ in range(k - 1):
        nxt = int(np.argmax(d))
        pick.append(nxt)
        d = np.minimum(d, np.linalg.norm(points - points[nxt], axis=1))
    return np.sort(np.array(pick))


def _pair_keys(corr: Correspondences) -> np.ndarray:
    """One integer per correspondence naming its pair (i, j)."""
    return corr.fi.astype(np.int64) * 1_000_003 + corr.fj


def thin(corr: Correspondences, per_pair: int) -> Correspondences:
    """At most ``per_pair`` correspondences of each pair, spread over the pair's overlap (:func:`_spread`)."""
    keys = _pair_keys(corr)
    order = np.argsort(keys, kind="stable")
    _, start, count = np.unique(keys[order], return_index=True, return_counts=True)
    pick = np.concatenate([order[s + _spread(corr.p[order[s:s + c]], per_pair)]
                           for s, c in zip(start, count)]) if len(keys) else np.zeros(0, int)
    pick.sort()
    return Correspondences(corr.fi[pick], corr.fj[pick], corr.p[pick], corr.q[pick])


def initial_focal(H0: dict[int, np.ndarray], size_wh: tuple[int, int], principal: tuple[float, float],
                  pair_H: dict[tuple[int, int], np.ndarray], params: AlignParams) -> float:
    """Self-calibration's starting point: OpenCV's ``estimateFocal`` on the pair homographies (it
    assumes a rotating camera, so on a translating sweep it is only a seed) competing with a scan
    of the metric-rectification residual of the layout. A scan whose best is the end of the plausible
    range has found no minimum (a drifted chain: validation sweep vt_original_train_173 gave the
    lowest focal length, 154 px, true 618): then the seed if it is plausible, else 1.2 frame sides."""
    from ._rectify import estimate_focal, focal_from_layout

    side = max(size_wh)
    lo, hi = params.focal_range[0] * side, params.focal_range[1] * side
    seed = estimate_focal(list(pair_H.values()), size_wh)
    f, _ = focal_from_layout(H0, size_wh, principal, (lo, hi), seeds=(seed,) if seed else ())
    if f < lo * 1.01 or f > hi / 1.01:
        return seed if seed and lo * 1.01 <= seed <= hi / 1.01 else 1.2 * side
    return f


def similarity_layout(frames: list[int], corr: Correspondences, size_wh: tuple[int, int]) -> dict[int, np.ndarray]:
    """A globally consistent layout of similarities (frame px -> mosaic px), solved linearly, all pairs
    (loop closures included) weighed at once: each frame is ``S_f(p) = z_f (p - c) + t_f`` in complex
    numbers (z: scale and rotation). First the log of every z from the pairs' own similarities
    (``log z_i - log z_j = log z_ij``, least squares), then, z held, the translations (linear in t).
    In log space no frame gains by shrinking (one linear solve for z and t together, its residuals
    in mosaic pixels, let the scale decay along a 400-frame pass). Chaining pair homographies along a
    spanning tree instead adds their errors up: on two 400-frame passes the chained layout was up to
    hundreds of px off where the passes meet, and the pose adjustment started from it did not
    converge. The best-connected frame holds the gauge. A similarity cannot tilt: a start, not a result."""
    n = len(frames)
    if n < 2 or not len(corr.fi):
        return {f: np.eye(3) for f in frames}
    from scipy.sparse.linalg import spsolve

    ii, jj = _rows(frames, corr)
    c = np.array([size_wh[0] / 2, size_wh[1] / 2])
    P = (corr.p[:, 0] - c[0]) + 1j * (corr.p[:, 1] - c[1])
    Q = (corr.q[:, 0] - c[0]) + 1j * (corr.q[:, 1] - c[1])
    # each pair's similarity q ~ z_ij p (centred on its correspondences' means)
    key, inv = np.unique(ii * n + jj, return_inverse=True)
    cnt = np.bincount(inv)
    mp = (np.bincount(inv, P.real) + 1j * np.bincount(inv, P.imag)) / cnt
    mq = (np.bincount(inv, Q.real) + 1j * np.bincount(inv, Q.imag)) / cnt
    dp, dq = P - mp[inv], Q - mq[inv]
    num = dq * np.conj(dp)
    zij = (np.bincount(inv, num.real) + 1j * np.bincount(inv, num.imag)) / np.maximum(np.bincount(inv, np.abs(dp) ** 2), 1e-12)
    pi, pj = key // n, key % n
    ok = np.abs(zij) > 0
    pi, pj, zij, w = pi[ok], pj[ok], zij[ok], np.sqrt(cnt[ok])
    ref = _reference(frames, ii, jj)
    keep = np.flatnonzero(np.arange(n) != ref)
    col = np.full(n, -1)
    col[keep] = np.arange(n - 1)

    def solve(rows_i, rows_j, rhs, weight):
        """Least squares of x_i - x_j = rhs (x_ref = 0)."""
        m = len(rhs)
        r = np.arange(m)
        mi, mj = col[rows_i] >= 0, col[rows_j] >= 0
        A = sp.csr_matrix((np.r_[weight[mi], -weight[mj]], (np.r_[r[mi], r[mj]], np.r_[col[rows_i[mi]], col[rows_j[mj]]])), shape=(m, n - 1))
        N = (A.T @ A).tocsc()
        N = N + sp.identity(n - 1, format="csc") * 1e-12 * max(float(N.diagonal().max()), 1.0)
        x = np.zeros(n)
        x[keep] = spsolve(N, A.T @ (weight * rhs))
        return x

    lz = np.log(zij)
    logz = solve(pi, pj, lz.real, w) + 1j * solve(pi, pj, lz.imag, w)
    z = np.exp(logz)
    # translations: t_i - t_j = z_j Q - z_i P for every correspondence
    d = z[jj] * Q - z[ii] * P
    ones = np.ones(len(d))
    t = solve(ii, jj, d.real, ones) + 1j * solve(ii, jj, d.imag, ones)
    out = {}
    for k, f in enumerate(frames):
        a, b = z[k].real, z[k].imag
        M = np.array([[a, -b], [b, a]])
        tt = np.array([t[k].real, t[k].imag]) - M @ c
        out[f] = np.array([[a, -b, tt[0]], [b, a, tt[1]], [0, 0, 1.0]])
    return out


def _start(H0: dict[int, np.ndarray], corr: Correspondences, size_wh: tuple[int, int]) -> dict[int, np.ndarray]:
    """The pose adjustment's start: the chained layout ``H0`` or :func:`similarity_layout`, whichever
    fits the correspondences better (RMS transfer error: the chained layout fits its chain's pairs
    exactly and errs where the chain closes a loop). synth_rust_sweep: chained 0.88 px, similarity
    2.0 px (kept chained); the 800-frame sweep of two 400-frame passes: chained 61.8 px, similarity 3.1 px."""
    frames = sorted(H0)
    if len(frames) < 3 or not len(corr.fi):
        return H0
    S = similarity_layout(frames, corr, size_wh)
    if not all(np.isfinite(h).all() and abs(np.linalg.det(h[:2, :2])) > 1e-12 for h in S.values()):
        return H0
    rms = lambda H: float(np.sqrt(np.mean(pair_errors(H, corr) ** 2)))  # noqa: E731
    return S if rms(S) < rms(H0) else H0


def fit_pose_model(
    H0: dict[int, np.ndarray], corr: Correspondences, size_wh: tuple[int, int], f0: float, principal: tuple[float, float],
    *, self_calibrate: bool, params: AlignParams, give_up_px: float | None = None, from_fixed_focal: bool = False,
    distortion: tuple[float, float] = (0.0, 0.0), odometry: Odometry | None = None, pair_sigma_px: float = 1.0,
) -> tuple[dict[int, np.ndarray], Camera, np.ndarray, bool, dict | None]:
    """Rectify the layout with ``f0``, then bundle-adjust the pose model on a thinned set of
    correspondences; returns (H, camera, errors of all correspondences, converged, the odometry's
    record or None). ``distortion`` (k1, k2) starts the camera, held fixed unless self-calibrating. A
    self-calibrated fit stalled above ``give_up_px`` stops there (:func:`_stalled`). ``odometry``, where
    given (and ``params.odometry_prior``), ties consecutive frames (:func:`pose_prior`, on the rectified
    start; ``pair_sigma_px``: the pairs' own RMS).

    Self-calibration starts from the chained layout ``H0``: its perspective is what finds the focal
    length (from the similarity start synth_rust_paint_sweep ended 1.01 / 8.46 px corner error, f 938,
    against 0.51 / 2.35, f 927). ``from_fixed_focal`` starts it instead from the pose model fitted with
    ``f0`` fixed from the better start (:func:`_start`): where the chain has drifted, the free fit from
    it crawls (vt_original_train_130: 0.70 px RMS after 60 evaluations against the pairs' 0.50; from
    the fixed-focal fit 0.52 px in 9 + 15)."""
    from ._rectify import rectify

    n_pairs = len(np.unique(_pair_keys(corr)))
    per_pair = min(params.pose_points_per_pair, max(params.pose_points_min, params.pose_points_budget // max(n_pairs, 1)))
    params = replace(params, pose_points_per_pair=per_pair)
    fixed = replace(params, max_nfev=params.pose_max_nfev)
    thinned = thin(corr, per_pair)
    cam = Camera(f0, *principal, *distortion)
    H_wall, _ = rectify(H0 if self_calibrate and not from_fixed_focal else _start(H0, corr, size_wh), size_wh, f0, principal)
    use_odometry = odometry is not None and params.odometry_prior
    prior, why = None, ""

    def fixed_fit(H_wall, c, cam):
        """A fit at the current focal length, the odometry's similarity fitted to the layout it starts from
        (the wall frame's scale follows the focal length, so a prior built before self-calibration would
        hold the focal length where it started)."""
        nonlocal prior, why
        if use_odometry:
            prior, why = pose_prior(H_wall, cam, odometry, pair_sigma_px, params)
        return adjust_poses(H_wall, c, cam, free_focal=False, free_distortion=False, params=fixed, prior=prior)

    # self-calibration converges on fewer correspondences first (with the focal length given one fit on all is cheaper)
    first = (thin(corr, params.pose_points_first) if self_calibrate and 0 < params.pose_points_first < params.pose_points_per_pair
             else None)
    if not self_calibrate or from_fixed_focal:
        if first is not None:
            H_wall, cam, _, ok = fixed_fit(H_wall, first, cam)
        H_wall, cam, _, ok = fixed_fit(H_wall, thinned, cam)
    if self_calibrate:  # along the flat valley of a free focal length, no restarts (they ended 6 px from it on synth_rust_sweep)
        # without the odometry: its similarity, fitted at the starting focal length, would hold the focal length there
        free = replace(params, ftol=params.self_calibration_ftol, max_nfev=params.self_calibration_max_nfev,
                       restart_nfev=params.self_calibration_max_nfev)
        H_wall, cam, _, ok = adjust_poses(H_wall, first if first is not None else thinned, cam, free_focal=True,
                                          free_distortion=params.distortion, params=free, give_up_px=give_up_px)
        prior, why = None, "not used while self-calibrating" if use_odometry else ""
        if ok and first is not None:  # the intrinsics found, the poses polished on every correspondence
            H_wall, cam, _, ok = fixed_fit(H_wall, thinned, cam)
    record = odometry_record(prior, why, H_wall, cam, pair_sigma_px) if use_odometry else None
    return H_wall, cam, pose_errors(H_wall, cam, corr), ok, record


def quick_layout(H0: dict[int, np.ndarray], corr: Correspondences, size_wh: tuple[int, int], *,
                 focal_px: float | None = None, pair_H: dict[tuple[int, int], np.ndarray] | None = None,
                 params: AlignParams = AlignParams()) -> dict[int, np.ndarray]:
    """A cheap global layout for proposing more pairs: the pose model with a fixed focal length
    (the given one, else a typical 1.2 frame sides), few correspondences, few iterations. Kept
    only if it fits as the pose model must (see :func:`align_group`); else the chained layout ``H0``
    (a scene far from planar, or a focal length far off, would mislead the guided matching)."""
    if len(H0) < params.pose_min_frames:
        return H0
    w, h = size_wh
    corr = corr.within(H0)
    quick = replace(params, pose_points_per_pair=6, max_nfev=5, pose_max_nfev=5)
    H, _, err, ok, _ = fit_pose_model(H0, corr, size_wh, focal_px or 1.2 * max(w, h), (w / 2, h / 2),
                                      self_calibrate=False, params=quick)
    pairs_rms = pairwise_rms(corr, {k: v for k, v in (pair_H or {}).items() if k[0] in H0 and k[1] in H0})
    limit = params.pose_ratio * pairs_rms + params.pose_slack_px
    return to_mosaic_frame(H, size_wh, H0) if ok and len(err) and float(np.sqrt(np.mean(err**2))) <= limit else H0


def align_group(
    H0: dict[int, np.ndarray],
    corr: Correspondences,
    size_wh: tuple[int, int],
    *,
    focal_px: float | None = None,
    principal_px: tuple[float, float] | None = None,
    pair_H: dict[tuple[int, int], np.ndarray] | None = None,
    camera: Camera | None = None,
    odometry: Odometry | None = None,
    params: AlignParams = AlignParams(),
) -> AlignResult:
    """Global alignment of one connected group from its initial layout ``H0`` (frame px -> mosaic px).

    Groups of >= ``pose_min_frames`` frames get the pose model, from the layout rectified with the
    given focal length or a self-calibrated one (:func:`initial_focal`). It is kept unless it finds
    an implausible focal length or fits the correspondences worse than ``pose_ratio`` x their own
    pair homographies' RMS + ``pose_slack_px``. A given focal length the pose model cannot fit while a
    self-calibrated one can is reported as contradicting the images. Otherwise the group keeps
    free homographies, and ``note`` says why.

    ``camera``, settled by an earlier alignment of the same sweep (``_register.align_groups``), replaces
    ``focal_px`` and self-calibration: the pose model is fitted once, with it held fixed. ``odometry``
    (a sweep with the vehicle's positions) ties consecutive frames in every pose fit (:func:`pose_prior`);
    ``odometry`` of the result says how."""
    frames = sorted(H0)
    corr = corr.within(frames)
    pair_H = {k: v for k, v in (pair_H or {}).items() if k[0] in H0 and k[1] in H0}
    w, h = size_wh
    principal = tuple(principal_px) if principal_px is not None else (w / 2, h / 2)
    distortion = (0.0, 0.0)
    if camera is not None:
        focal_px, principal, distortion = camera.f, (camera.cx, camera.cy), (camera.k1, camera.k2)
    side = max(w, h)
    f_lo, f_hi = params.focal_range[0] * side, params.focal_range[1] * side
    nfev = 0
    why = ""
    if params.pose_model and len(frames) >= params.pose_min_frames:
        pairs_rms = pairwise_rms(corr, pair_H)
        limit = params.pose_ratio * pairs_rms + params.pose_slack_px
        give_up_px = params.stall_ratio * limit
        # (given focal length, self-calibrate, from the fixed-focal fit): the last only after a self-calibrated fit
        # that missed by less than the give-up margin (a slow start, not a scene the pose model cannot describe)
        tries = [(float(focal_px), False, False)] if focal_px else []
        tries += [(None, True, False), (None, True, True)] if camera is None else []
        f_self, given_fail = None, ""
        for f0, self_cal, from_fixed in tries:
            if from_fixed and not (0 < rms_all <= give_up_px):
                break
            f0 = f0 or f_self or initial_focal(H0, size_wh, principal, pair_H, params)
            f_self = f0 if self_cal else None
            H, cam, err, ok, odo = fit_pose_model(H0, corr, size_wh, f0, principal, self_calibrate=self_cal, params=params,
                                                  give_up_px=give_up_px, from_fixed_focal=from_fixed,
                                                  distortion=distortion, odometry=odometry, pair_sigma_px=pairs_rms)
            rms = _rms(err, params.outlier_px)
            rms_all = float(np.sqrt(np.mean(err**2))) if len(err) else 0.0  # judged on all: a fit may leave whole pairs off
            if not ok:
                fail = "the pose model did not converge"
            elif not f_lo <= cam.f <= f_hi:
                fail = (f"self-calibration found an implausible focal length ({cam.f:.0f} px)" if self_cal
                        else f"outside {f_lo:.0f}-{f_hi:.0f} px, the plausible range for {w}x{h} frames")
            elif rms_all > limit:
                fail = f"the pose model fits {rms_all:.2f} px RMS, its pairs {pairs_rms:.2f} px"
            else:
                # a given focal length fails where a self-calibrated one fits: it contradicts the images
                note = given_fail and f"the focal length {focal_px:g} px contradicts the images ({given_fail}); self-calibration finds {cam.f:.0f} px"
                return AlignResult(to_mosaic_frame(H, size_wh, H0), rms, per_pair_rms(err, corr), nfev, "pose", cam, note, odo)
            if from_fixed:
                why = f"{why} (from the fixed-focal fit: {fail.removeprefix('the pose model ')})"
            elif not self_cal:
                given_fail = fail
                why = (f"with the focal length {focal_px:g} px {fail}" if camera is None else
                       f"with the focal length {focal_px:.5g} px settled by the sweep's first alignment {fail}")
            else:
                why = f"{why}; self-calibrated: {fail}" if why else fail
    # all correspondences: 12 a pair let 8 unknowns a frame overfit them (Haltbrekken ROV: a 5-frame chain 9-21 px off)
    H_free, n = adjust_homographies(H0, corr, params=params)
    err = pair_errors(H_free, corr)
    return AlignResult(to_mosaic_frame(H_free, size_wh, H0), _rms(err, params.outlier_px), per_pair_rms(err, corr),
                       nfev + n, "homography", None, why)
