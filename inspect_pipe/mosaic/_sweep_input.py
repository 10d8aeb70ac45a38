"""Sweeps (``inspect_pipe.capture`` format) as mosaic input, and the mosaic-to-wall geometry.

A sweep adds what a folder of images lacks: the camera's intrinsics (frames are undistorted
before registration, and the mosaic is rectified to the wall plane) and the vehicle's state at
each exposure. From those:

- ``m_per_px``: metres of wall per mosaic pixel, from the focal length and the estimated distance
  of the camera to the wall (front sonar, less the camera's forward offset on the body);
- ``wall_from_mosaic``: the 3x3 map from mosaic pixels to wall metres (u right from the wall's left
  edge, v up from the floor) of the surveyed wall (the survey plan's, or the simulated wall the
  vehicle faced; positions reach the hold frame through the plan's take-off tie). Its scale is ``m_per_px``; its rotation and offset are fitted
  robustly (Huber) between the frame centres in the mosaic and the wall points the vehicle's
  position estimates put in front of the camera. Odometry drifts and the mosaic does not, so the
  mosaic fixes the shape and odometry only places it. The odometry's linear drift (a velocity bias
  of the optical flow) is estimated jointly, since the lawnmower revisits the wall pass after pass;
  what remains is the position error at the start of the survey. The residual is reported.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ._io import read_image
from ._register import FrameError


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
            },
        }


def wall_geometry(sweep, H: dict[int, np.ndarray], focal_px: float, principal_px: tuple[float, float]) -> WallGeometry | None:
    """Mosaic -> wall map for the placed frames ``H`` (frame px -> mosaic px), or None when the
    sweep carries no position or wall distance estimates."""
    meta = sweep.meta
    cam_t = np.asarray(meta.cam_to_body.t, float)
    frame = meta.wall_frame()  # the surveyed wall (survey plan, or the simulated wall faced)
    a = frame.facing_heading_rad  # the vehicle faces the wall: the camera's offset turned with it
    cam_offset = np.array([cam_t[0] * np.cos(a) - cam_t[1] * np.sin(a), cam_t[0] * np.sin(a) + cam_t[1] * np.cos(a), cam_t[2]])
    mos, wall, dists, times = [], [], [], []
    c = np.array([principal_px[0], principal_px[1], 1.0])
    for i, h in H.items():
        f = sweep.frames[i]
        if f.dist_front_m is not None:
            dists.append(f.dist_front_m - cam_t[0])
        if f.position_m is None:
            continue
        p = h @ c
        mos.append(p[:2] / p[2])
        wall.append(frame.to_wall(meta.to_hold(f.position_m)[0] + cam_offset)[0])
        times.append(f.t_s)
    if not dists or len(mos) < 3:
        return None
    m_per_px = float(np.mean(dists) / focal_px)
    M, W = np.array(mos), np.array(wall)
    F = np.diag([1.0, -1.0])  # mosaic rows run down, wall v runs up

    def fit_to(Wt: np.ndarray, weights: np.ndarray, scale: float | None):
        wsum = weights.sum()
        mc = (weights[:, None] * M).sum(0) / wsum
        wc = (weights[:, None] * Wt).sum(0) / wsum
        A = ((weights[:, None] * (F @ (Wt - wc).T).T).T @ (M - mc))  # cross-covariance
        U, S, Vt = np.linalg.svd(A)
        D = np.diag([1.0, np.sign(np.linalg.det(U @ Vt))])
        R = U @ D @ Vt
        if scale is None:
            scale = float(np.trace(np.diag(S) @ D) / (weights * ((M - mc) ** 2).sum(1)).sum())
        L = scale * F @ R
        t = wc - L @ mc
        return L, t, scale

    # Odometry = truth + offset + drift * (t - t0): the mosaic knows the true relative layout, so
    # the drift rate is observable wherever the sweep revisits the wall (pass to pass). Alternate:
    # Procrustes (fixed scale) on drift-corrected positions, then the drift rate by least squares;
    # Huber weights at 5 cm throughout.
    dt = np.array(times) - min(times)
    drift = np.zeros(2)
    w = np.ones(len(M))
    span = float(np.ptp(dt))
    for _ in range(30):
        Wc = W - np.outer(dt, drift)
        L, t, _ = fit_to(Wc, w, m_per_px)
        r_vec = W - ((M @ L.T) + t)  # what odometry adds to the mosaic's placement
        if span > 1.0:
            A = np.c_[np.ones(len(dt)), dt] * np.sqrt(w)[:, None]
            coef, *_ = np.linalg.lstsq(A, r_vec * np.sqrt(w)[:, None], rcond=None)
            drift = coef[1]
        r = np.linalg.norm(W - np.outer(dt, drift) - ((M @ L.T) + t), axis=1)
        w = np.where(r <= 0.05, 1.0, 0.05 / np.maximum(r, 1e-12))
    _, _, free = fit_to(W - np.outer(dt, drift), np.ones(len(M)), None)
    r = np.linalg.norm(W - np.outer(dt, drift) - ((M @ L.T) + t), axis=1)
    T = np.eye(3)
    T[:2, :2], T[:2, 2] = L, t
    return WallGeometry(m_per_px, T, float(np.sqrt(np.mean(r**2))), float(r.max()), free, len(M), tuple(float(d) for d in drift),
                        frame.wall.value, meta.wall_frame_note())


def control_point_geometry(sweep, H: dict[int, np.ndarray], odometry: WallGeometry | None) -> WallGeometry | None:
    """The survey plan's control points (a pixel of a named frame and the wall point it shows)
    tie the mosaic to the wall: two or more fix rotation, scale and offset (a similarity, least
    squares); one only shifts the odometry's placement. None without usable points."""
    plan = sweep.meta.survey_plan
    if plan is None or not plan.control_points:
        return None
    by_name = {}
    for i, f in enumerate(sweep.frames):
        by_name.setdefault(f.image, i)
        by_name.setdefault(Path(f.image).name, i)
    K, dist = np.asarray(sweep.meta.K, float), np.asarray(sweep.meta.dist, float)
    mos, wall = [], []
    for cp in plan.control_points:
        i = by_name.get(cp.image, by_name.get(Path(cp.image).name))
        if i is None or i not in H:
            continue  # a frame that is not in the sweep or was not placed
        und = cv2.undistortPoints(np.array([[cp.pixel]], np.float64), K, dist, P=K).reshape(2)
        q = H[i] @ np.array([und[0], und[1], 1.0])
        mos.append(q[:2] / q[2])
        wall.append(cp.wall_m)
    if not mos:
        return None
    M, Wm = np.array(mos, float), np.array(wall, float)
    F = np.diag([1.0, -1.0])
    meta = sweep.meta
    if len(M) == 1:
        if odometry is None:
            return None  # one point fixes no scale
        T = odometry.wall_from_mosaic.copy()
        p = T @ np.array([M[0, 0], M[0, 1], 1.0])
        T[:2, 2] += Wm[0] - p[:2] / p[2]
        return WallGeometry(odometry.m_per_px, T, 0.0, 0.0, odometry.free_scale_m_per_px, 1, odometry.drift_m_per_s,
                            odometry.wall, odometry.wall_note, odometry.method + "; offset from 1 control point of the survey plan")
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
                        f"similarity fitted to {len(M)} control points of the survey plan (residual over the points)")


def is_sweep(path: Path) -> bool:
    return (Path(path) / "sweep.json").is_file()
