"""``inspect-pipe demo -o OUT``: a simulated inspection of a wall with known defects, end to end."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated, Optional

import typer

from cli._common import note, one_line_errors
from cli.detect import DEFAULT, ENGINE_HELP, Engine

HELP = """Simulated inspection flight over a demo wall with known defects, then the whole pipeline.

Builds the wall in OUT/demo_wall (painted steel with corrosion patches from the CC0 VT corrosion
images and cracks from CrackForest in --data, their masks kept as ground truth; without --data the
shipped CC0 scenario wall), flies the three-pass inspection sweep in front of it (10 Hz sweep in
OUT/sweep), mosaics, detects (--engine, default onnx: the learned network), writes
OUT/report/report.html and report.pdf, and prints how the found defects compare with the truth
(also in OUT/truth_comparison.json). Resumable like run: another --engine on the same
OUT redoes only detect and report.

Examples:

  inspect-pipe demo -o out/demo

  inspect-pipe demo -o out/demo --data ../shared/data --force

  inspect-pipe demo -o out/demo --engine saliency
"""


@one_line_errors
def demo(
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder (the demo's run directory).")],
    data: Annotated[Optional[Path], typer.Option("--data", help="Shared data folder (defects/vt_corrosion_cs, defects/crackforest).")] = Path("../shared/data"),
    force: Annotated[bool, typer.Option("--force", help="Rebuild the wall and redo every step.")] = False,
    no_pdf: Annotated[bool, typer.Option("--no-pdf", help="Do not render report.pdf.")] = False,
    engine: Annotated[Engine, typer.Option("--engine", help="Detect step: " + ENGINE_HELP)] = DEFAULT,
) -> None:
    from cli.run import RichProgress, build_config, check_engine, print_outcome
    from inspect_pipe.pipeline import DetectConfig, run_pipeline
    from inspect_pipe.pipeline._demo import DEMO_PLAN, DEMO_SURVEY, DemoWall, TruthDefect, build_demo_wall, compare_with_truth, demo_scenario
    from inspect_pipe.report import read_register
    from inspect_pipe.ship import parse_survey_plan

    t0 = time.monotonic()
    check_engine(DetectConfig(engine=engine.value))  # before the wall is built and flown
    wall_dir = out / "demo_wall"
    truth_path = wall_dir / "truth.json"
    if force or not truth_path.is_file():
        wall = build_demo_wall(wall_dir, data if data and data.is_dir() else None)
        typer.echo(f"demo wall: {len(wall.truth)} known defects, {wall.source}")
        force = True
    doc = json.loads(truth_path.read_text())
    truth = [TruthDefect(t["id"], t["class"], tuple(t["centroid_wall_m"]), t["area_m2"], tuple(t["bbox_wall_m"]), t["source"]) for t in doc["defects"]]
    wall = DemoWall(wall_dir / "wall.png", wall_dir / "wall_mask.png", wall_dir / "wall_labels.png", doc["m_per_px"], tuple(doc["origin_uv"]), tuple(truth), doc["source"])
    scenario = demo_scenario(wall, wall_dir / "scenario.yaml")
    cfg = build_config(f"fly:{scenario}", kinds="all", keyframe_spacing=0.5, scheme="MSC.1/Circ.1330", area_m=1.0,
                       no_pdf=no_pdf, m_per_px=None, focal_px=None, survey=DEMO_SURVEY, engine=engine.value,
                       survey_plan=parse_survey_plan(DEMO_PLAN, "demo survey plan"))
    prog = RichProgress("demo")
    try:
        o = run_pipeline(out, cfg, force=force, progress=prog, log=note)
    finally:
        prog.close()
    print_outcome(o)
    defects = read_register(out / "report" / "defects.json")
    cmp = compare_with_truth(defects, truth, wall=wall)
    (out / "truth_comparison.json").write_text(json.dumps(cmp, indent=1))
    typer.echo(f"found vs truth ({engine.value} engine): {cmp['matched']}/{cmp['truth']} known defects found, "
               f"{cmp['false_alarms']} other entries")
    for r in cmp["rows"]:
        if r["found"]:
            more = f" (+{len(r['pieces']) - 1} pieces)" if len(r["pieces"]) > 1 else ""
            typer.echo(f"  {r['truth']} {r['class']:9s} -> {r['found']}{more}: centroid off {100 * r['centroid_error_m']:.1f} cm, area {r['area_true_m2'] * 1e4:.0f} -> {r['area_found_m2'] * 1e4:.0f} cm2 ({100 * r['area_error']:+.0f} %)")
        else:
            typer.echo(f"  {r['truth']} {r['class']:9s} -> not found")
    rep = out / "report" / ("report.pdf" if (out / "report" / "report.pdf").exists() else "report.html")
    typer.echo(f"report: {rep}  ({time.monotonic() - t0:.0f} s)")
