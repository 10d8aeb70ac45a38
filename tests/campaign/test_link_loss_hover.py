"""Link loss: waiting_for_connectivity must make the vehicle hover within 0.3 s (the issue's goal),
also when the link drops while the vehicle is held at a wall. Campaign episodes kept as
scenarios in ``scenarios/regressions/`` and flown with the campaign's own metrics."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from inspect_pipe.campaign.generator import generate_episode
from inspect_pipe.campaign.run import fly_episode

REGRESSIONS = Path(__file__).resolve().parents[2] / "scenarios" / "regressions"

# (campaign seed, episode, regression file)
CASES = [(1, 89, "campaign_link_loss_hover_e89.yaml")]


@pytest.mark.parametrize("seed,index,fname", CASES, ids=[c[2] for c in CASES])
def test_regression_file_is_the_campaign_episode(seed, index, fname):
    doc = yaml.safe_load((REGRESSIONS / fname).read_text())
    gen = dict(generate_episode(seed, index).doc)
    assert {k: v for k, v in doc.items() if k != "name"} == {k: v for k, v in gen.items() if k != "name"}


@pytest.mark.parametrize("seed,index,fname", CASES, ids=[c[2] for c in CASES])
def test_link_loss_at_the_wall_hovers_within_0_3_s(seed, index, fname):
    # GIVEN the episode whose link loss came 2.02 s before a zero horizontal command
    # WHEN ours flies it THEN hover starts within 0.3 s and drifts less than 0.3 m
    r = fly_episode(generate_episode(seed, index), "ours")
    assert not r.collided
    assert r.link_hover_s, "the link loss was not measured"
    assert max(r.link_hover_s) <= 0.3
    assert max(r.link_drift_m) <= 0.3
