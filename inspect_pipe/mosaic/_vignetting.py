"""Flat-field (vignetting) estimate from the sweep itself.

Over many frames at different places on the wall, the mean of each pixel position tends to the
same value; what remains is the lens and lighting fall-off. We fit ``V(r) = 1 + a r^2 + b r^4``
(r: radius normalised by the half-diagonal) to the mean of small thumbnails and divide it out
before blending. Too few frames, or a fall-off under 3 %, leaves the images as they are.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

THUMB_WH = (64, 48)


@dataclass(frozen=True)
class Vignetting:
    a: float
    b: float

    def gain(self, size_wh: tuple[int, int]) -> np.ndarray:
        """(H, W) float32 multiplicative correction, 1 at the centre."""
        w, h = size_wh
        y, x = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = ((x - (w - 1) / 2) ** 2 + (y - (h - 1) / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
        return (1.0 / (1.0 + self.a * r2 + self.b * r2 * r2)).astype(np.float32)

    def falloff_at_corner(self) -> float:
        return 1.0 - (1.0 + self.a + self.b)


class VignettingAccumulator:
    def __init__(self, min_frames: int = 15, min_falloff: float = 0.03) -> None:
        self._sum = np.zeros(THUMB_WH[::-1], np.float64)
        self._n = 0
        self.min_frames = min_frames
        self.min_falloff = min_falloff

    def add(self, gray: np.ndarray) -> None:
        self.add_thumbnail(cv2.resize(gray, THUMB_WH, interpolation=cv2.INTER_AREA))

    def add_thumbnail(self, thumb: np.ndarray) -> None:
        """``thumb``: the grey frame resized to ``THUMB_WH`` with INTER_AREA."""
        self._sum += thumb.astype(np.float64)
        self._n += 1

    def result(self) -> Vignetting | None:
        if self._n < self.min_frames:
            return None
        mean = self._sum / self._n
        w, h = THUMB_WH
        y, x = np.mgrid[0:h, 0:w]
        r2 = (((x + 0.5) / w - 0.5) ** 2 * w * w + ((y + 0.5) / h - 0.5) ** 2 * h * h) / ((w / 2) ** 2 + (h / 2) ** 2)
        A = np.stack([np.ones(r2.size), r2.ravel(), r2.ravel() ** 2], axis=1)
        coef, *_ = np.linalg.lstsq(A, mean.ravel(), rcond=None)
        if coef[0] <= 0:
            return None
        v = Vignetting(float(coef[1] / coef[0]), float(coef[2] / coef[0]))
        if v.falloff_at_corner() < self.min_falloff or v.falloff_at_corner() > 0.8:
            return None
        return v
