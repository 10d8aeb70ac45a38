"""Failures the campaign found, kept as scenarios: each is the campaign episode its header
names, and each must now fly without a collision."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from inspect_pipe.campaign.generator import generate_episode
from inspect_pipe.flight import load_scenario, run_scenario

REGRESSIONS = sorted((Path(__file__).resolve().parents[2] / "scenarios" / "regressions").glob("*.yaml"))


@pytest.mark.parametrize("path", REGRESSIONS, ids=lambda p: p.stem)
def test_regression_scenario_flies_without_collision(path):
    # GIVEN a campaign episode that used to collide WHEN ours flies it THEN no collision
    res = run_scenario(load_scenario(path))
    assert res.status.value == "completed", f"collision at {res.collided_at_s}"


@pytest.mark.parametrize("path", REGRESSIONS, ids=lambda p: p.stem)
def test_regression_file_is_the_campaign_episode_its_header_names(path):
    # GIVEN the header "# Campaign seed S, episode I ..." WHEN the generator makes that episode
    # THEN the file is exactly it (the name aside): the regression replays what the campaign flew
    text = path.read_text()
    m = re.match(r"# Campaign seed (\d+), episode (\d+)", text)
    assert m, f"{path.name}: no '# Campaign seed S, episode I' header"
    gen = dict(generate_episode(int(m[1]), int(m[2])).doc)
    doc = yaml.safe_load(text)
    assert {k: v for k, v in doc.items() if k != "name"} == {k: v for k, v in gen.items() if k != "name"}


def test_there_are_regressions():
    assert len(REGRESSIONS) >= 2
