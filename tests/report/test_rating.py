"""IMO MSC.1/Circ.1330 Table 1 and MSC.1/Circ.1399 thresholds; the wall is its worst area."""

from __future__ import annotations

import numpy as np
import pytest

from inspect_pipe.report import FAIR, GOOD, NOT_RATED, POOR, SCHEMES, RatingParams, rate_wall

C1330, C1399 = SCHEMES["MSC.1/Circ.1330"], SCHEMES["MSC.1/Circ.1399"]


@pytest.mark.parametrize("breakdown, hard, expected", [
    (0.0, 0.0, GOOD), (2.99, 0.0, GOOD), (3.0, 0.0, FAIR), (20.0, 0.0, FAIR), (20.01, 0.0, POOR),
    (1.0, 0.5, FAIR), (1.0, 9.99, FAIR), (1.0, 10.0, POOR),
])
def test_circ_1330_table_1(breakdown, hard, expected):
    assert C1330.rate(breakdown, hard, None) == expected


def test_circ_1399_spot_breakdown_limit_is_5_percent():
    assert C1399.rate(4.0, 0.0, None) == GOOD and C1330.rate(4.0, 0.0, None) == FAIR
    assert C1399.rate(5.0, 0.0, None) == FAIR and C1399.rate(21.0, 0.0, None) == POOR


@pytest.mark.parametrize("edges, expected", [(10.0, GOOD), (20.0, FAIR), (49.0, FAIR), (50.0, POOR)])
def test_edges_and_welds_when_measured(edges, expected):
    assert C1330.rate(0.0, 0.0, edges) == expected


def _grid(breakdown_cols: dict[int, float], shape=(100, 300)):
    """1 cm cells, three 1 m areas side by side; breakdown percent per area column."""
    imaged = np.ones(shape, bool)
    corr = np.zeros(shape, bool)
    for col, pct in breakdown_cols.items():
        n = int(round(pct / 100 * 100 * 100))
        block = np.zeros(100 * 100, bool)
        block[:n] = True
        corr[:, col * 100:(col + 1) * 100] = block.reshape(100, 100)
    return imaged, corr


def test_wall_is_rated_by_its_worst_area_never_the_average():
    # GIVEN two clean areas and one at 25 % breakdown (average 8.3 %: FAIR)
    imaged, corr = _grid({0: 0.0, 1: 0.0, 2: 25.0})
    r = rate_wall(imaged, corr, np.zeros_like(corr), origin_uv_m=(0.0, 1.0), cell_m=0.01, params=RatingParams())
    # THEN the wall is POOR, set by the third area, and provisional (edges not assessed)
    assert [a.rating for a in r.areas] == [GOOD, GOOD, POOR]
    assert r.rating == POOR and r.worst_area == "A3" and r.provisional
    assert r.areas[2].breakdown_pct == pytest.approx(25.0, abs=0.01)
    assert r.areas[2].u0_m == pytest.approx(2.0) and r.areas[2].v1_m == pytest.approx(1.0)


def test_measured_edges_make_the_rating_final_and_unimaged_areas_are_not_rated():
    imaged, corr = _grid({0: 5.0})
    imaged[:, 100:] = False
    r = rate_wall(imaged, corr, np.zeros_like(corr), origin_uv_m=(0.0, 1.0), cell_m=0.01,
                  params=RatingParams(edges_welds_pct=10.0))
    assert [a.rating for a in r.areas] == [FAIR, NOT_RATED, NOT_RATED]
    assert r.rating == FAIR and not r.provisional


def test_hard_rust_scale_of_ten_percent_is_poor():
    imaged, corr = _grid({0: 12.0})
    hard = corr.copy()
    r = rate_wall(imaged[:, :100], corr[:, :100], hard[:, :100], origin_uv_m=(0.0, 1.0), cell_m=0.01)
    assert r.areas[0].hard_rust_pct == pytest.approx(12.0, abs=0.01) and r.rating == POOR


def test_plate_fields_and_condition_states():
    # GIVEN a 2 m x 2 m wall on a 1 cm grid, fully imaged, frames at u = 0.5 and 1.3 m, and corrosion
    # in the field Fr. 141-142 (u 0.5-1.3): 10 % of it, half fair and half severe
    from inspect_pipe.report._rating import RatingParams, rate_wall

    n = 200
    imaged = np.ones((n, n), bool)
    corr = np.zeros((n, n), bool)
    sev = np.zeros((n, n), np.uint8)
    corr[150:166, 50:130] = True  # rows 150..165 (v 0.34-0.50 m), u 0.50-1.30 m: 16 x 80 cells
    sev[150:158, 50:130] = 1
    sev[158:166, 50:130] = 3
    hard = corr & (sev >= 2)
    edges = [(0.5, "Fr. 141-142"), (1.3, "Fr. 142-143")]
    r = rate_wall(imaged, corr, hard, origin_uv_m=(0.0, 2.0), cell_m=0.01, params=RatingParams(area_size_m=1.0),
                  severity=np.where(corr, sev, 0), u_edges_m=edges)
    # THEN areas are the plate fields between frames (3 columns: before 0.5, 0.5-1.3, 1.3-2.0) in 1 m bands
    names = {(a.label, round(a.v0_m, 2)) for a in r.areas}
    assert ("Fr. 141-142", 0.0) in names and ("Fr. 142-143", 1.0) in names and len(r.areas) == 6
    field = next(a for a in r.areas if a.label == "Fr. 141-142" and a.v0_m < 0.5)
    assert field.u0_m == pytest.approx(0.5) and field.u1_m == pytest.approx(1.3)
    area_cells = 80 * 100
    assert field.breakdown_pct == pytest.approx(100 * 16 * 80 / area_cells)
    assert field.severity_pct["fair"] == pytest.approx(100 * 8 * 80 / area_cells)
    assert field.severity_pct["severe"] == pytest.approx(100 * 8 * 80 / area_cells) and field.severity_pct["poor"] == 0
    # hard rust (severe) 8 % < 10 %, breakdown 16 % <= 20 %: FAIR; the field beside it is GOOD
    assert field.rating == "FAIR"
    assert next(a for a in r.areas if a.label == "Fr. 142-143" and a.v0_m < 0.5).rating == "GOOD"


def test_a_corrosion_entry_takes_the_state_of_most_of_its_pixels():
    from inspect_pipe.report._register import Defect
    from inspect_pipe.report._report import entry_severity

    sev = np.zeros((50, 50), np.uint8)
    sev[10:30, 10:20] = 1  # fair: 200 px
    sev[10:30, 20:35] = 3  # severe: 300 px
    poly = ((10, 10), (34, 10), (34, 29), (10, 29))
    d = Defect("D001", "corrosion", ((0, 0),), (0.0, 0.0), (0, 0, 0, 0), 0.01, None, 0.9, (), (), (), poly, (10, 10, 25, 20), 500)
    s = entry_severity(d, sev)
    assert s["state"] == "severe"
    assert s["fractions"] == {"fair": 0.4, "poor": 0.0, "severe": 0.6}


@pytest.mark.parametrize("hard_cells, expected", [(2, GOOD), (4, GOOD), (6, FAIR), (50, FAIR)])
def test_hard_rust_that_rounds_to_zero_counts_as_none(hard_cells, expected):
    # GIVEN a 1 m area (10,000 cells of 1 cm) with 1 % breakdown, of which a few cells are hard rust
    imaged, corr = _grid({0: 1.0})
    hard = np.zeros_like(corr)
    hard.flat[np.flatnonzero(corr[:, :100].ravel())[:hard_cells]] = True  # cells inside the corrosion
    r = rate_wall(imaged[:, :100], corr[:, :100], hard[:, :100], origin_uv_m=(0.0, 1.0), cell_m=0.01)
    # THEN the figure is kept as measured, and under 0.05 % (shown as 0.0) it does not make the area FAIR
    assert r.areas[0].hard_rust_pct == pytest.approx(hard_cells / 100, abs=1e-9)
    assert r.areas[0].rating == expected
