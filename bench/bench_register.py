"""The register's screening (issue 20, item 2) on demo walls of several seeds: known defects found
and other entries with the screening, what each rule left out, and whether a left-out candidate lay
near a known defect of its class (a wrong suppression).

    python -m bench --only register            (3 walls, about 2 min each on 2 cores)
"""

from __future__ import annotations

import json
import time
from pathlib import Path

WALL_SEEDS = (5, 11, 12)  # 5: the demo's wall


def fly(data: Path, out: Path, wall_seed: int, flight_seed: int | None = None, wall=None):
    """Build (or reuse) the demo wall of ``wall_seed`` and run the whole pipeline over it."""
    from inspect_pipe.pipeline import run_pipeline
    from inspect_pipe.pipeline._demo import DEMO_SURVEY, build_demo_wall, demo_scenario
    from inspect_pipe.pipeline._steps import DetectConfig, RunConfig

    if wall is None:
        wall = build_demo_wall(out / "demo_wall", data, seed=wall_seed)
    out.mkdir(parents=True, exist_ok=True)
    sc = demo_scenario(wall, out / f"scenario_{flight_seed}.yaml", seed=flight_seed)
    cfg = RunConfig(input=f"fly:{sc}", survey=DEMO_SURVEY, detect=DetectConfig(keyframe_spacing=0.5), report={"pdf": False})
    run_pipeline(out, cfg, log=lambda s: None)
    return wall


def evaluate(run: Path, wall) -> dict:
    from inspect_pipe.pipeline._demo import compare_with_truth
    from inspect_pipe.report import read_register

    defects = read_register(run / "report" / "defects.json")
    cmp = compare_with_truth(defects, list(wall.truth), wall=wall)
    reg = json.loads((run / "report" / "defects.json").read_text())
    left = reg["traceability"]["screening"]["left_out"]
    wrong = []
    for x in left:  # near a known defect of its class (its box grown by 15 cm)?
        u, v = x["centroid_wall_m"]
        for t in wall.truth:
            b = t.bbox_wall_m
            if t.cls == x["class"] and b[0] - 0.15 <= u <= b[2] + 0.15 and b[1] - 0.15 <= v <= b[3] + 0.15:
                wrong.append((t.id, x["rule"]))
                break
    rules = {}
    for x in left:
        rules[x["rule"]] = rules.get(x["rule"], 0) + 1
    return {"found": cmp["matched"], "truth": cmp["truth"], "other": cmp["false_alarms"], "left_out": rules, "left_out_near_truth": wrong}


def run(data: Path) -> str:
    import tempfile

    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_register_") as tmp:
        for seed in WALL_SEEDS:
            t0 = time.monotonic()
            out = Path(tmp) / f"wall{seed}"
            wall = fly(data, out, seed)
            r = evaluate(out, wall)
            rows.append((seed, r, time.monotonic() - t0))
    lines = ["## Register screening on demo walls (`bench_register.py`)\n",
             "Demo wall of each seed (9 corrosion patches from VT eval images, 3 CrackForest cracks), one "
             "flight, onnx engine. Other entries: register entries that are no piece of a known defect. "
             "Left out: candidates the screening dropped, by rule; near truth: left-out candidates within 15 cm "
             "of a known defect of their class.\n",
             "| wall seed | known found | other entries | left out (outside / seam / unconfirmed) | left out near truth | s |",
             "|---:|---:|---:|---|---|---:|"]
    for seed, r, dt in rows:
        lo = r["left_out"]
        lines.append(f"| {seed} | {r['found']}/{r['truth']} | {r['other']} | {lo.get('outside', 0)} / {lo.get('seam', 0)} / {lo.get('unconfirmed', 0)} | "
                     f"{', '.join(f'{a} ({b})' for a, b in r['left_out_near_truth']) or 'none'} | {dt:.0f} |")
    return "\n".join(lines) + "\n"
