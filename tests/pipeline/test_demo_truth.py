"""`compare_with_truth`: the demo's found-vs-truth figures (docs/pipeline.md)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from inspect_pipe.pipeline._demo import TruthDefect, compare_with_truth


def _entry(ident, cls, u, v, area, status="suggested"):
    return SimpleNamespace(id=ident, cls=cls, centroid_wall_m=(u, v), area_m2=area, status=status, redetected=True)


def _truth(ident, cls, box, area):
    u0, v0, u1, v1 = box
    return TruthDefect(ident, cls, ((u0 + u1) / 2, (v0 + v1) / 2), area, box, "test")


def test_a_patch_registered_in_pieces_counts_its_pieces_area_not_one_fragment():
    # GIVEN a 1 m x 0.5 m true patch of 0.4 m^2, registered as a large piece and two small ones,
    # a crack far away found once, and one corrosion entry nowhere near a true defect
    truth = [_truth("T01", "corrosion", (0.0, 0.0, 1.0, 0.5), 0.4), _truth("T02", "crack", (3.0, 0.0, 3.4, 0.1), 0.001)]
    reg = [_entry("D1", "corrosion", 0.45, 0.25, 0.006),  # the closest to the centroid: a small piece
           _entry("D2", "corrosion", 0.30, 0.20, 0.30),
           _entry("D3", "corrosion", 0.90, 0.40, 0.05),
           _entry("D4", "crack", 3.2, 0.05, 0.0012),
           _entry("D5", "corrosion", 2.0, 2.0, 0.01),
           _entry("D6", "corrosion", 0.5, 0.2, 0.2, status="rejected")]  # a surveyor's rejection is no entry
    cmp = compare_with_truth(reg, truth)
    # THEN the patch is found in three pieces whose areas add up, its place their weighted centroid
    t1, t2 = cmp["rows"]
    assert t1["found"] == "D1" and sorted(t1["pieces"]) == ["D1", "D2", "D3"]
    assert t1["area_found_m2"] == pytest.approx(0.356, abs=1e-5)
    assert t1["area_error"] == pytest.approx(-0.11, abs=1e-3)
    u = (0.45 * 0.006 + 0.30 * 0.30 + 0.90 * 0.05) / 0.356
    v = (0.25 * 0.006 + 0.20 * 0.30 + 0.40 * 0.05) / 0.356
    assert t1["centroid_error_m"] == pytest.approx(((u - 0.5) ** 2 + (v - 0.25) ** 2) ** 0.5, abs=1e-4)
    assert t2["pieces"] == ["D4"] and t2["area_error"] == pytest.approx(0.2, abs=1e-3)
    # AND only the stray entry is another entry
    assert (cmp["matched"], cmp["found"], cmp["false_alarms"]) == (2, 5, 1)


def test_a_piece_joins_the_nearest_true_defect_and_each_defect_keeps_its_own_match():
    # GIVEN two small true patches whose grown boxes overlap, and three entries between them
    truth = [_truth("T01", "corrosion", (0.0, 0.0, 0.1, 0.1), 0.005), _truth("T02", "corrosion", (0.2, 0.0, 0.3, 0.1), 0.005)]
    reg = [_entry("D1", "corrosion", 0.05, 0.05, 0.004), _entry("D2", "corrosion", 0.25, 0.05, 0.004),
           _entry("D3", "corrosion", 0.22, 0.05, 0.001)]
    cmp = compare_with_truth(reg, truth)
    # THEN each defect is found by its own entry and the third joins the nearer one (T02)
    assert [r["pieces"] for r in cmp["rows"]] == [["D1"], ["D2", "D3"]]
    assert cmp["false_alarms"] == 0
    # AND a defect with nothing of its class near it is not found
    cmp = compare_with_truth([_entry("D9", "crack", 0.05, 0.05, 0.001)], truth)
    assert [r["found"] for r in cmp["rows"]] == [None, None] and cmp["false_alarms"] == 1


def test_with_the_wall_an_entry_is_near_a_defect_by_its_mask_not_its_box(tmp_path):
    # GIVEN an L-shaped true patch on a 1 m x 1 m wall at 1 cm/px (origin: top-left at u=0, v=1)
    import cv2
    import numpy as np

    from inspect_pipe.pipeline._demo import DemoWall

    labels = np.zeros((100, 100), np.uint16)
    labels[0:100, 0:20] = 1  # the L's upright, u 0-0.2 m
    labels[80:100, 0:100] = 1  # its foot, v 0-0.2 m
    cv2.imwrite(str(tmp_path / "labels.png"), labels)
    t = TruthDefect("T01", "corrosion", (0.3, 0.3), 0.36, (0.0, 0.0, 1.0, 1.0), "test")
    wall = DemoWall(tmp_path / "w.png", tmp_path / "m.png", tmp_path / "labels.png", 0.01, (0.0, 1.0), (t,), "test")
    inner = _entry("D1", "corrosion", 0.1, 0.5, 0.01)  # on the upright
    corner = _entry("D2", "corrosion", 0.7, 0.7, 0.01)  # inside the box, 0.5 m from the L
    near = _entry("D3", "corrosion", 0.3, 0.5, 0.01)  # 0.1 m right of the upright
    # WHEN matched by the box THEN all three are pieces of the patch
    assert sorted(compare_with_truth([inner, corner, near], [t])["rows"][0]["pieces"]) == ["D1", "D2", "D3"]
    # WHEN matched by the mask (grown by 0.15 m) THEN the entry in the L's empty corner is another entry
    cmp = compare_with_truth([inner, corner, near], [t], wall=wall)
    assert sorted(cmp["rows"][0]["pieces"]) == ["D1", "D3"] and cmp["false_alarms"] == 1
