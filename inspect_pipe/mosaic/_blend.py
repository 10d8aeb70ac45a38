"""Seam-aware multi-band blending with exposure compensation (OpenCV ``cv2.detail``).

Two passes over the group's frames, a few frames in memory at a time at full resolution (prepared in threads ahead of the blender):
1. at seam scale (about ``seam_megapix`` per frame): warp, estimate per-frame exposure
   gains from the overlaps (least squares, pairs only), find seams by dynamic programming on colour;
2. at full scale: correct vignetting, warp, apply the gains, cut by the seam mask, feed the
   multi-band blender.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from ._pairs import footprint, layout_pairs, overlap_fraction
from ._vignetting import Vignetting


@dataclass(frozen=True)
class BlendParams:
    seam_megapix: float = 0.01  # seam finding (DP, O(overlapping pairs)) at this size a frame: 0.02 took 3.7 s CPU of 6.2 on synth_rust_sweep, 0.01 2.0 s
    blend_strength: float = 5.0  # blend width as % of sqrt(canvas area), as OpenCV's stitcher ...
    # ... but at most this share of the frame diagonal: on a 30 m wall 5 % of the canvas is 300 px, 8 bands, and
    # OpenCV's blender works on each frame's footprint grown by 3 x 2^bands px, 12x the frame (2.7x at 6 bands),
    # so the blend grew faster than the sweep; synth_rust_sweep (80-86 px, 6 bands) is unchanged
    max_blend_frame: float = 0.125
    workers: int = 2  # threads preparing frames (decode, flat field, warp) ahead of the blender
    exposure: str = "gain"  # gain | none
    seam: str = "dp"  # dp | voronoi | none
    max_canvas_megapix: float = 600.0
    tile_px: int = 4096  # full-scale blending in tiles of at most this side (plus the pyramid's margin)
    # frames blended whole: in frame order, a frame overlapping the last one kept by more than this share is left out,
    # but for the wall no kept frame sees (_blend_set); 1.0 blends every frame whole
    blend_overlap: float = 0.6


class CanvasTooLarge(ValueError):
    pass


def canvas_layout(H: dict[int, np.ndarray], size_wh: tuple[int, int]) -> tuple[dict[int, np.ndarray], tuple[int, int]]:
    """Shift homographies so the canvas starts at (0, 0); return them and the canvas size (W, H)."""
    pts = np.concatenate([footprint(h, size_wh) for h in H.values()])
    x0, y0 = np.floor(pts.min(axis=0))
    x1, y1 = np.ceil(pts.max(axis=0))
    T = np.array([[1, 0, -x0], [0, 1, -y0], [0, 0, 1]], float)
    out = {}
    for f, h in H.items():
        g = T @ h
        out[f] = g / g[2, 2]
    return out, (int(x1 - x0) + 1, int(y1 - y0) + 1)


def _roi(Hc: np.ndarray, size_wh: tuple[int, int], canvas_wh: tuple[int, int]) -> tuple[int, int, int, int]:
    q = footprint(Hc, size_wh)
    x0, y0 = np.maximum(np.floor(q.min(axis=0)).astype(int), 0)
    x1 = min(int(np.ceil(q[:, 0].max())) + 1, canvas_wh[0])
    y1 = min(int(np.ceil(q[:, 1].max())) + 1, canvas_wh[1])
    return int(x0), int(y0), max(x1 - x0, 1), max(y1 - y0, 1)


def _warp(img: np.ndarray, Hc: np.ndarray, roi: tuple[int, int, int, int], interp=cv2.INTER_LINEAR):
    x0, y0, w, h = roi
    T = np.array([[1, 0, -x0], [0, 1, -y0], [0, 0, 1]], float)
    return cv2.warpPerspective(img, T @ Hc, (w, h), flags=interp, borderMode=cv2.BORDER_CONSTANT)


def _as_bgr(img: np.ndarray) -> np.ndarray:
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return img


def exposure_gains(
    frames: list[int],
    corners: list[tuple[int, int]],
    images: list[np.ndarray],
    masks: list[np.ndarray],
    pairs: list[tuple[int, int, float]],
    *,
    sigma_n: float = 10.0,
    sigma_g: float = 0.5,
) -> np.ndarray:
    """Per-frame gains that equalise mean intensity in overlaps (the least-squares model of
    Brown & Lowe / OpenCV's GainCompensator), over overlapping pairs only, so linear in frames.
    The prior keeping gains near 1 is weaker than OpenCV's (sigma_g 0.5, not 0.1), so a frame 40 %
    darker is corrected, and the gains are scaled so that their median is 1."""
    pos = {f: k for k, f in enumerate(frames)}
    n = len(frames)
    A = np.zeros((n, n))
    b = np.zeros(n)
    for fi, fj, _ in pairs:
        i, j = pos[fi], pos[fj]
        (xi, yi), (xj, yj) = corners[i], corners[j]
        hi, wi = masks[i].shape
        hj, wj = masks[j].shape
        x0, y0 = max(xi, xj), max(yi, yj)
        x1, y1 = min(xi + wi, xj + wj), min(yi + hi, yj + hj)
        if x1 <= x0 or y1 <= y0:
            continue
        si = (slice(y0 - yi, y1 - yi), slice(x0 - xi, x1 - xi))
        sj = (slice(y0 - yj, y1 - yj), slice(x0 - xj, x1 - xj))
        both = (masks[i][si] > 0) & (masks[j][sj] > 0)
        nij = int(both.sum())
        if nij < 50:
            continue
        Ii = float(images[i][si][both].mean())
        Ij = float(images[j][sj][both].mean())
        # d/dg of nij * ((g_i Ii - g_j Ij)^2 / sn^2 + (1 - g_i)^2 / sg^2 + (1 - g_j)^2 / sg^2)
        A[i, i] += nij * (Ii * Ii / sigma_n**2 + 1 / sigma_g**2)
        A[j, j] += nij * (Ij * Ij / sigma_n**2 + 1 / sigma_g**2)
        A[i, j] -= nij * Ii * Ij / sigma_n**2
        A[j, i] -= nij * Ii * Ij / sigma_n**2
        b[i] += nij / sigma_g**2
        b[j] += nij / sigma_g**2
    empty = np.diag(A) == 0
    A[empty, empty] = 1.0
    b[empty] = 1.0
    gains = np.linalg.solve(A, b)
    return gains / np.median(gains)  # the typical frame keeps its exposure


def seam_size(size_wh: tuple[int, int], seam_megapix: float = BlendParams.seam_megapix) -> tuple[int, int]:
    """Frame size (W, H) at the seam scale."""
    w, h = size_wh
    sc = min(1.0, float(np.sqrt(seam_megapix * 1e6 / (w * h))))
    return max(int(round(w * sc)), 1), max(int(round(h * sc)), 1)


def _shrunk(q: np.ndarray, d: float) -> np.ndarray:
    """A convex quadrilateral's corners moved ``d`` px toward its centroid."""
    c = q.mean(axis=0)
    v = q - c
    n = np.linalg.norm(v, axis=1, keepdims=True)
    return c + v * np.maximum(n - d, 0) / np.maximum(n, 1e-9)


_KERNEL = np.ones((3, 3), np.uint8)


def _footprint_mask(Hc: np.ndarray, size_wh: tuple[int, int], roi: tuple[int, int, int, int]) -> np.ndarray:
    """The frame's mask in ``roi`` of the canvas, eroded by 1 px (what the blender is fed)."""
    return cv2.erode(_warp(np.full(size_wh[::-1], 255, np.uint8), Hc, roi, cv2.INTER_NEAREST), _KERNEL)


def _blend_set(frames: list[int], Hc: dict[int, np.ndarray], size_wh: tuple[int, int], canvas_wh: tuple[int, int],
               max_overlap: float, margin_px: float = 2.0) -> tuple[list[int], dict[int, tuple[int, int, np.ndarray]]]:
    """The frames to blend, and the slivers of the others. In order, a frame is left out while it overlaps the last
    frame kept by more than ``max_overlap`` of its area. Where a frame left out sees wall that no kept frame does
    (inside a kept frame's footprint by ``margin_px``: a sweep's edges, its turns), that sliver of it is blended too
    (frame -> (x, y, mask) in canvas px, the mask cut to its bounding box), so the mosaic covers what all frames cover.
    On a sweep at 10 Hz most of a frame is in its neighbours: synth_rust_sweep (40 px steps on 512 px frames) blends
    36 of its 189 frames whole, and the seams and the blender, which grow with the frames' overlapping area, take a
    fraction of the time. The alignment is not touched: every frame keeps its homography."""
    if max_overlap >= 1.0 or len(frames) <= 2:
        return list(frames), {}
    quads = {f: footprint(Hc[f], size_wh) for f in frames}
    kept = [frames[0]]
    for f in frames[1:]:
        if overlap_fraction(quads[f], quads[kept[-1]]) < max_overlap:
            kept.append(f)
    keep = set(kept)
    # corners moved 2 * margin toward the centroid: a near-rectangle's edges move in by more than the margin
    inner = {f: _shrunk(quads[f].astype(np.float64), 2.0 * margin_px) for f in kept}
    kbox = np.array([np.concatenate([quads[k].min(axis=0), quads[k].max(axis=0)]) for k in kept])
    slivers: dict[int, tuple[int, int, np.ndarray]] = {}
    for f in frames:
        if f in keep:
            continue
        x0, y0, rw, rh = _roi(Hc[f], size_wh, canvas_wh)
        own = _footprint_mask(Hc[f], size_wh, (x0, y0, rw, rh))
        covered = np.zeros_like(own)
        near = np.flatnonzero((kbox[:, 2] >= x0) & (kbox[:, 0] <= x0 + rw) & (kbox[:, 3] >= y0) & (kbox[:, 1] <= y0 + rh))
        for i in near:
            cv2.fillConvexPoly(covered, np.round((inner[kept[i]] - (x0, y0)) * 16).astype(np.int32), 255, cv2.LINE_8, 4)
        left = cv2.bitwise_and(own, cv2.bitwise_not(covered))
        if cv2.countNonZero(left):
            bx, by, bw, bh = cv2.boundingRect(left)
            slivers[f] = (x0 + bx, y0 + by, left[by : by + bh, bx : bx + bw].copy())
    return kept, slivers


def _tiles(canvas_wh: tuple[int, int], tile_px: int, margin: int):
    """(core x0, y0, x1, y1, with-margin x0, y0, x1, y1) of each tile of the canvas."""
    W, H = canvas_wh
    for y0 in range(0, H, tile_px):
        for x0 in range(0, W, tile_px):
            x1, y1 = min(x0 + tile_px, W), min(y0 + tile_px, H)
            yield (x0, y0, x1, y1, max(x0 - margin, 0), max(y0 - margin, 0), min(x1 + margin, W), min(y1 + margin, H))


def _prefetched(pool, fn, items: list, ahead: int):
    """``fn`` over ``items`` in ``pool``, in order, at most ``ahead`` results waiting (bounded memory)."""
    if pool is None:
        yield from map(fn, items)
        return
    pending = []
    for item in items:
        pending.append(pool.submit(fn, item))
        if len(pending) > ahead:
            yield pending.pop(0).result()
    for fut in pending:
        yield fut.result()


def _blend_tile(out, tile, bands, feeds, Hc, prepared, pool=None) -> None:
    """Multi-band blend of what reaches one tile (with its margin) into ``out``. ``feeds``: (frame, canvas roi
    (x, y, w, h), gain, mask(x0, y0, x1, y1) -> uint8 mask of that canvas region). Frames are decoded and warped in
    ``pool`` (OpenCV releases the GIL) while the blender takes the previous ones."""
    cx0, cy0, cx1, cy1, mx0, my0, mx1, my1 = tile
    reach = []
    for f, (rx, ry, rw, rh), gain, mask in feeds:
        x0, y0, x1, y1 = max(rx, mx0), max(ry, my0), min(rx + rw, mx1), min(ry + rh, my1)
        if x1 > x0 and y1 > y0:
            reach.append((f, gain, mask, x0, y0, x1, y1))
    if not reach:
        return

    def warped(item):
        f, gain, mask, x0, y0, x1, y1 = item
        img = _warp(prepared(f), Hc[f], (x0, y0, x1 - x0, y1 - y0))
        if gain != 1.0:
            img = cv2.convertScaleAbs(img, alpha=float(gain))
        return img.astype(np.int16), mask(x0, y0, x1, y1), (x0, y0)

    blender = cv2.detail_MultiBandBlender(0, bands)
    blender.prepare((mx0, my0, mx1 - mx0, my1 - my0))
    for img, mask, tl in _prefetched(pool, warped, reach, ahead=4):
        blender.feed(img, mask, tl)
    result, result_mask = blender.blend(None, None)
    if isinstance(result, cv2.UMat):
        result, result_mask = result.get(), result_mask.get()
    ox, oy = cx0 - mx0, cy0 - my0
    core = (slice(oy, oy + cy1 - cy0), slice(ox, ox + cx1 - cx0))
    dst = out[cy0:cy1, cx0:cx1]
    dst[..., :3] = np.clip(result[core], 0, 255).astype(np.uint8)
    dst[..., 3] = result_mask[core]
    dst[dst[..., 3] == 0, :3] = 0


def _seam_mask(Hc: np.ndarray, size_wh: tuple[int, int], roi: tuple[int, int, int, int], seam: np.ndarray):
    """mask(x0, y0, x1, y1) of a blended frame: its footprint (eroded 1 px, on the whole footprint so a tile's cut
    makes no edge) cut by its seam mask (found at seam scale, dilated 1 px, resized)."""
    rx, ry, rw, rh = roi

    def mask(x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
        inside = _footprint_mask(Hc, size_wh, roi)[y0 - ry : y1 - ry, x0 - rx : x1 - rx]
        cut = cv2.resize(cv2.dilate(seam, _KERNEL), (rw, rh), interpolation=cv2.INTER_LINEAR_EXACT)[y0 - ry : y1 - ry, x0 - rx : x1 - rx]
        return cv2.bitwise_and(cut, inside)

    return mask


def _sliver_mask(x: int, y: int, sliver: np.ndarray):
    def mask(x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
        return sliver[y0 - y : y1 - y, x0 - x : x1 - x]

    return mask


class _no_pool:
    def __enter__(self):
        return None

    def __exit__(self, *exc) -> bool:
        return False


def render(
    load: Callable[[int], np.ndarray],
    H: dict[int, np.ndarray],
    size_wh: tuple[int, int],
    *,
    vignetting: Vignetting | None = None,
    params: BlendParams = BlendParams(),
    thumbnails: dict[int, np.ndarray] | None = None,
) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """Blend the frames of one group. Returns (BGRA uint8 mosaic, frame px -> mosaic px homographies).

    ``thumbnails`` (frame -> BGR at the seam scale, :func:`seam_size`), when given, spare the seam
    pass from decoding the frames again (the features pass keeps them).

    Alpha is 255 where some frame covers the mosaic, 0 elsewhere.
    """
    Hc, canvas_wh = canvas_layout(H, size_wh)
    if canvas_wh[0] * canvas_wh[1] > params.max_canvas_megapix * 1e6:
        raise CanvasTooLarge(f"canvas {canvas_wh[0]}x{canvas_wh[1]} px exceeds {params.max_canvas_megapix:g} MP")
    frames = sorted(Hc)
    w, h = size_wh
    gain = vignetting.gain(size_wh) if vignetting is not None else None

    def prepared(f: int) -> np.ndarray:
        img = _as_bgr(load(f))
        if gain is not None:
            img = np.clip(img.astype(np.float32) * gain[..., None], 0, 255).astype(np.uint8)
        return img

    # Pass 1: seam scale
    small_wh = seam_size(size_wh, params.seam_megapix)
    sc = small_wh[0] / w
    S = np.diag([sc, sc, 1.0])
    gain_s = cv2.resize(gain, small_wh, interpolation=cv2.INTER_AREA) if gain is not None else None

    def small_prepared(f: int) -> np.ndarray:
        t = thumbnails.get(f) if thumbnails else None
        if t is None or t.shape[1::-1] != small_wh:
            return cv2.resize(prepared(f), small_wh, interpolation=cv2.INTER_AREA)
        t = _as_bgr(t)
        return t if gain_s is None else np.clip(t.astype(np.float32) * gain_s[..., None], 0, 255).astype(np.uint8)

    small_canvas = (int(np.ceil(canvas_wh[0] * sc)) + 1, int(np.ceil(canvas_wh[1] * sc)) + 1)
    corners_s, imgs_s, masks_s = [], [], []
    ones_s = np.full(small_wh[::-1], 255, np.uint8)
    Sin = np.diag([w / small_wh[0], h / small_wh[1], 1.0])
    for f in frames:
        Hs = S @ Hc[f] @ Sin
        roi = _roi(Hs, small_wh, small_canvas)
        small = small_prepared(f)
        imgs_s.append(_warp(small, Hs, roi))
        masks_s.append(_warp(ones_s, Hs, roi, cv2.INTER_NEAREST))
        corners_s.append((roi[0], roi[1]))

    gains = np.ones(len(frames))
    if params.exposure == "gain" and len(frames) > 1:
        gains = exposure_gains(frames, corners_s, imgs_s, masks_s, layout_pairs(
            {f: S @ Hc[f] @ Sin for f in frames}, small_wh, tried=set(), min_overlap=0.05, per_frame=8))

    # seams and the full-scale blend over the frames that add something (exposure gains above over all frames)
    blend, slivers = _blend_set(frames, Hc, size_wh, canvas_wh, params.blend_overlap)
    pos = {f: k for k, f in enumerate(frames)}
    imgs_b, corners_b, masks_b = [imgs_s[pos[f]] for f in blend], [corners_s[pos[f]] for f in blend], [masks_s[pos[f]] for f in blend]
    if params.seam == "dp" and len(blend) > 1:
        finder = cv2.detail_DpSeamFinder("COLOR")
        seams = finder.find([im.astype(np.float32) for im in imgs_b], corners_b, [cv2.UMat(m) for m in masks_b])
        seams = [s.get() if isinstance(s, cv2.UMat) else s for s in seams]
    elif params.seam == "voronoi" and len(blend) > 1:
        finder = cv2.detail.SeamFinder_createDefault(cv2.detail.SeamFinder_VORONOI_SEAM)
        seams = finder.find([im.astype(np.float32) for im in imgs_b], corners_b, [cv2.UMat(m) for m in masks_b])
        seams = [s.get() if isinstance(s, cv2.UMat) else s for s in seams]
    else:
        seams = masks_b
    del imgs_s, imgs_b

    # Pass 2: full scale, tile by tile (each tile blended with the margin its pyramid needs, so
    # tiles join without a visible edge; memory is bounded by the tile, not by the wall)
    blend_width = min(np.sqrt(canvas_wh[0] * canvas_wh[1]) * params.blend_strength / 100.0, params.max_blend_frame * np.hypot(w, h))
    bands = max(int(np.ceil(np.log2(max(blend_width, 2.0)))) - 1, 1)
    out = np.zeros((canvas_wh[1], canvas_wh[0], 4), np.uint8)
    feeds = []
    for k, f in enumerate(blend):
        roi = _roi(Hc[f], size_wh, canvas_wh)
        feeds.append((f, roi, gains[pos[f]], _seam_mask(Hc[f], size_wh, roi, seams[k])))
    for f, (x, y, m) in sorted(slivers.items()):
        feeds.append((f, (x, y, m.shape[1], m.shape[0]), gains[pos[f]], _sliver_mask(x, y, m)))
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=params.workers) if params.workers > 0 else _no_pool() as pool:
        for tile in _tiles(canvas_wh, params.tile_px, 2 ** (bands + 1)):
            _blend_tile(out, tile, bands, feeds, Hc, prepared, pool)
    return out, Hc
