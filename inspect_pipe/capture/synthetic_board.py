"""Synthetic calibration views with ground truth: a chessboard (or any board image) seen by a
known pinhole camera with OpenCV distortion, rendered by inverse mapping with supersampling, for
tests and benchmarks of :mod:`inspect_pipe.capture._calibration`.

    cam = CameraModel(K, dist, 640, 480)
    img, corners = render_view(cam, board_image, board_size_m, rvec, tvec)
"""

from __future__ import annotations

import cv2
import numpy as np

from inspect_pipe.capture._geometry import CameraModel, undistort_points

__all__ = ["chessboard_image", "random_poses", "render_view"]


def chessboard_image(cols: int, rows: int, square_px: int = 40, margin_squares: float = 1.0) -> tuple[np.ndarray, float]:
    """A printed chessboard with ``cols`` x ``rows`` inner corners: (grey uint8 image, margin in
    squares). The first inner corner lies ``margin_squares + 1`` squares from the image's corner."""
    nx, ny = cols + 1, rows + 1
    m = int(round(margin_squares * square_px))
    img = np.full((ny * square_px + 2 * m, nx * square_px + 2 * m), 255, np.uint8)
    for j in range(ny):
        for i in range(nx):
            if (i + j) % 2 == 0:
                img[m + j * square_px:m + (j + 1) * square_px, m + i * square_px:m + (i + 1) * square_px] = 0
    return img, margin_squares


_RAYS: dict = {}


def _rays(cam: CameraModel, s: int) -> np.ndarray:
    """Normalised undistorted coordinates (N, 2) of every supersampled pixel centre (cached)."""
    key = (cam.width, cam.height, s, np.asarray(cam.K, float).tobytes(), np.asarray(cam.dist, float).tobytes())
    if key not in _RAYS:
        off = (np.arange(s) + 0.5) / s - 0.5
        xs = (np.arange(cam.width)[:, None] + off[None, :]).ravel()
        ys = (np.arange(cam.height)[:, None] + off[None, :]).ravel()
        X, Y = np.meshgrid(xs, ys)
        und = undistort_points(cam, np.stack([X.ravel(), Y.ravel()], 1).astype(np.float64), iterations=40)
        _RAYS.clear()
        _RAYS[key] = (und - cam.K[:2, 2]) / np.diag(cam.K)[:2]
    return _RAYS[key]


def render_view(
    cam: CameraModel,
    board_img: np.ndarray,
    board_m_per_px: float,
    rvec: np.ndarray,
    tvec: np.ndarray,
    *,
    origin_px: tuple[float, float] = (0.0, 0.0),
    supersample: int = 3,
    blur_sigma_px: float = 0.6,
    noise_dn: float = 2.0,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """The board (grey image, ``board_m_per_px`` metres per pixel, board point (0, 0) m at image
    pixel ``origin_px``; board x along columns, y along rows, z = 0) seen by ``cam`` at pose
    (``rvec``, ``tvec``: board -> camera). Grey uint8, with lens blur and read noise."""
    s = int(supersample)
    w, h = cam.width, cam.height
    norm = _rays(cam, s)
    R, _ = cv2.Rodrigues(np.asarray(rvec, float))
    t = np.asarray(tvec, float).ravel()
    # ray (xn, yn, 1) * lam meets the board plane: R @ [bx, by, 0] + t = lam * [xn, yn, 1]
    H = np.column_stack([R[:, 0], R[:, 1], t])  # board (x, y, 1) -> camera ray
    Hi = np.linalg.inv(H)
    rays = np.column_stack([norm, np.ones(len(norm))])
    b = rays @ Hi.T
    ok = b[:, 2] > 1e-9  # in front of the camera
    bx = np.where(ok, b[:, 0] / np.where(ok, b[:, 2], 1), -1e6)
    by = np.where(ok, b[:, 1] / np.where(ok, b[:, 2], 1), -1e6)
    mapx = (bx / board_m_per_px + origin_px[0]).astype(np.float32).reshape(h * s, w * s)
    mapy = (by / board_m_per_px + origin_px[1]).astype(np.float32).reshape(h * s, w * s)
    big = cv2.remap(board_img, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=128)
    img = big.reshape(h, s, w, s).astype(np.float32).mean(axis=(1, 3))
    if blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma_px)
    if noise_dn > 0:
        rng = rng or np.random.default_rng(0)
        img = img + rng.normal(0.0, noise_dn, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def random_poses(n: int, board_size_m: tuple[float, float], cam: CameraModel, *, distance_m: float, tilt_deg: float = 35.0,
                 rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` board poses (rvec, tvec), board centre near the optical axis at about ``distance_m``,
    tilted up to ``tilt_deg`` about both board axes, and the whole board inside the image."""
    bw, bh = board_size_m
    corners = np.array([[0, 0, 0], [bw, 0, 0], [bw, bh, 0], [0, bh, 0]], float)
    out: list[tuple[np.ndarray, np.ndarray]] = []
    while len(out) < n:
        ax, ay = np.radians(rng.uniform(-tilt_deg, tilt_deg, 2))
        az = np.radians(rng.uniform(-20, 20))
        R = cv2.Rodrigues(np.array([ax, 0, 0]))[0] @ cv2.Rodrigues(np.array([0, ay, 0]))[0] @ cv2.Rodrigues(np.array([0, 0, az]))[0]
        d = distance_m * rng.uniform(0.85, 1.2)
        c = np.array([rng.uniform(-0.15, 0.15) * d, rng.uniform(-0.12, 0.12) * d, d])
        t = c - R @ np.array([bw / 2, bh / 2, 0.0])
        rvec = cv2.Rodrigues(R)[0].ravel()
        px, _ = cv2.projectPoints(corners, rvec, t, cam.K, cam.dist)
        px = px.reshape(-1, 2)
        if np.all(px[:, 0] > 8) and np.all(px[:, 0] < cam.width - 8) and np.all(px[:, 1] > 8) and np.all(px[:, 1] < cam.height - 8):
            out.append((rvec, t))
    return out
