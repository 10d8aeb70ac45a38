"""Change since the last survey (issue 20, item 5): how small a change `compare` tells from noise.

Demo wall (seed 5) flown three times (flight seeds 11, 12 and 13), compared pair by pair: every
change reported is a false one, and the area differences of the matched defects are the noise (one
pair is one draw of the flight-to-flight spread; three give a rate). The same wall edited
(``edit_demo_wall``: 3 corrosion patches appeared, 2 grew 1.4x in size) and flown with seeds 12 and
13, each compared with flight 11: every appeared or grown defect should be reported new or grown
within 10 cm.

    python -m bench --only compare            (5 flights, about 20 s each on 2 free cores)
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path


def measure(old: Path, new: Path, truth_changes: list[dict] | None = None) -> dict:
    """Compare two runs; with the edit's true changes: which were reported (new/grown within 10 cm)
    and how many reported changes match none (false changes)."""
    from inspect_pipe.report._compare import compare_runs

    c = compare_runs(old, new)
    changes = [ch for ch in c.changes if ch.status != "unchanged"]
    same = [(ch.prob_area_old_m2, ch.prob_area_new_m2) if ch.prob_area_old_m2 is not None else (ch.area_old_m2, ch.area_new_m2)
            for ch in c.changes if ch.status == "unchanged"]  # the areas the grown/shrunk test uses
    rel = [abs(b - a) / max(a, b, 1e-12) for a, b in same]
    dabs = [abs(b - a) for a, b in same]
    out = {"registration": c.registration, "counts": {s: sum(ch.status == s for ch in c.changes) for s in ("new", "grown", "shrunk", "gone", "unchanged")},
           "below_noise": len(c.below_noise), "noise_rel_max": max(rel, default=0.0), "noise_abs_max_m2": max(dabs, default=0.0),
           "changes": [(ch.status, ch.cls, [round(x, 3) for x in ch.centroid_wall_m], round(ch.area_old_m2 * 1e4, 1), round(ch.area_new_m2 * 1e4, 1)) for ch in changes]}
    if truth_changes is not None:
        found = match_truth([(ch.status, ch.centroid_wall_m) for ch in changes], truth_changes)
        out["true_changes"] = [(t["truth"], t["kind"], None if f is None else (changes[f[0]].status, round(f[1] * 100, 1)))
                               for t, f in zip(truth_changes, found)]
        out["false_changes"] = len(changes) - len({f[0] for f in found if f is not None})
    else:
        out["false_changes"] = len(changes)
    return out


def match_truth(changes: list[tuple[str, tuple[float, float]]], truth_changes: list[dict], within_m: float = 0.10) -> list:
    """For each true change (``edit_demo_wall``'s), the nearest reported new or grown change within
    ``within_m`` as (index into ``changes``, distance m), or None: issue 20's 'reported within 10 cm'."""
    found = []
    for t in truth_changes:
        near = [(math.dist(c, t["centroid_wall_m"]), i) for i, (s, c) in enumerate(changes) if s in ("new", "grown")]
        near = [x for x in near if x[0] <= within_m]
        found.append(None if not near else (min(near)[1], min(near)[0]))
    return found


def run(data: Path) -> str:
    import tempfile

    from bench.bench_register import fly
    from inspect_pipe.pipeline._demo import build_demo_wall, edit_demo_wall

    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="bench_compare_") as tmp:
        tmp = Path(tmp)
        wall = build_demo_wall(tmp / "wall", data, seed=5)
        for s in SAME_FLIGHTS:
            fly(data, tmp / f"same{s}", 5, s, wall=wall)
        edited, truth = edit_demo_wall(wall, tmp / "wall_edited", data)
        for s in EDITED_FLIGHTS:
            fly(data, tmp / f"edited{s}", 5, s, wall=edited)
        first = SAME_FLIGHTS[0]
        same = [(f"same wall, flights {a} / {b}", measure(tmp / f"same{a}", tmp / f"same{b}"))
                for i, a in enumerate(SAME_FLIGHTS) for b in SAME_FLIGHTS[i + 1:]]
        changed = [(f"edited wall, flights {first} / {s}", measure(tmp / f"same{first}", tmp / f"edited{s}", [t.to_json() for t in truth]))
                   for s in EDITED_FLIGHTS]
    return section(same, changed, time.monotonic() - t0)


SAME_FLIGHTS = (11, 12, 13)  # flight seeds of the unchanged wall; every pair is compared
EDITED_FLIGHTS = (12, 13)  # flight seeds of the edited wall, each compared with the first unchanged flight


def section(same: list[tuple[str, dict]], changed: list[tuple[str, dict]], seconds: float) -> str:
    lines = ["## Change since the last survey (`bench_compare.py`)\n",
             f"Demo wall (seed 5) flown with seeds {', '.join(map(str, SAME_FLIGHTS))}, every pair compared; the edited wall "
             f"(3 corrosion patches appeared, 2 grew 1.4x linear) flown with seeds {', '.join(map(str, EDITED_FLIGHTS))}, each "
             f"compared with flight {SAME_FLIGHTS[0]}.\n",
             "| pair | registration (inliers, shift) | new / grown / shrunk / gone / unchanged | below noise | false changes | "
             "largest weighted-area difference called unchanged |",
             "|---|---|---|---:|---:|---|"]
    for name, r in same + changed:
        c = r["counts"]
        lines.append(f"| {name} | {r['registration']['inliers']}, {100 * r['registration']['shift_m']:.1f} cm | "
                     f"{c['new']} / {c['grown']} / {c['shrunk']} / {c['gone']} / {c['unchanged']} | {r['below_noise']} | {r['false_changes']} | "
                     f"{r['noise_abs_max_m2'] * 1e4:.1f} cm² ({100 * r['noise_rel_max']:.0f} %) |")
    lines.append("")
    false_same = sum(r["false_changes"] for _, r in same)
    lines.append(f"Unchanged wall: {false_same} false change(s) over {len(same)} pairs "
                 f"({sum(r['false_changes'] == 0 for _, r in same)} of {len(same)} pairs with none).")
    for name, r in changed:
        lines.append(f"\nTrue changes, {name}: " + "; ".join(
            f"{t} {k}: " + (f"reported {s[0]} at {s[1]} cm" if s else "missed") for t, k, s in r.get("true_changes", [])) + ".")
    lines.append(f"\nTotal {seconds:.0f} s.\n")
    return "\n".join(lines)


if __name__ == "__main__":  # python bench/bench_compare.py OLD NEW [CHANGES_TRUTH.json]
    import sys

    tc = json.loads(Path(sys.argv[3]).read_text()) if len(sys.argv) > 3 else None
    print(json.dumps(measure(Path(sys.argv[1]), Path(sys.argv[2]), tc), indent=1))
