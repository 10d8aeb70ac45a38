"""Failures the campaign found, kept as scenarios: each must now fly without a collision."""

from __future__ import annotations

from pathlib import Path

import pytest

from inspect_pipe.flight import load_scenario, run_scenario

REGRESSIONS = sorted((Path(__file__).resolve().parents[2] / "scenarios" / "regressions").glob("*.yaml"))


@pytest.mark.parametrize("path", REGRESSIONS, ids=lambda p: p.stem)
def test_regression_scenario_flies_without_collision(path):
    # GIVEN a campaign episode that used to collide WHEN ours flies it THEN no collision
    res = run_scenario(load_scenario(path))
    assert res.status.value == "completed", f"collision at {res.collided_at_s}"


def test_there_are_regressions():
    assert len(REGRESSIONS) >= 2
