"""Flight safety campaign: seeded randomized hold flights, each flown by our behaviour
arbitration and by PX4- and ArduPilot-style avoidance shields on the same vehicle, sensors,
operator scripts and faults (docs/campaign.md)."""

from inspect_pipe.campaign.generator import EpisodeSpec, Escape, generate_episode
from inspect_pipe.campaign.metrics import EpisodeMonitor, EpisodeResult, aggregate
from inspect_pipe.campaign.run import CampaignConfig, fly_episode, fly_scenario, run_campaign, write_failure
from inspect_pipe.campaign.shields import (
    SHIELDS,
    ArduPilotLikeParams,
    ArduPilotLikeShield,
    Px4LikeParams,
    Px4LikeShield,
    ShieldedStack,
    make_stack,
)

__all__ = [
    "ArduPilotLikeParams",
    "ArduPilotLikeShield",
    "CampaignConfig",
    "EpisodeMonitor",
    "EpisodeResult",
    "EpisodeSpec",
    "Escape",
    "Px4LikeParams",
    "Px4LikeShield",
    "SHIELDS",
    "ShieldedStack",
    "aggregate",
    "fly_episode",
    "fly_scenario",
    "generate_episode",
    "make_stack",
    "run_campaign",
    "write_failure",
]
