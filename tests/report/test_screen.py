"""The register's screening on synthetic walls: seams and plate edges left out, real cracks that run
near or across them kept; entries outside the surveyed region or below the tank top left out;
confirmation across the keyframes that saw an entry."""

from __future__ import annotations

import numpy as np
import pytest

from inspect_pipe.report._geo import Survey, WallMap
from inspect_pipe.report._register import FrameView, RegisterParams, build_defects
from inspect_pipe.report._screen import Precision, line_fit, screen_defects

S = 0.002  # m per mosaic px
H, W = 600, 1200  # 1.2 m x 2.4 m; mosaic px -> wall: u = x S, v = 1.2 - y S (floor at v = 0)
WALL = WallMap(np.array([[S, 0, 0], [0, -S, H * S], [0, 0, 1]]), S, fit_rms_m=0.012)
EDGE_Y = 150  # a plate edge (horizontal) at v = 0.9 m


def crack_path(x0: int, y0: int, n: int, rng, *, step=(4, 0), wander: float = 1.6) -> np.ndarray:
    """A meandering crack: n steps of ``step`` px, its direction wandering like a real crack's."""
    pts = [(float(x0), float(y0))]
    a = float(np.arctan2(step[1], step[0]))
    L = float(np.hypot(*step))
    for _ in range(n):
        a += rng.normal(0, 0.35)
        a = float(np.clip(a, np.arctan2(step[1], step[0]) - wander / 2, np.arctan2(step[1], step[0]) + wander / 2))
        x, y = pts[-1]
        pts.append((x + L * np.cos(a), y + L * np.sin(a)))
    return np.array(pts)


def draw(mask, prob, pts, p: int, width: int = 2):
    import cv2

    poly = np.round(pts).astype(np.int32).reshape(-1, 1, 2)
    cv2.polylines(mask, [poly], False, 255, width)
    cv2.polylines(prob, [poly], False, p, width + 2)


def wall(seed: int):
    """Crack class maps of a wall with a plate edge whose response the detector turned into three
    short detections, a real crack running 2 cm below the edge, one crossing it, one far from it."""
    import cv2

    rng = np.random.default_rng(seed)
    mask = np.zeros((H, W), np.uint8)
    prob = np.full((H, W), 8, np.uint8)
    cv2.line(prob, (0, EDGE_Y), (W - 1, EDGE_Y), 110, 3)  # the edge's ridge: above seam_prob, below the detector's decision
    for x0 in (100, 520, 900):  # its strongest stretches, 5-8 cm: what the detector reported
        n = int(rng.integers(25, 40))
        x1 = x0 + n
        cv2.line(mask, (x0, EDGE_Y + int(rng.integers(-1, 2))), (x1, EDGE_Y), 255, 2)
        cv2.line(prob, (x0, EDGE_Y), (x1, EDGE_Y), 230, 3)
    real = {
        "parallel": crack_path(250, EDGE_Y + 10, 40, rng),  # 2 cm below the edge, along it
        "crossing": crack_path(700, EDGE_Y - 60, 30, rng, step=(1, 4)),  # runs down across the edge
        "far": crack_path(300, 420, 50, rng),
    }
    for pts in real.values():
        draw(mask, prob, pts, 220)
    return {"crack": mask > 0}, {"crack": prob}, real


def _candidates(masks, probs, keyframe_masks=None):
    views = [FrameView(0, np.eye(3), (W, H))]
    return build_defects(masks, probs, WALL, views, Survey(), keyframe_masks=keyframe_masks, params=RegisterParams())


def _at(defects, pts):
    """The candidate whose centroid is nearest the middle of ``pts`` (mosaic px)."""
    c = WALL.to_wall(pts.mean(0, keepdims=True))[0]
    return min(defects, key=lambda d: np.hypot(d.centroid_wall_m[0] - c[0], d.centroid_wall_m[1] - c[1]))


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_plate_edge_detections_are_left_out_and_real_cracks_near_it_are_kept(seed):
    masks, probs, real = wall(seed)
    cands = _candidates(masks, probs)
    valid = np.ones((H, W), bool)
    kept, dropped = screen_defects(cands, masks, probs, S, (0.0, 0.0, W * S, H * S), 0.0, valid)
    seams = [x for x in dropped if x.rule == "seam"]
    assert len(seams) == 3, [(x.centroid_wall_m, x.reason) for x in dropped]
    assert all(abs(x.centroid_wall_m[1] - (H - EDGE_Y) * S) < 0.01 for x in seams)
    for name, pts in real.items():
        d = _at(kept, pts)
        c = WALL.to_wall(pts.mean(0, keepdims=True))[0]
        assert np.hypot(d.centroid_wall_m[0] - c[0], d.centroid_wall_m[1] - c[1]) < 0.05, name
    assert len(kept) == 3


def test_a_long_straight_detection_is_a_seam_even_without_a_ridge_around_it():
    import cv2

    mask = np.zeros((H, W), np.uint8)
    prob = np.full((H, W), 8, np.uint8)
    cv2.line(mask, (200, 300), (420, 302), 255, 2)  # 44 cm, straight: a weld seam
    cv2.line(prob, (200, 300), (420, 302), 230, 3)
    masks, probs = {"crack": mask > 0}, {"crack": prob}
    kept, dropped = screen_defects(_candidates(masks, probs), masks, probs, S, (0.0, 0.0, W * S, H * S), 0.0, np.ones((H, W), bool))
    assert not kept and dropped[0].rule == "seam" and "44 cm long" in dropped[0].reason
    # the same detection bent into a real crack's path is kept
    rng = np.random.default_rng(7)
    mask[:] = 0
    draw(mask, prob, crack_path(200, 300, 55, rng), 230)
    masks = {"crack": mask > 0}
    kept, dropped = screen_defects(_candidates(masks, probs), masks, probs, S, (0.0, 0.0, W * S, H * S), 0.0, np.ones((H, W), bool))
    assert len(kept) == 1 and not dropped


def test_entries_outside_the_region_below_the_tank_top_or_on_unimaged_wall_are_left_out():
    import cv2

    mask = np.zeros((H, W), np.uint8)
    for x, y in [(100, 80), (600, 590), (1100, 300), (600, 300)]:
        cv2.rectangle(mask, (x - 8, y - 8), (x + 8, y + 8), 255, -1)
    masks, probs = {"corrosion": mask > 0}, {"corrosion": np.where(mask > 0, 230, 5).astype(np.uint8)}
    valid = np.ones((H, W), bool)
    valid[:, 1000:] = False  # not imaged
    region = (0.0, -0.5, 2.4, 1.0)  # v up to 1.0 m: (100, 80) at v 1.04 lies above it
    cands = _candidates(masks, probs)
    kept, dropped = screen_defects(cands, masks, probs, S, region, 0.05, valid)  # tank top at v = 0.05 m: (600, 590) at v 0.02 is below
    assert [tuple(np.round(d.centroid_wall_m, 2)) for d in kept] == [(1.2, 0.6)]
    why = sorted(x.reason.split(" (")[0].split(" u ")[0] for x in dropped)
    assert why == ["below the tank top", "centre on a part of the mosaic no frame imaged", "outside the surveyed region"]


def test_confirmation_needs_half_of_the_keyframes_that_saw_it():
    import cv2

    mask = np.zeros((H, W), np.uint8)
    spots = [(200, 300), (600, 300), (1000, 300)]
    for x, y in spots:
        cv2.rectangle(mask, (x - 10, y - 10), (x + 10, y + 10), 255, -1)
    masks, probs = {"corrosion": mask > 0}, {"corrosion": np.where(mask > 0, 230, 5).astype(np.uint8)}
    hit = lambda x, y: (lambda m: (cv2.rectangle(m, (x - 10, y - 10), (x + 10, y + 10), 1, -1), m > 0)[1])(np.zeros((H, W), np.uint8))  # noqa: E731
    # keyframes 0-3 each see the whole mosaic. Spot 1: found by 2 of 4 (kept); spot 2: by 1 of 4 (left out)
    kf = {"corrosion": [(0, hit(*spots[0]) | hit(*spots[1])), (1, hit(*spots[0]) | hit(*spots[1]) | hit(*spots[2])), (2, np.zeros((H, W), bool)), (3, np.zeros((H, W), bool))]}
    views = [FrameView(i, np.eye(3), (W, H)) for i in range(4)]
    cands = build_defects(masks, probs, WALL, views, Survey(), keyframe_masks=kf, params=RegisterParams())
    kept, dropped = screen_defects(cands, masks, probs, S, (0.0, 0.0, W * S, H * S), 0.0, np.ones((H, W), bool))
    assert [round(d.centroid_wall_m[0], 1) for d in kept] == [0.4, 1.2]
    assert dropped[0].rule == "unconfirmed" and "found by 1 of the 4 keyframes" in dropped[0].reason and "needs 2" in dropped[0].reason
    # a keyframe that holds a spot only in part (its border cuts the spot's box) did not see it
    part = [FrameView(0, np.array([[1.0, 0, 195], [0, 1, 0], [0, 0, 1]]), (W - 195, H))]  # its left edge at x 195: through spot 0 (190-210)
    kf1 = {"corrosion": [(0, np.zeros((H, W), bool))]}
    cands = build_defects(masks, probs, WALL, part, Survey(), keyframe_masks=kf1, params=RegisterParams())
    assert [len(d.keyframes_seen) for d in cands] == [0, 1, 1]
    kept, dropped = screen_defects(cands, masks, probs, S, (0.0, 0.0, W * S, H * S), 0.0, np.ones((H, W), bool))
    assert [round(d.centroid_wall_m[0], 1) for d in kept] == [0.4] and len(dropped) == 2  # seen whole and missed: left out
    # an entry no keyframe saw is kept on the mosaic's detection alone
    cands = build_defects(masks, probs, WALL, views, Survey(), keyframe_masks={}, params=RegisterParams())
    kept, _ = screen_defects(cands, masks, probs, S, (0.0, 0.0, W * S, H * S), 0.0, np.ones((H, W), bool))
    assert len(kept) == 3 and all(not d.keyframes_seen for d in kept)


def test_precision_follows_the_wall_fit():
    p = Precision.of(0.002, 0.013)
    assert p.position_step_m == 0.01 and p.pos(4.6024) == "4.60"
    assert Precision.of(0.002, 0.002).pos(4.6024) == "4.602"
    assert Precision.of(0.002, 0.05).pos(4.6024) == "4.6"
    assert Precision.of(0.002, None).position_sigma_m == pytest.approx(0.004)


def test_line_fit_residual():
    t = np.linspace(0, 100, 200)
    c, d, rms, t0, t1 = line_fit(np.c_[t, 0.5 * t + 3])
    assert rms < 1e-9 and t1 - t0 == pytest.approx(np.hypot(100, 50))


def test_a_keyframe_that_found_the_defect_a_few_mm_off_confirms_it():
    import cv2

    mask = np.zeros((H, W), np.uint8)
    cv2.rectangle(mask, (590, 295), (610, 305), 255, -1)
    masks, probs = {"corrosion": mask > 0}, {"corrosion": np.where(mask > 0, 230, 5).astype(np.uint8)}
    views = [FrameView(i, np.eye(3), (W, H)) for i in range(2)]
    shifted = np.zeros((H, W), bool)
    shifted[308:312, 590:610] = True  # 3 px (6 mm) below the mosaic's detection: inside the 1 cm tolerance
    far = np.zeros((H, W), bool)
    far[320:324, 590:610] = True  # 15 px (3 cm) below: not this defect
    for kf, found in (([(0, shifted), (1, shifted)], 2), ([(0, far), (1, far)], 0)):
        cands = build_defects(masks, probs, WALL, views, Survey(), keyframe_masks={"corrosion": kf}, params=RegisterParams())
        assert len(cands) == 1 and len(cands[0].keyframes_detected) == found and len(cands[0].keyframes_seen) == 2


def test_an_entry_cut_by_the_imaged_walls_edge_is_marked_beyond_the_survey_with_its_surveyed_area():
    """A rust patch the imaged wall's edge cuts keeps the surveyed part's area and says it goes on
    past the edge (its area is a lower bound); one well inside is not marked."""
    import cv2

    valid = np.zeros((H, W), bool)
    valid[:, :800] = True  # the mosaic ends at x = 800 px (u = 1.6 m)
    mask = np.zeros((H, W), np.uint8)
    cv2.circle(mask, (790, 300), 40, 255, -1)  # 8 cm radius, its centre 1 cm inside the edge
    cv2.circle(mask, (300, 300), 40, 255, -1)
    masks = {"corrosion": (mask > 0) & valid}  # the detector saw only the imaged part
    probs = {"corrosion": np.where(masks["corrosion"], 230, 8).astype(np.uint8)}
    views = [FrameView(0, np.eye(3), (W, H))]
    out = build_defects(masks, probs, WALL, views, Survey(), valid=valid, params=RegisterParams())
    by_u = sorted(out, key=lambda d: d.centroid_wall_m[0])
    assert len(by_u) == 2
    inside, cut = by_u
    assert not inside.beyond_survey and cut.beyond_survey
    full = np.pi * (40 * S) ** 2
    assert inside.area_m2 == pytest.approx(full, rel=0.05)
    # the register leaves out the 2 cm (10 px) band along the edge: what stays is the part left of x = 790
    assert cut.area_m2 < 0.55 * full and cut.area_m2 > 0.4 * full
    assert cut.to_json()["beyond_survey"] is True
