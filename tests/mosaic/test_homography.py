from __future__ import annotations

import cv2
import numpy as np

from inspect_pipe.mosaic import detect_features, match_pair
from inspect_pipe.mosaic.synthetic import render_frame, textured_wall


def _frames(offset_xy, rng, size=(256, 192)):
    wall = textured_wall(800, 600, rng)
    H1 = np.array([[1, 0, 100], [0, 1, 100], [0, 0, 1.0]])
    H2 = np.array([[1, 0, 100 + offset_xy[0]], [0, 1, 100 + offset_xy[1]], [0, 0, 1.0]])
    return [cv2.cvtColor(render_frame(wall, H, size), cv2.COLOR_BGR2GRAY) for H in (H1, H2)], np.linalg.inv(H2) @ H1


def test_overlapping_pair_recovers_the_true_homography():
    (a, b), H_true = _frames((60, 20), np.random.default_rng(1))
    res = match_pair(0, 1, detect_features(a), detect_features(b), (256, 192), rng=np.random.default_rng(0))
    assert res, getattr(res, "reason", "")
    corners = np.float32([[0, 0], [256, 0], [256, 192], [0, 192]]).reshape(-1, 1, 2)
    err = np.abs(cv2.perspectiveTransform(corners, res.H) - cv2.perspectiveTransform(corners, H_true)).max()
    assert err < 0.5


def test_frames_that_do_not_overlap_are_rejected_with_a_reason():
    (a, b), _ = _frames((400, 300), np.random.default_rng(2))
    res = match_pair(0, 1, detect_features(a), detect_features(b), (256, 192), rng=np.random.default_rng(0))
    assert not res
    assert res.reason


def test_repetitive_texture_match_contradicting_the_layout_is_rejected():
    # A periodic texture: the frame 64 px to the right looks exactly like the frame itself.
    rng = np.random.default_rng(3)
    tile = textured_wall(64, 64, rng)
    wall = np.tile(tile, (12, 12, 1))
    H1 = np.array([[1, 0, 64], [0, 1, 64], [0, 0, 1.0]])
    H2 = np.array([[1, 0, 64 + 64 + 20], [0, 1, 64], [0, 0, 1.0]])  # truly 84 px to the right
    a, b = (cv2.cvtColor(render_frame(wall, H, (256, 192)), cv2.COLOR_BGR2GRAY) for H in (H1, H2))
    fa, fb = detect_features(a), detect_features(b)
    # the layout predicts a shift of 84 px; a prior 150 px off must not be confirmed by a texture alias
    wrong_prior = np.array([[1, 0, -84 + 150], [0, 1, 0], [0, 0, 1.0]])
    res = match_pair(0, 1, fa, fb, (256, 192), prior_H=wrong_prior, rng=np.random.default_rng(0))
    if res:  # an alias may be found, but then it must agree with the prior, never be far from it
        shift = res.H[0, 2]
        assert abs(shift - wrong_prior[0, 2]) < 0.25 * np.hypot(256, 192)
    right_prior = np.array([[1, 0, -84], [0, 1, 0], [0, 0, 1.0]])
    res = match_pair(0, 1, fa, fb, (256, 192), prior_H=right_prior, rng=np.random.default_rng(0))
    assert res and abs(res.H[0, 2] + 84) < 1.0
