"""``inspect-pipe compare OLD_RUN NEW_RUN -o OUT``: what changed since the last survey."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cli._common import note, one_line_errors

HELP = """Compare two surveys of one wall: what appeared, grew, shrank or went since the last one.

OLD_RUN and NEW_RUN are run directories of `inspect-pipe run` (a mosaic placed on the wall and a
register in report/defects.json). The two mosaics are registered on the wall (wall coordinates
first, SIFT features on a common wall raster to refine), the registers matched (outlines within
3 cm), and each defect called new, grown, shrunk, unchanged or gone; area changes within the
noise measured between flights of unchanged walls count as unchanged. Areas are compared only
over the wall both surveys imaged; a defect mostly outside it is listed as not compared. An entry
registered by one survey only is new or gone only where the other survey's detection map no
longer shows it; a faint patch near the detector's operating point is unchanged, with a note.

OUT gets changes.json (inspect_pipe.changes/1: entries with status, old_id, new_id,
centroid_wall_m, area_old_m2, area_new_m2; below_noise; not_compared), change_map.png, crops/ (old | new side by side),
report.html and report.pdf.

Two runs of different walls (other vessel, hold or wall in their surveys, mosaics that do not
overlap on the wall, or too few image features that agree) or a run without a register: one
line, exit 2, nothing written.

Examples:

  inspect-pipe compare out/survey_2025 out/survey_2026 -o out/changes

  inspect-pipe compare out/run1 out/run2 -o out/changes --no-pdf
"""


@one_line_errors
def compare(
    old_run: Annotated[Path, typer.Argument(help="The earlier survey's run directory.")],
    new_run: Annotated[Path, typer.Argument(help="The later survey's run directory.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder.")],
    no_pdf: Annotated[bool, typer.Option("--no-pdf", help="Do not render report.pdf.")] = False,
) -> None:
    from inspect_pipe.report._compare import compare_runs, write_comparison

    c = compare_runs(old_run, new_run)  # every check before anything is written
    written = write_comparison(c, out, pdf=not no_pdf, log=note)
    counts = ", ".join(f"{sum(ch.status == s for ch in c.changes)} {s}" for s in ("new", "grown", "shrunk", "gone", "unchanged"))
    if c.not_compared:
        counts += f"; {len(c.not_compared)} not compared (outside the wall both surveys imaged)"
    typer.echo(f"{written['changes']}: {counts}")
    typer.echo(f"{written['html']}" + (f"\n{written['pdf']}" if written.get("pdf") else ""))
