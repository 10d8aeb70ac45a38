"""Synthetic defect images with exact ground truth (seeded, no data files)."""

from __future__ import annotations

import cv2
import numpy as np

from inspect_pipe.saliency_defects import _onnx_detect as od
from inspect_pipe.saliency_defects import _onnx_train as ot


def _smooth_noise(rng: np.random.Generator, shape, sigma: float) -> np.ndarray:
    n = rng.standard_normal(shape).astype(np.float32)
    n = cv2.GaussianBlur(n, (0, 0), sigma)
    return n / (n.std() + 1e-6)


def painted_wall_with_rust(
    rng: np.random.Generator, h: int = 384, w: int = 512, n_blobs: int = 5
) -> tuple[np.ndarray, np.ndarray]:
    """Grey-green painted steel with orange-brown, rough rust blobs. Returns (BGR uint8, mask bool)."""
    base = np.array([118, 128, 112], np.float32)  # BGR paint
    shade = 1.0 + 0.08 * _smooth_noise(rng, (h, w), 60)[..., None]
    img = base * shade + rng.normal(0, 2.5, (h, w, 3)).astype(np.float32)
    mask = np.zeros((h, w), bool)
    blob_field = _smooth_noise(rng, (h, w), 6)
    for _ in range(n_blobs):
        cy, cx = rng.integers(40, h - 40), rng.integers(40, w - 40)
        r = rng.uniform(14, 38)
        yy, xx = np.ogrid[:h, :w]
        d = np.sqrt((yy - cy) ** 2 + (xx - cx) ** 2) / r
        mask |= (d + 0.35 * blob_field) < 1.0
    rust = np.array([38, 72, 150], np.float32) * (1.0 + 0.25 * _smooth_noise(rng, (h, w), 1.2))[..., None]
    rust += rng.normal(0, 8, (h, w, 3)).astype(np.float32)
    img[mask] = rust[mask]
    img = cv2.GaussianBlur(img, (0, 0), 0.7)
    return np.clip(img, 0, 255).astype(np.uint8), mask


def pavement_with_cracks(
    rng: np.random.Generator, h: int = 320, w: int = 480, n_cracks: int = 3
) -> tuple[np.ndarray, np.ndarray]:
    """Grainy grey surface with dark, thin, meandering cracks 2-3 px wide. Returns (BGR, mask)."""
    g = 125 + 10 * _smooth_noise(rng, (h, w), 1.0) + 8 * _smooth_noise(rng, (h, w), 25)
    mask8 = np.zeros((h, w), np.uint8)
    for _ in range(n_cracks):
        x, y = rng.uniform(0, w), rng.uniform(0, h)
        ang = rng.uniform(0, 2 * np.pi)
        pts = [(x, y)]
        for _ in range(60):
            ang += rng.normal(0, 0.25)
            x, y = x + 6 * np.cos(ang), y + 6 * np.sin(ang)
            if not (0 <= x < w and 0 <= y < h):
                break
            pts.append((x, y))
        if len(pts) < 8:
            continue
        poly = np.round(np.array(pts)).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(mask8, [poly], False, 255, thickness=int(rng.integers(2, 4)), lineType=cv2.LINE_8)
    mask = mask8 > 0
    g[mask] = 55 + 8 * rng.standard_normal(int(mask.sum()))
    g = cv2.GaussianBlur(g.astype(np.float32), (0, 0), 0.6)
    img = np.clip(g, 0, 255).astype(np.uint8)
    return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR), mask


def tiny_items(seed):
    """The onnx training's items (``_onnx_train._Item``): a few 64 x 64 synthetic images per
    class, a bright square (corrosion, surface) or line (crack)."""
    rng = np.random.default_rng(seed)
    out = {}
    for c in od.CLASSES:
        items = []
        for i in range(3):
            rgb = rng.integers(60, 120, (64, 64, 3), dtype=np.uint8)
            gt = np.zeros((64, 64), bool)
            if c == "crack":
                gt[10 + 10 * i, 5:60] = True
            else:
                gt[16:40, 10 + 5 * i:34 + 5 * i] = True
            rgb[gt] = (200, 90, 40)
            it = ot._Item(c, f"{c}{i}", rgb, gt)
            it.pos = np.argwhere(gt).astype(np.int32)
            items.append(it)
        out[c] = items
    return out
