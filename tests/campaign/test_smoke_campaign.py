"""A small safety campaign whose seed is the date (UTC, YYYYMMDD): a different seed every day, so
no change can be tuned to it (issue 19, item 4). A failure names its seed; replay it with
``INSPECT_PIPE_SMOKE_SEED=<seed>`` (and keep the episode as a regression scenario)."""

from __future__ import annotations

import datetime
import os

from inspect_pipe.campaign import CampaignConfig, run_campaign

EPISODES = 20
# Seeds used while tuning the stack and the simulator (docs/campaign.md lists them); the date
# seeds (2020xxxx and later) can never collide with them.
TUNING_SEEDS = frozenset(range(1, 10)) | {11, 12, 41}


def smoke_seed() -> int:
    env = os.environ.get("INSPECT_PIPE_SMOKE_SEED")
    if env:
        return int(env)
    return int(datetime.datetime.now(datetime.timezone.utc).strftime("%Y%m%d"))


def test_date_seeded_smoke_campaign(tmp_path):
    seed = smoke_seed()
    assert seed not in TUNING_SEEDS
    # GIVEN 20 fresh episodes (every fault class, ours only) WHEN flown
    summary = run_campaign(
        CampaignConfig(episodes=EPISODES, seed=seed, out=tmp_path, workers=1, shields=("ours",), report=False)
    )
    ours = summary["shields"]["ours"]
    where = f"smoke campaign seed {seed}: {ours['collided_episodes']} collided"
    # THEN at most one of 20 collides (the 2,000-episode goal is 99.9 %: a second collision in 20
    # episodes would be very unlikely at that rate)
    assert ours["collision_free"] >= 0.95, where
    # AND a link loss hovers within 0.3 s and drifts at most 0.3 m while the link is down (goals)
    if ours["link_loss_hover_s_max"] is not None:
        assert ours["link_loss_hover_s_max"] <= 0.3, where
    if ours["link_loss_drift_m_max"] is not None:
        assert ours["link_loss_drift_m_max"] <= 0.3, where
    # AND no stop overshoots the line by more than 0.10 m (the goal; not met on every fresh seed:
    # 0.135 m in 2,000 episodes of seed 47, a blind drift while every range sensor is lost at a
    # wall, docs/campaign.md: on such a date this test fails and names its seed, as it should)
    if ours["overshoot_max_m"] is not None:
        assert ours["overshoot_max_m"] <= 0.10, where
