"""``inspect-pipe report RUN_DIR -o OUT``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from cli._common import SURVEY_HELP, load_plan, note, one_line_errors
from cli.run import Scheme, build_config
from inspect_pipe.errors import InputError

HELP = """Write the surveyor's report from a run directory's mosaic and detections.

OUT gets report.html, report.pdf (WeasyPrint), defects.json and defects.csv (the register: id,
class, polygon and centroid in wall metres, area or crack length, confidence, frames, ship frames,
status), coco.json, coverage.json, rating.json and assets/. Statuses a surveyor set in OUT's
defects.json or defects.csv (suggested / confirmed / rejected) are kept.

Examples:

  inspect-pipe report out/run1 -o out/run1/report

  inspect-pipe report out/run1 -o out/rep --scheme MSC.1/Circ.1399 --area-m 2
"""


@one_line_errors
def report(
    run_dir: Annotated[Path, typer.Argument(help="Run directory (inspect-pipe run) with mosaic/ and detect/.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder.")],
    scheme: Annotated[Scheme, typer.Option("--scheme", help="Coating rating scheme.")] = Scheme("MSC.1/Circ.1330"),
    area_m: Annotated[float, typer.Option("--area-m", help="Side of an area under consideration, m.")] = 1.0,
    m_per_px: Annotated[Optional[float], typer.Option("--m-per-px", help="Mosaic of a plain folder: metres per pixel.")] = None,
    no_pdf: Annotated[bool, typer.Option("--no-pdf", help="Do not render report.pdf.")] = False,
    survey: Annotated[Optional[Path], typer.Option("--survey", help=SURVEY_HELP + " Default: the plan stored in the sweep.")] = None,
) -> None:
    from inspect_pipe.pipeline import RunStore
    from inspect_pipe.pipeline._steps import run_report_step

    if not run_dir.is_dir():
        raise InputError(str(run_dir), "not found" if not run_dir.exists() else "not a directory", "give a run directory written by inspect-pipe run")
    store = RunStore(run_dir)
    cfg = build_config(str(run_dir), kinds="all", keyframe_spacing=0.0, scheme=scheme.value, area_m=area_m, no_pdf=no_pdf,
                       m_per_px=m_per_px, focal_px=None, report_out=out, survey_plan=load_plan(survey))
    written = run_report_step(store, cfg, None, log=note)
    typer.echo(f"{written['html']}" + (f"\n{written['pdf']}" if written.get("pdf") else ""))
