"""Run a campaign: every episode flown once per shield, in worker processes; summary, failures
and the per-episode results written to the output directory."""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import yaml

from inspect_pipe.campaign.generator import EpisodeSpec, generate_episode
from inspect_pipe.campaign.metrics import EpisodeMonitor, EpisodeResult, aggregate
from inspect_pipe.campaign.shields import SHIELDS, make_stack
from inspect_pipe.errors import InputError
from inspect_pipe.flight.runner import FlightResult, TickRecord, run_scenario
from inspect_pipe.flight.scenario import Scenario

__all__ = ["CampaignConfig", "FORMAT", "fly_episode", "fly_scenario", "run_campaign", "write_failure"]

FORMAT = "inspect_pipe.campaign_summary/1"
GOALS = {
    "collision_free_min": 0.999,
    "overshoot_max_m": 0.10,
    "link_loss_hover_s_max": 0.3,
    "link_loss_drift_m_max": 0.3,
    "stuck_episodes": 0,
}


#: Largest campaign one command runs (a million episodes x 3 shields is a week of one core).
MAX_EPISODES = 1_000_000
#: Most worker processes (each one flies whole episodes on one core).
MAX_WORKERS = 256


@dataclass(frozen=True)
class CampaignConfig:
    episodes: int
    seed: int
    out: Path
    workers: int = 2
    shields: tuple[str, ...] = SHIELDS
    report: bool = True

    def check(self) -> "CampaignConfig":
        if not 1 <= self.episodes <= MAX_EPISODES:
            raise InputError("--episodes", f"is {self.episodes}", f"1 to {MAX_EPISODES:,}; each takes about 3 s of CPU")
        if self.seed < 0:
            raise InputError("--seed", f"is {self.seed}", "an integer >= 0")
        if not 1 <= self.workers <= MAX_WORKERS:
            raise InputError("--workers", f"is {self.workers}", f"1 to {MAX_WORKERS}, one per core; this machine has {os.cpu_count()}")
        for s in self.shields:
            if s not in SHIELDS:
                raise InputError("--shields", f"unknown shield {s!r}", "one of " + ", ".join(SHIELDS))
        if self.out.exists() and not self.out.is_dir():
            raise InputError(str(self.out), "exists and is not a directory", "give a directory for the campaign output")
        return self


def fly_scenario(scenario: Scenario, shield: str, on_tick: Callable[[TickRecord], None] | None = None) -> FlightResult:
    """Fly one scenario with the given shield in place of the behaviour arbitration."""
    return run_scenario(scenario, on_tick=on_tick, make_stack=make_stack(shield))


def fly_episode(spec: EpisodeSpec, shield: str, on_tick: Callable[[TickRecord], None] | None = None) -> EpisodeResult:
    sc = spec.scenario()
    mon = EpisodeMonitor(spec, sc, shield)
    cb = mon if on_tick is None else (lambda rec: (mon(rec), on_tick(rec)))
    t0 = time.process_time()
    fly_scenario(sc, shield, cb)
    return mon.finish(time.process_time() - t0)


def _work(job: tuple[int, int, tuple[str, ...]]) -> tuple[int, list[EpisodeResult]]:
    seed, index, shields = job
    spec = generate_episode(seed, index)
    return index, [fly_episode(spec, s) for s in shields]


def write_failure(spec: EpisodeSpec, shield: str, result: EpisodeResult, folder: Path) -> Path:
    """The episode's scenario file, replayable with ``inspect-pipe fly`` (ours) or
    ``inspect-pipe campaign --replay FILE --shield NAME``."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{spec.name}__{shield}.yaml"
    header = (
        f"# Campaign seed {spec.seed}, episode {spec.index} ({spec.kind}); shield {shield} collided at "
        f"t={result.collided_at_s:.2f} s.\n"
        f"# Replay: inspect-pipe campaign --replay {path.name} --shield {shield}"
        + ("  (or: inspect-pipe fly --scenario " + path.name + " --log LOG)" if shield == "ours" else "")
        + "\n"
    )
    path.write_text(header + yaml.safe_dump(spec.doc, sort_keys=False, default_flow_style=None, width=120))
    return path


def run_campaign(cfg: CampaignConfig, progress: Callable[[int, int], None] | None = None) -> dict:
    cfg.check()
    out = cfg.out
    out.mkdir(parents=True, exist_ok=True)
    jobs = [(cfg.seed, i, cfg.shields) for i in range(cfg.episodes)]
    results: dict[int, list[EpisodeResult]] = {}
    t0 = time.perf_counter()
    if cfg.workers == 1:
        for k, job in enumerate(jobs):
            i, rs = _work(job)
            results[i] = rs
            if progress:
                progress(k + 1, len(jobs))
    else:
        ctx = mp.get_context("fork" if hasattr(os, "fork") else "spawn")
        with ctx.Pool(min(cfg.workers, cfg.episodes)) as pool:
            for k, (i, rs) in enumerate(pool.imap_unordered(_work, jobs, chunksize=2)):
                results[i] = rs
                if progress:
                    progress(k + 1, len(jobs))
    elapsed = time.perf_counter() - t0
    per_shield: dict[str, list[EpisodeResult]] = {s: [] for s in cfg.shields}
    for i in sorted(results):
        for r in results[i]:
            per_shield[r.shield].append(r)

    failures = out / "failures"
    written = []
    for s, rs in per_shield.items():
        for r in rs:
            if r.collided:
                written.append(str(write_failure(generate_episode(cfg.seed, r.index), s, r, failures).relative_to(out)))
    with (out / "episodes.jsonl").open("w") as fh:
        for s, rs in per_shield.items():
            for r in rs:
                fh.write(json.dumps(r.to_json(), separators=(",", ":")) + "\n")
    shields = {s: aggregate(rs) for s, rs in per_shield.items()}
    summary = {
        "format": FORMAT,
        "episodes": cfg.episodes,
        "seed": cfg.seed,
        "workers": cfg.workers,
        "elapsed_s": round(elapsed, 1),
        "shields": shields,
        "failures": written,
        "goals": _goals(shields),
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    if cfg.report:
        from inspect_pipe.campaign.report import write_report

        write_report(summary, per_shield, out)
    return summary


def _goals(shields: dict) -> dict:
    ours = shields.get("ours")
    if ours is None:
        return {}
    g: dict = {
        "collision_free": {"goal": GOALS["collision_free_min"], "value": ours["collision_free"]},
        "overshoot_max_m": {"goal": GOALS["overshoot_max_m"], "value": ours["overshoot_max_m"]},
        "link_loss_hover_s_max": {"goal": GOALS["link_loss_hover_s_max"], "value": ours["link_loss_hover_s_max"]},
        "link_loss_drift_m_max": {"goal": GOALS["link_loss_drift_m_max"], "value": ours["link_loss_drift_m_max"]},
        "stuck_episodes": {"goal": GOALS["stuck_episodes"], "value": ours["stuck_episodes"]},
    }
    g["collision_free"]["met"] = ours["collision_free"] is not None and ours["collision_free"] >= GOALS["collision_free_min"]
    for k in ("overshoot_max_m", "link_loss_hover_s_max", "link_loss_drift_m_max"):
        v = g[k]["value"]
        g[k]["met"] = v is None or v <= g[k]["goal"]
    g["stuck_episodes"]["met"] = ours["stuck_episodes"] == 0
    for subset in ("dropout", "link_loss"):
        ours_cf = ours["subsets"].get(subset, {}).get("collision_free")
        others = [shields[s]["subsets"].get(subset, {}).get("collision_free") for s in shields if s != "ours"]
        others = [o for o in others if o is not None]
        g[f"ahead_on_{subset}"] = {
            "value": ours_cf, "baselines": others,
            # None: no baseline was flown (``--shields ours``), so "ahead" is not measured
            # Ahead of each baseline: strictly more collision-free, except at 1.0 (nothing is
            # ahead of no collision at all). A tie with one baseline is not "ahead of both".
            "met": None if not others else (
                ours_cf is not None and all(ours_cf > o or ours_cf == 1.0 for o in others)
            ),
        }
    return g
