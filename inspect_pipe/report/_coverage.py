"""Coverage: which part of the wall was imaged at usable resolution and sharpness, and the gaps.

A wall raster of ``cell_m`` cells; every placed frame paints its footprint (frame corners through
H and ``wall_from_mosaic``). A frame is usable when its resolution on the wall is at most
``max_m_per_px`` and its sharpness (variance of the Laplacian on a 1/4-size grey image) is at
least ``min_sharpness_ratio`` times the sweep's median (blur is relative to the wall's own
texture, which no absolute threshold knows).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ._geo import WallMap, frame_footprint_px
from ._register import FrameView


@dataclass(frozen=True)
class CoverageParams:
    cell_m: float = 0.01
    max_m_per_px: float = 0.003  # a 1 cm defect spans >= 3 px
    min_sharpness_ratio: float = 0.35
    min_gap_m2: float = 0.01  # gaps smaller than 10 x 10 cm are not listed


@dataclass(frozen=True)
class WallGrid:
    """Raster over the wall: cell (row, col) covers u0 + col*cell .. , v_top - row*cell downwards."""

    u0_m: float
    v_top_m: float
    cell_m: float
    shape: tuple[int, int]  # rows, cols

    @classmethod
    def around(cls, u0: float, v0: float, u1: float, v1: float, cell_m: float) -> "WallGrid":
        cols = max(1, int(np.ceil((u1 - u0) / cell_m)))
        rows = max(1, int(np.ceil((v1 - v0) / cell_m)))
        return cls(u0, v1, cell_m, (rows, cols))

    @property
    def extent(self) -> tuple[float, float, float, float]:
        r, c = self.shape
        return self.u0_m, self.v_top_m - r * self.cell_m, self.u0_m + c * self.cell_m, self.v_top_m

    def grid_from_wall(self) -> np.ndarray:
        """3x3: wall (u, v) m -> grid (col, row) px (pixel centres at integers)."""
        s = 1.0 / self.cell_m
        return np.array([[s, 0, -self.u0_m * s - 0.5], [0, -s, self.v_top_m * s - 0.5], [0, 0, 1.0]])

    def from_mosaic(self, mosaic_img: np.ndarray, wall: WallMap, *, nearest: bool = True) -> np.ndarray:
        """Resample a mosaic-sized raster onto this grid."""
        M = self.grid_from_wall() @ wall.wall_from_mosaic
        flags = cv2.INTER_NEAREST if nearest else cv2.INTER_AREA
        return cv2.warpPerspective(mosaic_img, M, (self.shape[1], self.shape[0]), flags=flags)


@dataclass(frozen=True)
class FrameQuality:
    index: int
    m_per_px: float
    sharpness: float | None
    usable: bool
    reason: str = ""

    def to_json(self) -> dict:
        return {"index": self.index, "m_per_px": round(self.m_per_px, 6),
                "sharpness": None if self.sharpness is None else round(self.sharpness, 2),
                "usable": self.usable, "reason": self.reason}


@dataclass(frozen=True)
class Coverage:
    grid: WallGrid
    imaged: np.ndarray  # bool (rows, cols): any placed frame
    usable: np.ndarray  # bool: a usable frame
    frames: tuple[FrameQuality, ...]
    gaps: tuple[dict, ...]  # {"bbox_wall_m": [u0, v0, u1, v1], "area_m2": ...}

    @property
    def usable_fraction(self) -> float:
        return float(self.usable.mean())

    def to_json(self) -> dict:
        u0, v0, u1, v1 = self.grid.extent
        cell2 = self.grid.cell_m**2
        return {
            "region_wall_m": [round(u0, 4), round(v0, 4), round(u1, 4), round(v1, 4)],
            "cell_m": self.grid.cell_m,
            "region_m2": round(self.imaged.size * cell2, 4),
            "imaged_m2": round(float(self.imaged.sum()) * cell2, 4),
            "usable_m2": round(float(self.usable.sum()) * cell2, 4),
            "usable_fraction": round(self.usable_fraction, 4),
            "frames_usable": sum(f.usable for f in self.frames), "frames_total": len(self.frames),
            "gaps": list(self.gaps),
            "frames": [f.to_json() for f in self.frames],
        }


def sharpness(gray: np.ndarray) -> float:
    small = cv2.resize(gray, (max(1, gray.shape[1] // 4), max(1, gray.shape[0] // 4)), interpolation=cv2.INTER_AREA)
    return float(cv2.Laplacian(small, cv2.CV_32F).var())


def frame_resolution_m_per_px(view: FrameView, wall: WallMap) -> float:
    """Wall metres per frame pixel at the frame's centre."""
    w, h = view.size_wh
    c = np.array([[w / 2 - 0.5, h / 2], [w / 2 + 0.5, h / 2], [w / 2, h / 2 - 0.5], [w / 2, h / 2 + 0.5], ], float)
    q = np.c_[c, np.ones(4)] @ view.H.T
    pts = wall.to_wall(q[:, :2] / q[:, 2:3])
    J = np.c_[pts[1] - pts[0], pts[3] - pts[2]]
    return float(np.sqrt(abs(np.linalg.det(J))))


def compute_coverage(
    views: list[FrameView],
    wall: WallMap,
    grid: WallGrid,
    sharpness_of: dict[int, float] | None = None,
    *,
    params: CoverageParams = CoverageParams(),
) -> Coverage:
    imaged = np.zeros(grid.shape, np.uint8)
    usable = np.zeros(grid.shape, np.uint8)
    sharp = sharpness_of or {}
    med = float(np.median(list(sharp.values()))) if sharp else None
    G = grid.grid_from_wall()
    quality = []
    for v in views:
        res = frame_resolution_m_per_px(v, wall)
        s = sharp.get(v.index)
        reasons = []
        if res > params.max_m_per_px:
            reasons.append(f"{res * 1000:.1f} mm/px > {params.max_m_per_px * 1000:.1f}")
        if s is not None and med and s < params.min_sharpness_ratio * med:
            reasons.append(f"blurred (sharpness {s:.0f} < {params.min_sharpness_ratio:g} x median {med:.0f})")
        ok = not reasons
        quality.append(FrameQuality(v.index, res, s, ok, "; ".join(reasons)))
        poly_m = wall.to_wall(frame_footprint_px(v.H, v.size_wh))
        q = np.c_[poly_m, np.ones(4)] @ G.T
        pts = np.round(q[:, :2] / q[:, 2:3] * 4).astype(np.int32)  # 2 fractional bits
        cv2.fillConvexPoly(imaged, pts, 1, shift=2)
        if ok:
            cv2.fillConvexPoly(usable, pts, 1, shift=2)
    gaps = []
    n, labels, stats, _ = cv2.connectedComponentsWithStats((usable == 0).astype(np.uint8), connectivity=4)
    cell2 = grid.cell_m**2
    for k in range(1, n):
        x, y, w, h, a = stats[k]
        if a * cell2 < params.min_gap_m2:
            continue
        u0 = grid.u0_m + x * grid.cell_m
        v1 = grid.v_top_m - y * grid.cell_m
        gaps.append({"bbox_wall_m": [round(u0, 3), round(v1 - h * grid.cell_m, 3), round(u0 + w * grid.cell_m, 3), round(v1, 3)],
                     "area_m2": round(a * cell2, 4)})
    gaps.sort(key=lambda g: -g["area_m2"])
    return Coverage(grid, imaged > 0, usable > 0, tuple(quality), tuple(gaps))
