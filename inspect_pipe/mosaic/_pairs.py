"""Which pairs to match. Grows linearly with the sweep: never all pairs.

- temporal neighbours: each frame with the next ``window`` frames;
- layout candidates: frames the current layout (or the vehicle's positions) puts over the same
  patch of wall, found with a k-d tree on footprint centres and ranked by predicted overlap, at
  most ``per_frame`` per frame.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial import cKDTree


def temporal_pairs(n: int, window: int = 3) -> list[tuple[int, int]]:
    return [(i, j) for i in range(n) for j in range(i + 1, min(n, i + window + 1))]


def footprint(H: np.ndarray, size_wh: tuple[int, int]) -> np.ndarray:
    """(4, 2) float32 corners of a frame in the mosaic."""
    w, h = size_wh
    c = np.array([[0, 0], [w, 0], [w, h], [0, h]], np.float32).reshape(-1, 1, 2)
    return cv2.perspectiveTransform(c, H.astype(np.float64)).reshape(4, 2).astype(np.float32)


def overlap_fraction(a: np.ndarray, b: np.ndarray) -> float:
    """Area of the intersection of two convex quadrilaterals over the smaller area."""
    area, _ = cv2.intersectConvexConvex(a, b)
    small = min(cv2.contourArea(a), cv2.contourArea(b))
    return float(area / small) if small > 0 else 0.0


def layout_pairs(
    H: dict[int, np.ndarray],
    size_wh: tuple[int, int],
    *,
    tried: set[tuple[int, int]],
    linked: set[tuple[int, int]] | None = None,
    min_overlap: float = 0.15,
    per_frame: int = 4,
) -> list[tuple[int, int, float]]:
    """Untried pairs (i < j, overlap) that the layout ``H`` (frame -> mosaic) predicts overlap.

    Pairs in ``linked`` (already joined by a short chain of registered pairs) add little and are
    skipped, so the budget goes to loop closures: the pass-to-pass overlaps.
    """
    linked = linked or set()
    frames = sorted(H)
    if len(frames) < 2:
        return []
    polys = {f: footprint(H[f], size_wh) for f in frames}
    centres = np.array([polys[f].mean(axis=0) for f in frames])
    radius = float(np.hypot(*size_wh))
    tree = cKDTree(centres)
    found: dict[int, list[tuple[float, int, int]]] = {}
    for a, b in tree.query_pairs(radius):
        i, j = sorted((frames[a], frames[b]))
        if (i, j) in tried or (i, j) in linked:
            continue
        ov = overlap_fraction(polys[i], polys[j])
        if ov >= min_overlap:
            found.setdefault(i, []).append((ov, i, j))
            found.setdefault(j, []).append((ov, i, j))
    chosen: set[tuple[int, int]] = set()
    out = []
    for f in frames:
        for ov, i, j in sorted(found.get(f, []), reverse=True)[:per_frame]:
            if (i, j) not in chosen:
                chosen.add((i, j))
                out.append((i, j, ov))
    return out


def short_links(edges: list[tuple[int, int]], hops: int = 4) -> set[tuple[int, int]]:
    """Pairs (i < j) joined by a chain of at most ``hops`` edges (bounded BFS from each frame)."""
    adj: dict[int, set[int]] = {}
    for i, j in edges:
        adj.setdefault(i, set()).add(j)
        adj.setdefault(j, set()).add(i)
    out: set[tuple[int, int]] = set()
    for start in adj:
        seen = {start}
        frontier = {start}
        for _ in range(hops):
            frontier = {n for f in frontier for n in adj[f]} - seen
            seen |= frontier
        out.update((start, o) for o in seen if o > start)
    return out
