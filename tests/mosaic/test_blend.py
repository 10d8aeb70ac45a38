from __future__ import annotations

import cv2
import numpy as np

from inspect_pipe.mosaic import BlendParams, FolderSource, RegisterParams, register, render
from inspect_pipe.mosaic._vignetting import VignettingAccumulator


def test_blended_mosaic_matches_the_wall(synthetic_sweep):
    folder, H_gt, path, wall = synthetic_sweep
    src = FolderSource(folder)
    reg = register(src, params=RegisterParams(focal_px=path.focal_px))
    mosaic, Hc = render(src.load, reg.groups[0].H, path.frame_wh, vignetting=reg.vignetting)
    assert mosaic.shape[2] == 4 and mosaic.dtype == np.uint8
    # Map the mosaic back onto the wall through frame 0 (mosaic -> frame 0 -> wall) and compare.
    M = H_gt[0] @ np.linalg.inv(Hc[0])
    back = cv2.warpPerspective(mosaic, M, (wall.shape[1], wall.shape[0]))
    covered = cv2.erode((back[..., 3] == 255).astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    assert covered.mean() > 0.4
    diff = np.abs(back[..., :3].astype(float) - wall.astype(float))[covered]
    assert np.median(diff) < 6.0, np.median(diff)


def test_exposure_gains_equalise_a_darker_frame(synthetic_sweep, tmp_path):
    folder, H_gt, path, wall = synthetic_sweep
    src = FolderSource(folder)
    reg = register(src)
    H = reg.groups[0].H

    def load(i):
        img = src.load(i)
        return (img * 0.6).astype(np.uint8) if i == 3 else img

    flat, Hc = render(load, H, path.frame_wh, params=BlendParams(exposure="none", seam="none"))
    comp, _ = render(load, H, path.frame_wh, params=BlendParams(exposure="gain", seam="none"))
    ref, _ = render(src.load, H, path.frame_wh, params=BlendParams(exposure="none", seam="none"))
    w, h = path.frame_wh
    corners = cv2.perspectiveTransform(np.float32([[0, 0], [w, 0], [w, h], [0, h]]).reshape(-1, 1, 2), Hc[3]).reshape(-1, 2)
    mask = np.zeros(ref.shape[:2], np.uint8)
    cv2.fillConvexPoly(mask, corners.astype(np.int32), 1)
    m = (mask > 0) & (ref[..., 3] > 0)
    err_flat = abs(flat[..., :3][m].mean() - ref[..., :3][m].mean())
    err_comp = abs(comp[..., :3][m].mean() - ref[..., :3][m].mean())
    assert err_comp < 0.5 * err_flat


def test_vignetting_is_estimated_from_the_sweep():
    rng = np.random.default_rng(5)
    acc = VignettingAccumulator()
    h, w = 96, 128
    y, x = np.mgrid[0:h, 0:w]
    r2 = ((x - (w - 1) / 2) ** 2 + (y - (h - 1) / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    falloff = 1 - 0.3 * r2
    for _ in range(40):
        scene = cv2.GaussianBlur(rng.uniform(60, 200, (h, w)), (0, 0), 3)
        acc.add(np.clip(scene * falloff, 0, 255).astype(np.uint8))
    v = acc.result()
    assert v is not None
    assert abs(v.falloff_at_corner() - 0.3) < 0.06


def test_tiled_blending_matches_one_piece(synthetic_sweep):
    # GIVEN the sweep's frames placed by their true homographies
    folder, H_gt, path, wall = synthetic_sweep
    src = FolderSource(folder)
    one, _ = render(src.load, H_gt, path.frame_wh)
    # WHEN the full-scale blend is done in 96-px tiles (dozens of them) instead of one piece
    tiled, _ = render(src.load, H_gt, path.frame_wh, params=BlendParams(tile_px=96))
    # THEN the mosaics are the same but for rounding near tile edges
    assert one.shape == tiled.shape and one.shape[0] > 3 * 96
    assert (one[..., 3] == tiled[..., 3]).mean() > 0.999
    both = (one[..., 3] > 0) & (tiled[..., 3] > 0)
    diff = np.abs(one[..., :3].astype(int) - tiled[..., :3].astype(int))[both]
    assert np.percentile(diff, 99) <= 2 and diff.max() <= 12, (np.percentile(diff, 99), diff.max())
