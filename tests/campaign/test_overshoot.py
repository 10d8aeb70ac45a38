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
CASES = [
    (1, 16, "campaign_oblique_wall_e16.yaml", 0.291, 0.10),
    (1, 916, "campaign_s1_e00916_push_yaw.yaml", 0.209, 0.10),
    (1, 1804, "campaign_s1_e01804_push_yaw.yaml", 0.188, 0.10),
]


@pytest.mark.parametrize("seed,index,fname,before,bound", CASES, ids=[c[2] for c in CASES])
def test_regression_file_is_the_campaign_episode(seed, index, fname, before, bound):
    doc = yaml.safe_load((REGRESSIONS / fname).read_text())
    gen = dict(generate_episode(seed, index).doc)
    assert {k: v for k, v in doc.items() if k != "name"} == {k: v for k, v in gen.items() if k != "name"}


@pytest.mark.parametrize("seed,index,fname,before,bound", CASES, ids=[c[2] for c in CASES])
def test_push_while_yawing_overshoots_less(seed, index, fname, before, bound):
    # GIVEN a forward push held while yawing, the front wall heard ever more obliquely WHEN ours
    # flies it THEN the remembered face-on wall stops the forward motion at the 1 m line (goal 0.10)
    r = fly_episode(generate_episode(seed, index), "ours")
    assert not r.collided
    assert r.overshoot_m is not None and r.overshoot_m <= bound < before
