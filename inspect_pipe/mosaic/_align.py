"""Global alignment: every frame-to-mosaic homography refined jointly over all matched pairs.

Unknowns: one homography per frame (8 parameters, h33 = 1), in normalised coordinates (frame
pixels centred and divided by half the frame's larger side; mosaic pixels divided by the same).
Residuals: for each inlier correspondence (p in frame i, q in frame j), ``H_i p - H_j q`` in the
mosaic. Pairwise constraints leave the mosaic free up to one global homography; eight gauge rows
pin it so the mosaic neither drifts nor shrinks: the frames' mean perspective, shear and
anisotropy are zero, their mean rotation is zero, their mean scale is one (mosaic pixels are
frame pixels) and their mean translation stays where the initial layout put it. A weak prior on
each frame's perspective keeps a frame with a thin overlap from tilting freely.

The solver is Levenberg-Marquardt on the sparse normal equations (scipy.sparse); the Jacobian is
analytic and has 10 non-zeros per row.
"""

from __future__ import annotations

from dataclasses import dataclass
DEBUG = False

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


@dataclass(frozen=True)
class AlignParams:
    points_per_pair: int = 40
    iterations: int = 15
    perspective_prior: float = 0.1  # normalised perspective that costs as much as 1 px of residual
    outlier_px: float = 3.0  # correspondences further apart than this after a first solve are dropped


@dataclass(frozen=True)
class Correspondences:
    """Stacked inlier correspondences: rows (frame_i, frame_j, x_i, y_i, x_j, y_j) in pixels."""

    fi: np.ndarray
    fj: np.ndarray
    p: np.ndarray  # (N, 2)
    q: np.ndarray  # (N, 2)


@dataclass(frozen=True)
class AlignResult:
    H: dict[int, np.ndarray]  # frame -> 3x3, frame pixels -> mosaic pixels (before the canvas offset)
    rms_px: float
    per_pair_rms_px: dict[tuple[int, int], float]
    iterations: int


def _normaliser(size_wh: tuple[int, int]) -> tuple[np.ndarray, float]:
    w, h = size_wh
    s = max(w, h) / 2.0
    T = np.array([[1 / s, 0, -w / 2 / s], [0, 1 / s, -h / 2 / s], [0, 0, 1]])
    return T, s


def _project(params: np.ndarray, idx: np.ndarray, pts: np.ndarray):
    a, b, c, d, e, f, g, h = (params[idx, k] for k in range(8))
    x, y = pts[:, 0], pts[:, 1]
    w = g * x + h * y + 1.0
    u = (a * x + b * y + c) / w
    v = (d * x + e * y + f) / w
    return u, v, w


def _woodbury_solve(A: sp.csc_matrix, U: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve (A + U U^T) x = b with a sparse factorisation of A and a small dense correction."""
    lu = spla.splu(A, permc_spec="MMD_AT_PLUS_A")
    Ainv_b = lu.solve(b)
    Ainv_U = lu.solve(U)
    small = np.eye(U.shape[1]) + U.T @ Ainv_U
    return Ainv_b - Ainv_U @ np.linalg.solve(small, U.T @ Ainv_b)


def refine(
    H0: dict[int, np.ndarray],
    corr: Correspondences,
    size_wh: tuple[int, int],
    *,
    params: AlignParams = AlignParams(),
) -> AlignResult:
    """Jointly refine the homographies ``H0`` (frame px -> mosaic px) of one connected group."""
    frames = sorted(H0)
    col = {f: k for k, f in enumerate(frames)}
    n = len(frames)
    T, s = _normaliser(size_wh)
    Tinv = np.linalg.inv(T)
    M = np.diag([1 / s, 1 / s, 1.0])
    Minv = np.diag([s, s, 1.0])
    x = np.empty((n, 8))
    for f, k in col.items():
        Hn = M @ H0[f] @ Tinv
        Hn = Hn / Hn[2, 2]
        x[k] = Hn.ravel()[:8]
    keep = np.isin(corr.fi, frames) & np.isin(corr.fj, frames)
    ii = np.array([col[f] for f in corr.fi[keep]], dtype=np.int64)
    jj = np.array([col[f] for f in corr.fj[keep]], dtype=np.int64)
    P = (corr.p[keep] - [size_wh[0] / 2, size_wh[1] / 2]) / s
    Q = (corr.q[keep] - [size_wh[0] / 2, size_wh[1] / 2]) / s
    t0 = x[:, [2, 5]].mean(axis=0)
    n_pts = len(ii)
    gauge_w = 10.0 * np.sqrt(max(n_pts, 1))
    prior_w = (1.0 / s) / params.perspective_prior

    def residuals(xv: np.ndarray, rows_ok: np.ndarray) -> np.ndarray:
        ui, vi, _ = _project(xv, ii[rows_ok], P[rows_ok])
        uj, vj, _ = _project(xv, jj[rows_ok], Q[rows_ok])
        g = _gauge(xv)
        return np.concatenate([ui - uj, vi - vj, gauge_w * g, prior_w * xv[:, 6], prior_w * xv[:, 7]])


    def _gauge(xv):
        a, b, c, d, e, f, g, h = xv.T
        return np.array([
            g.mean(), h.mean(), (a - e).mean(), (b + d).mean(), (d - b).mean() / 2,
            (a + e).mean() / 2 - 1.0, c.mean() - t0[0], f.mean() - t0[1],
        ])

    gauge_J = np.zeros((8, n * 8))
    for r, coeffs in enumerate([
        {6: 1}, {7: 1}, {0: 1, 4: -1}, {1: 1, 3: 1}, {3: 0.5, 1: -0.5}, {0: 0.5, 4: 0.5}, {2: 1}, {5: 1},
    ]):
        for k, v in coeffs.items():
            gauge_J[r, np.arange(n) * 8 + k] = v / n
    gauge_J = sp.csr_matrix(gauge_w * gauge_J)
    prior_J = sp.vstack([
        sp.csr_matrix((np.full(n, prior_w), (np.arange(n), np.arange(n) * 8 + 6)), shape=(n, 8 * n)),
        sp.csr_matrix((np.full(n, prior_w), (np.arange(n), np.arange(n) * 8 + 7)), shape=(n, 8 * n)),
    ])

    def jacobian(xv: np.ndarray, rows_ok: np.ndarray) -> sp.csr_matrix:
        blocks = []
        m = int(rows_ok.sum())
        rows = np.arange(m)
        for frame_idx, pts, sign in ((ii[rows_ok], P[rows_ok], 1.0), (jj[rows_ok], Q[rows_ok], -1.0)):
            u, v, w = _project(xv, frame_idx, pts)
            X, Y = pts[:, 0] / w, pts[:, 1] / w
            one = 1.0 / w
            base = frame_idx * 8
            # x-residual: a, b, c, g, h ; y-residual: d, e, f, g, h
            rx = np.repeat(rows, 5)
            cx = (base[:, None] + np.array([0, 1, 2, 6, 7])).ravel()
            vx = np.stack([X, Y, one, -u * X, -u * Y], axis=1).ravel()
            ry = np.repeat(rows + m, 5)
            cy = (base[:, None] + np.array([3, 4, 5, 6, 7])).ravel()
            vy = np.stack([X, Y, one, -v * X, -v * Y], axis=1).ravel()
            blocks.append(sp.csr_matrix(
                (sign * np.concatenate([vx, vy]), (np.concatenate([rx, ry]), np.concatenate([cx, cy]))),
                shape=(2 * m, 8 * n),
            ))
        return sp.vstack([blocks[0] + blocks[1], prior_J]).tocsr()

    rows_ok = np.ones(n_pts, dtype=bool)
    it_total = 0
    for stage in range(2):
        lam = 1e-3
        r = residuals(x, rows_ok)
        cost = float(r @ r)
        m2 = 2 * int(rows_ok.sum())
        U = gauge_J.toarray().T  # (8n, 8): the gauge rows are dense, so they enter by Woodbury
        for _ in range(params.iterations):
            it_total += 1
            J = jacobian(x, rows_ok)
            JtJ = (J.T @ J).tocsc()
            r_sparse = np.concatenate([r[:m2], r[m2 + 8:]])
            g = J.T @ r_sparse + U @ r[m2 : m2 + 8]
            diag = JtJ.diagonal() + (U * U).sum(axis=1)
            improved = False
            for _try in range(8):
                A = (JtJ + sp.diags(lam * np.maximum(diag, 1e-12))).tocsc()
                step = _woodbury_solve(A, U, -g)
                xn = x + step.reshape(n, 8)
                rn = residuals(xn, rows_ok)
                cn = float(rn @ rn)
                if cn < cost:
                    print("it", _, "cost", cost, "->", cn, "lam", lam) if DEBUG else None
                    x, r, improved = xn, rn, True
                    lam = max(lam / 10, 1e-9)
                    rel = (cost - cn) / max(cost, 1e-30)
                    cost = cn
                    break
                lam *= 10
            if not improved or rel < 1e-10:
                break
        if stage == 0:
            ui, vi, _ = _project(x, ii, P)
            uj, vj, _ = _project(x, jj, Q)
            err = np.hypot(ui - uj, vi - vj) * s
            new_ok = err <= params.outlier_px
            if new_ok.all():
                break
            rows_ok = new_ok

    H = {}
    for f, k in col.items():
        Hn = np.append(x[k], 1.0).reshape(3, 3)
        Hf = Minv @ Hn @ T
        H[f] = Hf / Hf[2, 2]
    ui, vi, _ = _project(x, ii, P)
    uj, vj, _ = _project(x, jj, Q)
    err = np.hypot(ui - uj, vi - vj) * s
    per_pair: dict[tuple[int, int], float] = {}
    fi_all, fj_all = corr.fi[keep], corr.fj[keep]
    keys = fi_all * 1_000_003 + fj_all
    for key in np.unique(keys):
        sel = keys == key
        per_pair[(int(fi_all[sel][0]), int(fj_all[sel][0]))] = float(np.sqrt(np.mean(err[sel] ** 2)))
    used = err[rows_ok]
    rms = float(np.sqrt(np.mean(used**2))) if len(used) else 0.0
    return AlignResult(H, rms, per_pair, it_total)
