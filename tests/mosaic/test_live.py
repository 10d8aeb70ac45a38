"""The live mosaicer: frames placed one by one, coverage against the synthetic sweep's truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from inspect_pipe.mosaic import LiveMosaic
from inspect_pipe.mosaic.metrics import coverage_error
from inspect_pipe.mosaic.synthetic import SweepPath, lawnmower_homographies, render_frame, textured_wall

FRAME_WH = (752, 480)


@pytest.fixture(scope="module")
def live_sweep():
    """3 passes x 30 frames of 752x480 at 10 Hz over a synthetic wall; every 10th frame blurred."""
    rng = np.random.default_rng(11)
    path = SweepPath(passes=3, per_pass=30, step_px=30, row_px=300, frame_wh=FRAME_WH, focal_px=650, margin_px=60)
    Hs = lawnmower_homographies(path, rng)
    wall = textured_wall(60 * 2 + 752 + 30 * 30 + 100, 60 * 2 + 480 + 300 * 3 + 100, rng)
    blurred = set(range(5, len(Hs), 10))
    frames = []
    for i, H in enumerate(Hs):
        img = render_frame(wall, H, FRAME_WH)
        frames.append(cv2.blur(img, (9, 9)) if i in blurred else img)
    return frames, dict(enumerate(Hs)), blurred


def test_live_mosaic_places_every_frame_fast_and_maps_coverage(live_sweep):
    # GIVEN a sweep fed frame by frame
    frames, H_gt, blurred = live_sweep
    live = LiveMosaic(FRAME_WH)
    for i, img in enumerate(frames):
        p = live.add_frame(img, {"t_s": 0.1 * i})
        assert p.index == i
    # THEN every frame is placed, each by its own small step (the 50 ms p95 goal is measured by
    # `make bench` on a quiet core; a shared CI core only guards against a step that redoes the mosaic)
    s = live.summary()
    assert s["placed"] == len(frames), s
    assert s["p95_cpu_ms"] < 400, s
    # AND blurred frames do not count as coverage, sharp ones do
    assert not any(live.usable(i) for i in blurred)
    assert sum(live.usable(i) for i in range(len(frames)) if i not in blurred) >= len(frames) - len(blurred) - 2
    # AND the coverage map matches the truth over the surveyed wall
    err, truth = coverage_error(live.covered(), live.origin_px, {p.index: p.H for p in live.placements},
                                H_gt, set(H_gt) - blurred, FRAME_WH)
    assert truth > 0.9
    assert err < 0.03, err  # 3.6 % before keyframes were held to the level and footprints drawn as the truth is
    # AND the pictures have the same size, the coverage map marks gaps in red only where nothing usable was seen
    assert live.mosaic().shape == live.coverage().shape
    assert not (live.gaps() & live.covered()).any()


def test_a_gap_in_the_sweep_shows_on_the_coverage_map(live_sweep):
    # GIVEN the same sweep with most of its middle pass lost to blur (26 frames, more than a frame width)
    frames, H_gt, _ = live_sweep
    lost = set(range(32, 58))
    live = LiveMosaic(FRAME_WH)
    for i, img in enumerate(frames):
        live.add_frame(cv2.GaussianBlur(img, (0, 0), 6) if i in lost else img, {"t_s": 0.1 * i})
    # THEN the map has a gap where only blurred frames looked, and it is in the middle of the wall
    gaps = live.gaps()
    assert gaps.sum() > 0.005 * gaps.size
    c = np.array([FRAME_WH[0] / 2, FRAME_WH[1] / 2, 1.0])
    centre = live.placements[45].H @ c
    x, y = (centre[:2] / centre[2] - live.origin_px).astype(int)
    assert gaps[y - 5 : y + 5, x - 5 : x + 5].any()


def test_a_stalled_stream_is_one_line_and_the_placed_frames_stay(live_sweep):
    frames, _, _ = live_sweep
    live = LiveMosaic(FRAME_WH)
    for i in range(10):
        live.add_frame(frames[i], {"t_s": 0.1 * i})
    placed = live.summary()["placed"]
    p = live.add_frame(frames[10], {"t_s": 4.0})  # 3.1 s without a frame
    assert "stalled" in p.problem and "3.1 s" in p.problem and "\n" not in p.problem
    assert p.placed and live.summary()["placed"] == placed + 1
    assert live.summary()["problem"] == p.problem


def test_a_frame_that_matches_nothing_is_reported_and_later_frames_still_place(live_sweep):
    frames, _, _ = live_sweep
    live = LiveMosaic(FRAME_WH)
    for i in range(6):
        live.add_frame(frames[i], {"t_s": 0.1 * i})
    p = live.add_frame(np.zeros_like(frames[0]), {"t_s": 0.6})  # lens cap
    assert not p.placed and "could not be placed" in p.problem
    q = live.add_frame(frames[7], {"t_s": 0.7})
    assert q.placed


def test_a_featureless_first_view_does_not_hold_the_mosaic_hostage(live_sweep):
    # GIVEN a sweep that starts on plain paint (no texture to match: the floor, a painted wall before the survey area)
    frames, _, _ = live_sweep
    rng = np.random.default_rng(0)
    plain = [np.clip(128 + rng.normal(0, 3, frames[0].shape), 0, 255).astype(np.uint8) for _ in range(3)]
    live = LiveMosaic(FRAME_WH)
    for i, img in enumerate(plain + frames[:30]):
        live.add_frame(img, {"t_s": 0.1 * i})
    # THEN the mosaic starts again on the first frame of texture and places the sweep; the plain views are dropped
    # and say why
    assert all(p.placed for p in live.placements[4:]), live.summary()
    assert not any(p.placed for p in live.placements[:3])
    assert all("started again" in p.problem or "could not be placed" in p.problem for p in live.placements[:3])
