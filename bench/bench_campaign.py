"""Flight safety campaign benchmark: the 200-episode subset (seed 1), ours against PX4-like and
ArduPilot-like avoidance on identical episodes.

    python -m bench --only campaign
"""

from __future__ import annotations

import io
import os
import tempfile
from pathlib import Path

from inspect_pipe.campaign import CampaignConfig, run_campaign
from inspect_pipe.campaign.report import METRIC_ROWS as _ROWS
from inspect_pipe.campaign.report import fmt as _f

EPISODES = 200
SEED = 1


def run(data: Path) -> str:  # data: unused, the episodes are generated
    workers = min(2, os.cpu_count() or 1)
    with tempfile.TemporaryDirectory() as tmp:
        s = run_campaign(CampaignConfig(episodes=EPISODES, seed=SEED, out=Path(tmp), workers=workers, report=False))
    sh = s["shields"]
    names = list(sh)
    out = io.StringIO()
    out.write("## Flight safety campaign (200-episode subset)\n\n")
    out.write(
        f"`inspect-pipe campaign --episodes {EPISODES} --seed {SEED}`: {EPISODES} generated hold flights, each flown "
        f"by every shield on the same vehicle, sensors, operator script and faults; {workers} worker processes, "
        f"{s['elapsed_s']} s wall time for {sum(v['sim_time_s'] for v in sh.values()) / 60:.0f} simulated minutes.\n\n"
    )
    out.write("| metric | " + " | ".join(names) + " |\n|---|" + "---:|" * len(names) + "\n")
    for key, label in _ROWS:
        out.write(f"| {label} | " + " | ".join(_f(sh[n].get(key)) for n in names) + " |\n")
    for subset in ("clean", "dropout", "link_loss", "gust", "model_error"):
        cells = [sh[n]["subsets"].get(subset) for n in names]
        if any(cells):
            ep = next(c["episodes"] for c in cells if c)
            out.write(f"| collision-free, {subset} subset ({ep} episodes) | " + " | ".join(_f(c["collision_free"]) if c else "-" for c in cells) + " |\n")
    out.write("\nGoals for ours: " + "; ".join(
        f"{k} {'not measured' if v.get('met') is None else 'met' if v['met'] else 'NOT met'} ({_f(v.get('value'))})" for k, v in s["goals"].items()
    ) + ".\n")
    return out.getvalue()
