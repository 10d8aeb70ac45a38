"""Stuck episodes: an escape the operator asked for (away from the wall it was pushed at) must
make progress. Campaign episodes kept as scenarios in ``scenarios/regressions/``, flown with the
campaign's own metrics."""

from __future__ import annotations

from pathlib import Path

import pytest

from inspect_pipe.campaign.generator import generate_episode
from inspect_pipe.campaign.run import fly_episode

REGRESSIONS = Path(__file__).resolve().parents[2] / "scenarios" / "regressions"

# (campaign seed, episode, regression file)
CASES = [(1, 182, "campaign_weak_thrust_stuck_e182.yaml"), (1, 15, "campaign_escape_from_wall_e15.yaml")]


@pytest.mark.parametrize("seed,index,fname", CASES, ids=[c[2] for c in CASES])
def test_escape_from_the_wall_makes_progress(seed, index, fname):
    assert (REGRESSIONS / fname).is_file()  # the episode kept as a scenario (test_regressions checks it)
    r = fly_episode(generate_episode(seed, index, honest_faults=False), "ours")
    assert not r.collided
    assert r.escapes_blocked == 0  # the escape is possible, so "not stuck" is a real verdict
    assert not r.stuck
    assert r.min_clearance_m > 0.3  # and it flew: a vehicle on the floor has no clearance figure
