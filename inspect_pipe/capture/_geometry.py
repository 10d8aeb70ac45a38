"""Camera geometry, pure math on arrays: pinhole intrinsics, lens distortion, camera poses and the
exact homography between the front wall plane and a frame.

Frames: world (x towards the front wall, y left, z up), body (X forward, Y left, Z up), camera
(OpenCV: x right, y down, z along the optical axis). The front wall is the plane ``x = length_m``;
wall coordinates ``u = width_m/2 - y`` (m, to the right), ``v = z`` (m, up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "CameraModel",
    "Pose",
    "SIM_CALIBRATION",
    "R_BODY_CAM_FORWARD",
    "rotation_from_rpy",
    "rpy_from_rotation",
    "slerp",
    "wall_to_frame_homography",
    "texture_px_to_wall",
    "distort_points",
    "undistort_points",
]

# A forward-looking camera: optical axis = body X, image right = -body Y, image down = -body Z.
R_BODY_CAM_FORWARD = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


# What a simulated camera's ``calibration`` says: its model is exact, not estimated.
SIM_CALIBRATION = {"source": "simulator", "sha256": None, "rms_px": 0.0, "note": "the simulated camera's exact model"}


@dataclass(frozen=True)
class CameraModel:
    """Pinhole camera with OpenCV distortion ``dist`` = (k1, k2, p1, p2, k3).

    ``calibration`` says where K and dist come from: ``{"source": path, "sha256", "rms_px"}`` for a
    camera file (``capture._calibration.load_camera``), ``{"source": "simulator", ...}`` for the
    simulated camera, None for a guess (:meth:`from_hfov`)."""

    K: np.ndarray  # 3x3, pixels
    dist: np.ndarray  # (5,)
    width: int
    height: int
    name: str = "camera"
    calibration: dict | None = None

    @staticmethod
    def from_hfov(width: int, height: int, hfov_deg: float, dist=(0.0, 0.0, 0.0, 0.0, 0.0), name: str = "camera") -> "CameraModel":
        f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        K = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
        return CameraModel(K, np.asarray(dist, dtype=float), int(width), int(height), name)

    @property
    def hfov_deg(self) -> float:
        return math.degrees(2 * math.atan2(self.width / 2.0, float(self.K[0, 0])))

    def to_json(self) -> dict:
        return {
            "model": "pinhole_opencv",
            "name": self.name,
            "width": self.width,
            "height": self.height,
            "K": np.asarray(self.K, float).round(6).tolist(),
            "dist": np.asarray(self.dist, float).round(8).tolist(),
            "calibration": self.calibration,
            **({} if self.calibration else {"note": self.uncalibrated_note}),
        }

    @property
    def uncalibrated_note(self) -> str:
        return f"uncalibrated: {self.hfov_deg:.0f}\u00b0 guess"


@dataclass(frozen=True)
class Pose:
    """Rigid transform ``p_parent = R @ p_child + t`` (R 3x3, t metres)."""

    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def to_json(self) -> dict:
        return {"R": np.asarray(self.R, float).round(9).tolist(), "t_m": np.asarray(self.t, float).round(6).tolist()}

    def compose(self, child: "Pose") -> "Pose":
        return Pose(self.R @ child.R, self.R @ child.t + self.t)


def rotation_from_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """World-from-body rotation for ZYX Euler angles (rad)."""
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def rpy_from_rotation(R: np.ndarray) -> tuple[float, float, float]:
    pitch = -math.asin(max(-1.0, min(1.0, float(R[2, 0]))))
    return math.atan2(float(R[2, 1]), float(R[2, 2])), pitch, math.atan2(float(R[1, 0]), float(R[0, 0]))


def _quat(R: np.ndarray) -> np.ndarray:
    w = math.sqrt(max(0.0, 1.0 + R[0, 0] + R[1, 1] + R[2, 2])) / 2.0
    x = math.copysign(math.sqrt(max(0.0, 1.0 + R[0, 0] - R[1, 1] - R[2, 2])) / 2.0, R[2, 1] - R[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1.0 - R[0, 0] + R[1, 1] - R[2, 2])) / 2.0, R[0, 2] - R[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1.0 - R[0, 0] - R[1, 1] + R[2, 2])) / 2.0, R[1, 0] - R[0, 1])
    q = np.array([w, x, y, z])
    return q / np.linalg.norm(q)


def _rot(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def slerp(R0: np.ndarray, R1: np.ndarray, a: float) -> np.ndarray:
    """Rotation a fraction ``a`` of the way from R0 to R1 (shortest arc)."""
    q0, q1 = _quat(R0), _quat(R1)
    d = float(q0 @ q1)
    if d < 0:
        q1, d = -q1, -d
    if d > 0.9995:
        q = q0 + a * (q1 - q0)
    else:
        th = math.acos(d)
        q = (math.sin((1 - a) * th) * q0 + math.sin(a * th) * q1) / math.sin(th)
    return _rot(q / np.linalg.norm(q))


def wall_to_frame_homography(
    K: np.ndarray, R_world_cam: np.ndarray, c_world: np.ndarray, length_m: float, width_m: float
) -> np.ndarray:
    """3x3 H mapping wall metres (u, v, 1) to undistorted frame pixels (x, y, 1) for a camera at
    ``c_world`` with orientation ``R_world_cam`` (camera-to-world rotation). Exact: a plane seen
    through a pinhole is a homography."""
    A = np.array([[0.0, 0.0, length_m], [-1.0, 0.0, width_m / 2.0], [0.0, 1.0, 0.0]])  # (u,v,1) -> world
    M = A.copy()
    M[:, 2] -= np.asarray(c_world, float)
    H = K @ R_world_cam.T @ M
    return H / H[2, 2] if abs(H[2, 2]) > 1e-12 else H


def texture_px_to_wall(m_per_px: float, origin_uv: tuple[float, float]) -> np.ndarray:
    """3x3 map from texture pixel (col, row) -- pixel centres at integers, as OpenCV -- to wall (u, v) m.
    ``origin_uv`` is the wall position of the image's top-left corner; rows run down the wall."""
    m = float(m_per_px)
    u0, v0 = origin_uv
    return np.array([[m, 0.0, u0 + 0.5 * m], [0.0, -m, v0 - 0.5 * m], [0.0, 0.0, 1.0]])


def distort_points(cam: CameraModel, xy_undist: np.ndarray) -> np.ndarray:
    """Undistorted pixel coordinates (N, 2) -> distorted (observed) pixels (N, 2)."""
    K, d = cam.K, np.zeros(5)
    d[: len(cam.dist)] = cam.dist[:5]
    k1, k2, p1, p2, k3 = d
    x = (xy_undist[:, 0] - K[0, 2]) / K[0, 0]
    y = (xy_undist[:, 1] - K[1, 2]) / K[1, 1]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 ** 3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd * K[0, 0] + K[0, 2], yd * K[1, 1] + K[1, 2]], axis=1)


def undistort_points(cam: CameraModel, xy_dist: np.ndarray, iterations: int = 20) -> np.ndarray:
    """Distorted pixels (N, 2) -> undistorted pixels (N, 2) by fixed-point iteration (the inverse
    of :func:`distort_points`, to well below 0.01 px for moderate distortion)."""
    xy_dist = np.asarray(xy_dist, float)
    und = xy_dist.copy()
    for _ in range(iterations):
        und = und + (xy_dist - distort_points(cam, und))
    return und
