"""Synthetic sweeps with exact ground truth: a texture seen by a camera moving in a lawnmower.

Used by the tests and the benchmarks (scaling runs). ``H[i]`` maps frame-``i`` pixels to texture
(wall) pixels; the frames are the texture resampled through it, so every correspondence is known.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class SweepPath:
    passes: int = 3
    per_pass: int = 8
    step_px: float = 40.0
    row_px: float = 120.0
    frame_wh: tuple[int, int] = (256, 192)
    margin_px: float = 40.0
    yaw_sigma_deg: float = 2.0
    scale_sigma: float = 0.03
    tilt_sigma_deg: float = 1.5
    focal_px: float = 300.0


def lawnmower_homographies(path: SweepPath, rng: np.random.Generator) -> list[np.ndarray]:
    """Frame px -> wall px for a boustrophedon path (passes left-right, right-left, ...)."""
    w, h = path.frame_wh
    K = np.array([[path.focal_px, 0, w / 2], [0, path.focal_px, h / 2], [0, 0, 1]])
    Kinv = np.linalg.inv(K)
    out = []
    for p in range(path.passes):
        for k in range(path.per_pass):
            col = k if p % 2 == 0 else path.per_pass - 1 - k
            cx = path.margin_px + w / 2 + col * path.step_px + rng.normal(0, 2)
            cy = path.margin_px + h / 2 + p * path.row_px + rng.normal(0, 2)
            yaw = np.deg2rad(rng.normal(0, path.yaw_sigma_deg))
            s = 1.0 + rng.normal(0, path.scale_sigma)
            tx, ty = np.deg2rad(rng.normal(0, path.tilt_sigma_deg, 2))
            Rx = np.array([[1, 0, 0], [0, np.cos(tx), -np.sin(tx)], [0, np.sin(tx), np.cos(tx)]])
            Ry = np.array([[np.cos(ty), 0, np.sin(ty)], [0, 1, 0], [-np.sin(ty), 0, np.cos(ty)]])
            tilt = K @ Rx @ Ry @ Kinv
            c, si = np.cos(yaw), np.sin(yaw)
            A = np.array([[s * c, -s * si, cx], [s * si, s * c, cy], [0, 0, 1]])
            Hc = np.array([[1, 0, -w / 2], [0, 1, -h / 2], [0, 0, 1]])
            H = A @ Hc @ tilt
            out.append(H / H[2, 2])
    return out


def textured_wall(width: int, height: int, rng: np.random.Generator) -> np.ndarray:
    """A BGR texture rich in corners at every scale (coloured noise octaves, blobs and scratches)."""
    img = np.zeros((height, width), np.float32)
    for octave, amp in ((4, 60), (16, 40), (64, 30)):
        small = rng.normal(0, 1, (height // octave + 2, width // octave + 2)).astype(np.float32)
        img += amp * cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC)
    img = cv2.normalize(img, None, 30, 220, cv2.NORM_MINMAX)
    bgr = cv2.merge([img * 0.7, img * 0.85, img]).astype(np.uint8)
    for _ in range(width * height // 4000):
        x, y = int(rng.integers(width)), int(rng.integers(height))
        colour = tuple(int(v) for v in rng.integers(20, 235, 3))
        if rng.random() < 0.5:
            cv2.circle(bgr, (x, y), int(rng.integers(2, 9)), colour, -1, cv2.LINE_AA)
        else:
            cv2.line(bgr, (x, y), (x + int(rng.integers(-25, 25)), y + int(rng.integers(-25, 25))), colour, 1, cv2.LINE_AA)
    return bgr


def render_frame(wall: np.ndarray, H: np.ndarray, frame_wh: tuple[int, int]) -> np.ndarray:
    """What the camera sees: ``frame(x) = wall(H x)``."""
    return cv2.warpPerspective(wall, H, frame_wh, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REFLECT)
