"""Overshoot past the 1 m stop line when the wall is oblique to the sonars (push while yawing):
campaign episodes kept as scenarios in ``scenarios/regressions/``, flown with the campaign's
own metrics."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from inspect_pipe.campaign.generator import generate_episode
from inspect_pipe.campaign.run import fly_episode

REGRESSIONS = Path(__file__).resolve().parents[2] / "scenarios" / "regressions"

# (campaign seed, episode, regression file, overshoot before the fix, bound now)
CASES = [(1, 16, "campaign_oblique_wall_e16.yaml", 0.291, 0.2)]


@pytest.mark.parametrize("seed,index,fname,before,bound", CASES, ids=[c[2] for c in CASES])
def test_regression_file_is_the_campaign_episode(seed, index, fname, before, bound):
    doc = yaml.safe_load((REGRESSIONS / fname).read_text())
    gen = dict(generate_episode(seed, index).doc)
    assert {k: v for k, v in doc.items() if k != "name"} == {k: v for k, v in gen.items() if k != "name"}


@pytest.mark.parametrize("seed,index,fname,before,bound", CASES, ids=[c[2] for c in CASES])
def test_push_while_yawing_overshoots_less(seed, index, fname, before, bound):
    # GIVEN a forward push held while yawing, the front wall seen ever more obliquely by the left
    # sonar WHEN ours flies it THEN the closing of that sonar's range stops the forward motion
    r = fly_episode(generate_episode(seed, index), "ours")
    assert not r.collided
    assert r.overshoot_m is not None and r.overshoot_m <= bound < before
