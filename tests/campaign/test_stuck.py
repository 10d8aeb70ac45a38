"""Stuck episodes: an escape the operator asked for (away from the wall it was pushed at) must
make progress. Campaign episodes kept as scenarios in ``scenarios/regressions/``, flown with the
campaign's own metrics."""

from __future__ import annotations

from pathlib import Path

import pytest

from inspect_pipe.campaign.generator import generate_episode
from inspect_pipe.campaign.run import fly_episode

REGRESSIONS = Path(__file__).resolve().parents[2] / "scenarios" / "regressions"

# (campaign seed, episode, regression file, honest simulator)
CASES = [
    (1, 182, "campaign_weak_thrust_stuck_e182.yaml", False),
    (1, 15, "campaign_escape_from_wall_e15.yaml", False),
    # braking face-on into a corner, the lagging range rate read as an oblique wall across it (fresh seed 113)
    (113, 1814, "campaign_s113_e01814_wall_push.yaml", True),
]


@pytest.mark.parametrize("seed,index,fname,honest", CASES, ids=[c[2] for c in CASES])
def test_escape_from_the_wall_makes_progress(seed, index, fname, honest):
    assert (REGRESSIONS / fname).is_file()  # the episode kept as a scenario (test_regressions checks it)
    r = fly_episode(generate_episode(seed, index, honest_faults=honest), "ours")
    assert not r.collided
    assert r.escapes_blocked == 0  # the escape is possible, so "not stuck" is a real verdict
    assert not r.stuck
    assert r.min_clearance_m > 0.3  # and it flew: a vehicle on the floor has no clearance figure
