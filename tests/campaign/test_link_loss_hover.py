"""Link loss: waiting_for_connectivity must make the vehicle hover within 0.3 s (the issue's goal),
also when the link drops while the vehicle is held at a wall. Campaign episodes kept as
scenarios in ``scenarios/regressions/`` and flown with the campaign's own metrics."""

from __future__ import annotations

from pathlib import Path

import pytest

from inspect_pipe.campaign.generator import generate_episode
from inspect_pipe.campaign.run import fly_episode

REGRESSIONS = Path(__file__).resolve().parents[2] / "scenarios" / "regressions"

# (campaign seed, episode, regression file)
CASES = [(1, 89, "campaign_link_loss_hover_e89.yaml")]


@pytest.mark.parametrize("seed,index,fname", CASES, ids=[c[2] for c in CASES])
def test_link_loss_at_the_wall_hovers_within_0_3_s(seed, index, fname):
    assert (REGRESSIONS / fname).is_file()  # the episode kept as a scenario (test_regressions checks it)
    # GIVEN the episode whose link loss came 2.02 s before a zero horizontal command
    # WHEN ours flies it THEN hover starts within 0.3 s and drifts less than 0.3 m
    r = fly_episode(generate_episode(seed, index, honest_faults=False), "ours")
    assert not r.collided
    assert r.link_hover_s, "the link loss was not measured"
    assert max(r.link_hover_s) <= 0.3
    assert max(r.link_drift_m) <= 0.3


# (campaign seed, episode, regression file, drift before the fix)
DRIFT_CASES = [
    (1, 927, "campaign_s1_e00927_wall_push.yaml", 0.863),  # bottom flow stuck during the loss
    (1, 627, "campaign_s1_e00627_wall_push.yaml", 0.452),  # bottom flow stuck during the loss
    (1, 170, "campaign_s1_e00170_wall_push.yaml", 0.418),  # loss while braking from 0.8 m/s
    # every range sensor lost during the loss: braking (the lagging range rate was the speed),
    # at rest (the last noisy flow reading was carried on)
    # (on the honest simulator 0.39 m, open until the vertical reference model and trim-only
    # hand-over of issue 19's session 8: 0.26 m; not analysed why the vertical loop's change helps)
    (1, 1007, "campaign_s1_e01007_inspection_sweep.yaml", 0.389),
    (1, 1367, "campaign_s1_e01367_corner_push.yaml", 0.351),
]


@pytest.mark.parametrize("seed,index,fname,before", DRIFT_CASES, ids=[(c.values if hasattr(c, "values") else c)[2] for c in DRIFT_CASES])
def test_link_loss_hover_drifts_less_than_0_3_m(seed, index, fname, before):
    assert (REGRESSIONS / fname).is_file()  # the episode kept as a scenario (test_regressions checks it)
    # GIVEN a link loss with a stuck bottom flow, or while braking at a wall WHEN ours flies it
    # THEN, once at rest, the vehicle stays within 0.3 m (the goal) until the link is back
    r = fly_episode(generate_episode(seed, index, honest_faults=False), "ours")
    assert not r.collided
    assert r.link_drift_m and max(r.link_drift_m) <= 0.3 < before


# Episodes of the honest simulator's fault classes (the generator's current faults)
HONEST_DRIFT_CASES = [
    # every range sensor lost under vibration during the loss: the hold chased the IMU's dead reckoning (alarm mode -2)
    (263, 226, "campaign_s263_e00226_corner_push.yaml", 0.331),
    # a flow glitch the x observer refused drove the front range's rate, then the observer, then the station keeping
    (11, 428, "campaign_s11_e00428_wall_push.yaml", 0.312),
    # a 9.5 s hold 3 m over a floor of low texture, no wall in the sonars' range: the bottom flow's quality
    # about 26, refused below 40 five readings in six, the rest too few to hold the IMU's drift
    (315, 94, "campaign_s315_e00094_passage.yaml", 0.414),
]


@pytest.mark.parametrize("seed,index,fname,before", HONEST_DRIFT_CASES, ids=[c[2] for c in HONEST_DRIFT_CASES])
def test_link_loss_hover_does_not_chase_a_speed_nothing_measured(seed, index, fname, before):
    assert (REGRESSIONS / fname).is_file()
    # GIVEN a link loss during which the speed estimate leaves the truth: dead reckoning under vibration (alarm mode),
    # or a flow glitch the observer refused that still reached it through the front range, or a floor of low texture
    # WHEN ours flies it THEN the station keeping holds the vehicle within 0.25 m (goal 0.3)
    r = fly_episode(generate_episode(seed, index), "ours")
    assert not r.collided
    assert r.link_drift_m and max(r.link_drift_m) <= 0.25 < before, r.link_drift_m
