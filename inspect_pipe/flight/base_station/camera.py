"""The live camera image of the embedded simulator: a pinhole view of the front wall.

The wall's texture is the scenario's ``front_wall_texture`` when it has one, otherwise a plain
painted plate with weld seams every metre, so the surveyor sees motion. The camera looks along the
vehicle's heading; roll and pitch are ignored (the real camera sits on a levelled mount).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from inspect_pipe._images import imread
from inspect_pipe.flight.scenario import Scenario

__all__ = ["WallCamera"]


def _plain_wall(width_m: float, height_m: float, m_per_px: float) -> np.ndarray:
    w, h = int(width_m / m_per_px), int(height_m / m_per_px)
    rng = np.random.default_rng(0)
    img = np.full((h, w, 3), (120, 128, 134), np.uint8)
    img = cv2.add(img, rng.integers(0, 18, (h, w, 3), dtype=np.uint8))
    step = int(1.0 / m_per_px)
    for k in range(0, w, step):
        cv2.line(img, (k, 0), (k, h), (70, 74, 78), 2)
    for k in range(0, h, step):
        cv2.line(img, (0, k), (w, k), (70, 74, 78), 2)
    for _ in range(int(width_m * height_m / 6)):  # a few rust patches
        c = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        cv2.circle(img, c, int(rng.integers(3, 12)), (40, 70, 140), -1)
    return img


class WallCamera:
    def __init__(self, scenario: Scenario, *, width: int = 320, height: int = 204) -> None:
        hold = scenario.world.hold
        self.length, self.width_m = hold.length_m, hold.width_m
        self.size = (width, height)
        hfov = math.radians(scenario.camera.hfov_deg)
        f = width / 2 / math.tan(hfov / 2)
        self.K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]])
        tex = scenario.world.front_wall_texture
        img = imread(str(tex.image), cv2.IMREAD_COLOR) if tex is not None else None
        if img is not None and tex is not None:
            self.texture, self.m_per_px, self.origin_uv = img, tex.m_per_px, tex.origin_uv
        else:
            self.m_per_px = 0.02
            self.texture = _plain_wall(hold.width_m, hold.height_m, self.m_per_px)
            self.origin_uv = (0.0, hold.height_m)

    def render(self, position: tuple[float, float, float], yaw: float) -> np.ndarray | None:
        """BGR image, or None when the camera does not face the front wall."""
        if math.cos(yaw) < 0.3:
            return None
        x, y, z = position
        c, s = math.cos(yaw), math.sin(yaw)
        # World -> camera (x right, y down, z forward): forward = (c, s, 0), right = (s, -c, 0).
        R = np.array([[s, -c, 0.0], [0.0, 0.0, -1.0], [c, s, 0.0]])
        t = -R @ np.array([x, y, z])
        # Texture pixel (col, row) -> world point on the wall x = L: y = W/2 - u, z = v.
        u0, v0, m = self.origin_uv[0], self.origin_uv[1], self.m_per_px
        A = np.array([[0.0, 0.0, self.length], [-m, 0.0, self.width_m / 2 - u0], [0.0, -m, v0]])
        H = self.K @ (R @ A + np.column_stack([np.zeros(3), np.zeros(3), t]))
        return cv2.warpPerspective(self.texture, H, self.size, flags=cv2.INTER_LINEAR, borderValue=(30, 30, 30))
