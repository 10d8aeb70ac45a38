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
