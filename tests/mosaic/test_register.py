"""Registration against exact ground truth: synthetic lawnmower and a real-texture golden fixture."""

from __future__ import annotations

import numpy as np
import pytest

from inspect_pipe.mosaic import FolderSource, RegisterParams, register
from inspect_pipe.mosaic.metrics import global_shape, misalignment


def test_synthetic_lawnmower_is_placed_with_subpixel_misalignment(synthetic_sweep):
    # GIVEN a 3-pass sweep with yaw, scale and tilt jitter and exact ground truth
    folder, H_gt, path, _ = synthetic_sweep
    # WHEN it is registered with the camera's focal length known
    reg = register(FolderSource(folder), params=RegisterParams(focal_px=path.focal_px))
    # THEN every frame is placed in one group
    assert not reg.unplaced
    assert len(reg.groups) == 1 and len(reg.groups[0].frames) == len(H_gt)
    H = reg.groups[0].H
    near, cross = misalignment(H, H_gt, path.frame_wh)
    # AND the same wall point lands on the same mosaic pixel from every frame that saw it
    assert near.rmse_px < 0.5 and near.max_px < 3.0
    assert cross.n_pairs > 10, "pass-to-pass pairs must be scored"
    assert cross.rmse_px < 0.5 and cross.max_px < 3.0
    # AND the mosaic is the wall up to a similarity (no bending, no shrinking)
    shape = global_shape(H, H_gt, path.frame_wh)
    assert shape.rms_px < 1.5
    assert abs(shape.scale_error) < 0.005


def test_pass_to_pass_pairs_are_found_and_pairs_grow_linearly(synthetic_sweep):
    folder, H_gt, path, _ = synthetic_sweep
    reg = register(FolderSource(folder), params=RegisterParams(focal_px=path.focal_px))
    n = len(H_gt)
    cross = [p for p in reg.pairs if abs(p.j - p.i) > path.per_pass // 2]
    assert len(cross) >= path.passes - 1, "no loop closure between passes"
    tried = len(reg.pairs) + len(reg.failures)
    assert tried <= 6 * n, f"{tried} pairs tried for {n} frames: not linear"
    assert tried < n * (n - 1) / 2


def test_golden_rust_fixture(rust_mini):
    """Real rusty-metal texture (13 frames of synth_rust_sweep, two passes): golden figures."""
    folder, H_gt, focal = rust_mini
    reg = register(FolderSource(folder), params=RegisterParams(focal_px=focal))
    assert not reg.unplaced and len(reg.groups) == 1
    near, cross = misalignment(reg.groups[0].H, H_gt, (256, 192))
    assert near.rmse_px < 0.2, near
    assert cross.n_pairs >= 10 and cross.rmse_px < 0.3, cross
    assert global_shape(reg.groups[0].H, H_gt, (256, 192)).rms_px < 0.6


def test_without_focal_length_gauge_keeps_mean_frame_scale(synthetic_sweep):
    folder, H_gt, path, _ = synthetic_sweep
    reg = register(FolderSource(folder))
    H = reg.groups[0].H
    c = np.array([path.frame_wh[0] / 2, path.frame_wh[1] / 2, 1.0])
    scales = []
    for h in H.values():
        J = h[:2, :2] * (h[2] @ c) - np.outer((h @ c)[:2], h[2, :2])
        scales.append(np.sqrt(abs(np.linalg.det(J))) / (h[2] @ c) ** 2)
    assert abs(np.mean(scales) - 1.0) < 0.01  # mosaic px = mean frame px: it neither shrinks nor grows


class _Frames:
    """A frame source over images in memory."""

    def __init__(self, frames: list[np.ndarray]) -> None:
        self.frames = frames

    def __len__(self) -> int:
        return len(self.frames)

    def name(self, i: int) -> str:
        return f"{i}"

    def load(self, i: int) -> np.ndarray:
        return self.frames[i]


def test_slow_sweep_aligns_keyframes_and_attaches_the_rest():
    # GIVEN a slow sweep (3 px between frames, 1 % of the diagonal) over a synthetic wall
    from inspect_pipe.mosaic.synthetic import SweepPath, lawnmower_homographies, render_frame, textured_wall

    rng = np.random.default_rng(9)
    path = SweepPath(passes=2, per_pass=40, step_px=3.0, row_px=110.0)
    wall = textured_wall(600, 420, rng)
    Hs = lawnmower_homographies(path, rng)
    frames = [render_frame(wall, H, path.frame_wh) for H in Hs]

    reg = register(_Frames(frames), params=RegisterParams(focal_px=path.focal_px))
    # THEN every frame is placed, but only a fraction went through global alignment
    g = reg.groups[0]
    assert len(g.frames) == len(Hs) and not reg.unplaced
    assert len(g.keyframes) < 0.5 * len(Hs)
    near, cross = misalignment(g.H, dict(enumerate(Hs)), path.frame_wh)
    assert near.rmse_px < 0.5 and cross.rmse_px < 0.5 and cross.max_px < 3.0


class _CountingSource:
    """Frames of a texture-poor wall (smooth shading and a few faint spots), counting decodes."""

    def __init__(self, n: int) -> None:
        rng = np.random.default_rng(3)
        yy, xx = np.mgrid[0:192, 0:256]
        base = 120 + 20 * np.sin(xx / 40.0) + 10 * np.cos(yy / 30.0)
        self.frames = [np.clip(base + rng.normal(0, 1.0, base.shape), 0, 255).astype(np.uint8) for _ in range(n)]
        self.loads = [0] * n

    def __len__(self) -> int:
        return len(self.frames)

    def name(self, i: int) -> str:
        return f"f{i}"

    def load(self, i: int) -> np.ndarray:
        self.loads[i] += 1
        return self.frames[i]


def test_a_clearly_texture_poor_sweep_is_decided_on_the_quick_sample(monkeypatch):
    from inspect_pipe.mosaic import _register

    # GIVEN a 40-frame sweep whose every frame is texture-poor, and a count of the detections by mode
    modes: list[str] = []
    real = _register.detect_features

    def counting(gray, **kw):
        modes.append(kw.get("mode", "auto"))
        return real(gray, **kw)

    monkeypatch.setattr(_register, "detect_features", counting)
    src = _CountingSource(40)
    params = RegisterParams(texture_quick=8)
    _register.extract_features(src, None, params, 2, None)
    # THEN only the quick sample's 8 frames were detected normally, every frame once with equalisation, each decoded once
    assert modes.count("normal") == 8 and modes.count("low_texture") == 40
    assert src.loads == [1] * 40


@pytest.mark.parametrize("texture_sample", [64, 8], ids=["in-the-sample", "after-the-sample"])
def test_one_frame_too_dull_for_the_normal_detector_switches_the_sweep(texture_sample):
    from inspect_pipe.mosaic import _register
    from inspect_pipe.mosaic.synthetic import SweepPath, lawnmower_homographies, render_frame, textured_wall

    # GIVEN a well-textured 24-frame sweep with one frame at a tenth of the contrast (the normal detector finds
    # nothing in it, the low-texture one plenty): 4 % of the frames, under the share that switches a sweep
    rng = np.random.default_rng(5)
    path = SweepPath(passes=2, per_pass=12)
    wall = textured_wall(700, 560, rng)
    Hs = lawnmower_homographies(path, rng)
    frames = [render_frame(wall, H, path.frame_wh) for H in Hs]
    sample = set(_register._texture_sample(len(frames), texture_sample))
    dull = 7 if texture_sample >= len(frames) else next(i for i in range(1, len(frames)) if i not in sample)
    f = frames[dull].astype(np.float32)
    frames[dull] = np.clip(f.mean() + 0.1 * (f - f.mean()) + rng.normal(0, 0.6, f.shape), 0, 255).astype(np.uint8)

    reg = register(_Frames(frames), params=RegisterParams(focal_px=path.focal_px, texture_sample=texture_sample))
    # THEN the whole sweep is detected the low-texture way and every frame is placed, the dull one too (it was lost)
    assert not reg.unplaced, reg.unplaced
    assert sum(len(g.frames) for g in reg.groups) == len(frames)
    g = reg.groups[0]
    near, _ = misalignment(g.H, dict(enumerate(Hs)), path.frame_wh)
    assert near.max_px < 3.0, near


def test_bridge_keyframes_spread_over_a_group_whose_feature_counts_tie():
    from inspect_pipe.mosaic import _register
    from inspect_pipe.mosaic._features import Features

    # GIVEN two groups of a low-texture sweep, where the detector's cap gives every frame 1500 features
    feats = {f: Features(np.zeros((1500, 2), np.float32), np.zeros((1500, 128), np.uint8), False) for f in range(165)}
    small, large = list(range(66)), list(range(66, 165))
    # WHEN the unguided bridge candidates are chosen
    cand = _register._bridge_candidates([large, small], feats, set(), 400)
    # THEN the smaller group's keyframes spread over the whole group (its last pass is the one beside the other group)
    keys = sorted({i for i, j in cand})
    assert len(keys) == 4 and keys[0] <= 5 and keys[-1] >= 60
    # AND where the counts differ, the best-textured frames are still the ones taken
    feats.update({f: Features(np.zeros((200, 2), np.float32), np.zeros((200, 128), np.uint8), False) for f in range(0, 66, 2)})
    keys = sorted({i for i, j in _register._bridge_candidates([large, small], feats, set(), 400)})
    assert all(k % 2 == 1 for k in keys)
