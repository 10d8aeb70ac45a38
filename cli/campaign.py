"""``inspect-pipe campaign``: randomized flight safety campaign, ours against PX4- and
ArduPilot-style avoidance on identical episodes; or replay one failure scenario."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from cli._common import StageProgress, choices, one_line_errors
from inspect_pipe.errors import InputError

HELP = (
    "Randomized flight safety campaign: N seeded hold flights (holds, boxes, passages, operator "
    "pushes and sweeps, sensor/link/battery/wind/model faults), each flown by our behaviour "
    "arbitration and by PX4-like and ArduPilot-like avoidance. Writes OUT/summary.json, "
    "OUT/episodes.jsonl, OUT/failures/ (a replayable scenario per collision) and OUT/report.html.\n\n"
    "Examples:\n\n"
    "  inspect-pipe campaign --episodes 200 --seed 1 -o out/campaign\n\n"
    "  inspect-pipe campaign --episodes 2000 --seed 1 -o out/campaign_full --workers 2\n\n"
    "  inspect-pipe campaign --replay out/campaign/failures/X__px4_like.yaml --shield px4_like"
)

Shield = choices("Shield", ("ours", "px4_like", "ardupilot_like"))  # inspect_pipe.campaign.SHIELDS (a test checks)


@one_line_errors
def campaign(
    episodes: Annotated[int, typer.Option("--episodes", help="number of episodes")] = 200,
    seed: Annotated[int, typer.Option("--seed", help="campaign seed (episode i depends on seed and i only)")] = 1,
    out: Annotated[Optional[Path], typer.Option("-o", "--out", help="output directory")] = None,
    workers: Annotated[int, typer.Option("--workers", help="worker processes")] = 2,
    shields: Annotated[str, typer.Option("--shields", help="comma-separated: ours,px4_like,ardupilot_like")] = "ours,px4_like,ardupilot_like",
    no_report: Annotated[bool, typer.Option("--no-report", help="skip report.html and its plots")] = False,
    replay: Annotated[Optional[Path], typer.Option("--replay", help="fly one scenario file with --shield and exit 1 on a collision")] = None,
    shield: Annotated[Shield, typer.Option("--shield", help="with --replay: the shield to fly")] = Shield.ours,
) -> None:
    """Run the flight safety campaign."""
    from inspect_pipe.campaign import SHIELDS, CampaignConfig, fly_scenario, run_campaign
    from inspect_pipe.flight import ExitStatus, load_scenario

    if replay is not None:
        shield = shield.value
        sc = load_scenario(replay)
        res = fly_scenario(sc, shield)
        typer.echo(f"{sc.name} [{shield}]: {res.status.value}, {res.final_fsm.value} after {res.sim_time_s:.2f} s")
        if res.status is ExitStatus.COLLISION:
            typer.echo(f"collision at t={res.collided_at_s:.2f} s", err=True)
            raise typer.Exit(1)
        return
    if out is None:
        raise InputError("-o", "missing", "give the output directory with -o OUT")
    names = tuple(s.strip() for s in shields.split(",") if s.strip())
    if not names:
        raise InputError("--shields", "is empty", "one or more of " + ", ".join(SHIELDS))
    cfg = CampaignConfig(episodes=episodes, seed=seed, out=out, workers=workers, shields=names, report=not no_report).check()

    bar = StageProgress("campaign")
    try:
        summary = run_campaign(cfg, lambda done, total: bar("episodes", done, total))
    finally:
        bar.close()
    for name, s in summary["shields"].items():
        typer.echo(
            f"{name:15s} collision-free {s['collision_free']:.4f}  min clearance p0.1 {s['min_clearance_p001_m']} m  "
            f"overshoot max {s['overshoot_max_m']} m  stuck {s['stuck_episodes']}  link-loss hover max {s['link_loss_hover_s_max']} s"
        )
    typer.echo(f"{episodes} episodes in {summary['elapsed_s']} s; {out / 'summary.json'}")
