"""``OUT/report.html``: the summary table per shield and PNG plots (matplotlib, Agg)."""

from __future__ import annotations

import html
import math
from pathlib import Path

from inspect_pipe.campaign.metrics import EpisodeResult

__all__ = ["METRIC_ROWS", "fmt", "write_report"]

METRIC_ROWS = (  # (summary key, label): the table of report.html and of the benchmark
    ("collision_free", "collision-free share"),
    ("collisions", "collisions"),
    ("min_clearance_p001_m", "min clearance from rotor envelope, p0.1 (m)"),
    ("min_clearance_median_m", "min clearance from rotor envelope, median (m)"),
    ("overshoot_max_m", "overshoot past the 1 m stop line, max (m)"),
    ("overshoot_p99_m", "overshoot past the 1 m stop line, p99 (m)"),
    ("lateral_entry_max_m", "surface met inside the line sliding past its end, max depth (m)"),
    ("lateral_entry_episodes", "episodes meeting a surface inside the line"),
    ("dither_changes_per_10s_max", "dithering at the wall, max sign changes / 10 s"),
    ("stuck_episodes", "episodes stuck in corners"),
    ("escapes_blocked", "scripted escapes the geometry does not allow (not judged)"),
    ("stale_block_s_max", "time to block a stale sector, max (s)"),
    ("stale_unblocked", "stale-sector pushes never blocked"),
    ("link_loss_hover_s_max", "hover after link loss (the push no longer obeyed), max (s)"),
    ("link_loss_still_s_max", "link loss until no horizontal command at all, max (s)"),
    ("link_loss_brake_m_max", "braking after the link-loss hover command, max (m)"),
    ("link_loss_drift_m_max", "drift while hovering during link loss (<= 10 s), max (m)"),
    ("altitude_excursion_m_max", "altitude excursion over floor steps, max (m)"),
    ("false_landed", "false 'landed' in the air"),
)


def _verdict(met: bool | None) -> str:
    return "not measured (no baseline flown)" if met is None else ("met" if met else "NOT met")


def fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def write_report(summary: dict, per_shield: dict[str, list[EpisodeResult]], out: Path) -> Path:
    shields = list(summary["shields"])
    plots: list[tuple[str, str]] = []
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # the [campaign] extra is not installed: table only
        return _write_html(summary, shields, plots, out, note="matplotlib not installed (pip install '.[campaign]'): no plots")
    # 1. collision-free share per subset
    subsets = sorted({k for s in shields for k in summary["shields"][s]["subsets"]})
    fig, ax = plt.subplots(figsize=(10, 4))
    w = 0.8 / max(len(shields), 1)
    lowest = 1.0
    for k, s in enumerate(shields):
        vals = [summary["shields"][s]["subsets"].get(name, {}).get("collision_free", math.nan) for name in subsets]
        ax.bar([i + k * w for i in range(len(subsets))], vals, w, label=s)
        lowest = min([lowest] + [v for v in vals if v == v])
    ax.set_xticks([i + w * (len(shields) - 1) / 2 for i in range(len(subsets))], subsets, rotation=30, ha="right")
    # Zoomed to the lowest bar: the shares differ in the second and third decimal, and drawn from
    # 0 the bars looked equal (the axis starts a hundredth below the lowest).
    ax.set_ylim(max(0.0, math.floor((lowest - 0.01) * 100.0) / 100.0), 1.002)
    ax.set_ylabel("collision-free share")
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0))  # beside the axes: over the bars it hid them
    fig.tight_layout()
    fig.savefig(out / "collision_free_by_subset.png", dpi=90)
    plt.close(fig)
    plots.append(("collision_free_by_subset.png", "Collision-free share per subset"))
    # 2. distribution of the per-episode minimum clearance
    fig, ax = plt.subplots(figsize=(7, 4))
    for s in shields:
        xs = sorted(r.min_clearance_m for r in per_shield[s] if math.isfinite(r.min_clearance_m))
        if xs:
            ax.plot(xs, [(i + 1) / len(xs) for i in range(len(xs))], label=s)
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_xlabel("episode minimum clearance from the rotor envelope (m)")
    ax.set_ylabel("share of episodes")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "min_clearance_cdf.png", dpi=90)
    plt.close(fig)
    plots.append(("min_clearance_cdf.png", "Per-episode minimum clearance (CDF)"))
    # 3. worst episodes: re-flown (deterministic) and drawn from above
    plots.extend(_worst_plots(summary, per_shield, out, plt))
    return _write_html(summary, shields, plots, out)


def _write_html(summary: dict, shields: list[str], plots: list[tuple[str, str]], out: Path, note: str = "") -> Path:
    rows = []
    for key, label in METRIC_ROWS:
        cells = "".join(f"<td>{fmt(summary['shields'][s].get(key))}</td>" for s in shields)
        rows.append(f"<tr><th>{html.escape(label)}</th>{cells}</tr>")
    goals = "".join(
        f"<li>{html.escape(k)}: {fmt(v.get('value'))} (goal {fmt(v.get('goal'))}) - {_verdict(v.get('met'))}</li>"
        for k, v in summary.get("goals", {}).items()
    )
    imgs = "".join(f"<figure><img src='{p}'><figcaption>{html.escape(c)}</figcaption></figure>" for p, c in plots)
    fails = "".join(f"<li><code>{html.escape(f)}</code></li>" for f in summary.get("failures", [])[:200])
    doc = f"""<!doctype html><html><head><meta charset="utf-8"><title>Flight safety campaign</title>
<style>body{{font-family:sans-serif;margin:2em}}table{{border-collapse:collapse}}td,th{{border:1px solid #bbb;padding:4px 8px;text-align:right}}th{{text-align:left}}img{{max-width:100%}}</style></head><body>
<h1>Flight safety campaign</h1>
<p>{summary['episodes']} episodes, seed {summary['seed']}, {summary['workers']} worker processes, {summary['elapsed_s']} s.</p>
<table><tr><th></th>{''.join(f'<th>{html.escape(s)}</th>' for s in shields)}</tr>{''.join(rows)}</table>
<h2>Goals (ours)</h2><ul>{goals}</ul>
<h2>Plots</h2>{html.escape(note)}{imgs}
<h2>Failures (replayable scenarios)</h2><ul>{fails or '<li>none</li>'}</ul>
</body></html>"""
    path = out / "report.html"
    path.write_text(doc)
    return path


def _worst_plots(summary, per_shield, out: Path, plt) -> list[tuple[str, str]]:
    from inspect_pipe.campaign.generator import generate_episode
    from inspect_pipe.campaign.run import fly_episode

    plots = []
    for s, rs in per_shield.items():
        if not rs:
            continue
        worst = min(rs, key=lambda r: (not r.collided, r.min_clearance_m))
        spec = generate_episode(summary["seed"], worst.index)
        trace: list = []
        fly_episode(spec, s, trace.append)
        sc = spec.scenario()
        h = sc.world.hold
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
        a1.add_patch(plt.Rectangle((0, -h.width_m / 2), h.length_m, h.width_m, fill=False))
        for b in sc.world.boxes:
            a1.add_patch(plt.Rectangle((b.min_m[0], b.min_m[1]), b.max_m[0] - b.min_m[0], b.max_m[1] - b.min_m[1], color="0.7"))
        a1.plot([r.pos_true[0] for r in trace], [r.pos_true[1] for r in trace], lw=1)
        if worst.collided:
            a1.plot([trace[-1].pos_true[0]], [trace[-1].pos_true[1]], "rx", ms=10)
        a1.set_aspect("equal")
        a1.set_xlabel("x (m)")
        a1.set_ylabel("y (m)")
        a1.set_title(f"{s}: episode {worst.index} ({spec.kind}), top view")
        from inspect_pipe.flight.geometry import HoldGeometry

        g = HoldGeometry(sc.world)
        a2.plot([r.t for r in trace], [g.side_distance(*r.pos_true) - 0.27 for r in trace], lw=1, label="clearance")
        for f in sc.faults:
            a2.axvspan(f.t_s, f.t_s + f.duration_s, alpha=0.15, color="r")
        a2.axhline(0, color="k", lw=0.8)
        a2.set_xlabel("t (s)")
        a2.set_ylabel("clearance from rotor envelope (m)")
        a2.set_title("faults shaded")
        fig.tight_layout()
        name = f"worst_{s}.png"
        fig.savefig(out / name, dpi=80)
        plt.close(fig)
        plots.append((name, f"Worst episode of {s}: {spec.name}" + (" (collision)" if worst.collided else "")))
    return plots
