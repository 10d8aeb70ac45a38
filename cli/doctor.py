"""``inspect-pipe doctor``: which camera and vehicle back-ends work here, and why not."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from cli._common import SURVEY_HELP, load_plan, one_line_errors
from inspect_pipe.capture import backends
from inspect_pipe.capture.sources import v4l2
from inspect_pipe.errors import InputError

HELP = """List every camera and vehicle back-end, whether it is usable on this machine, and why
(not): missing SDK, missing runtime, no device attached. Under the list, each V4L2 camera's pixel
formats, frame sizes and frame rates (v4l2-ctl --list-formats-ext when v4l-utils is installed,
else probed through OpenCV): `capture` runs the camera at its own rate and keeps the frame
nearest each --rate deadline.

With --sweep SWEEP it says instead what that sweep still lacks for a report in metres and ship
terms (camera calibration, vehicle state, the distance to the wall, a survey plan and its take-off
tie, the hold's dimensions, the time alignment of imported footage) and what follows for the report.

Examples:

  inspect-pipe doctor

  inspect-pipe doctor --sweep out/sweep1 [--survey plan.yaml]

Exit 0 (the list is the result, whatever it says); 2 when the sweep cannot be read.
"""


@one_line_errors
def doctor(
    sweep: Annotated[Optional[Path], typer.Option("--sweep", help="A sweep: what it still lacks for a georeferenced report.")] = None,
    survey: Annotated[Optional[Path], typer.Option("--survey", help=SURVEY_HELP + " With --sweep: judged with this plan; alone: checked, one line before the backends.")] = None,
) -> None:
    if sweep is not None:
        from inspect_pipe.capture import read_sweep
        from inspect_pipe.pipeline._readiness import sweep_readiness

        sw = read_sweep(sweep)
        if not sw.frames:
            why = f" ({sw.problems[0]})" if sw.problems else ""
            raise InputError(str(sweep / "frames.jsonl"), f"no readable frames{why}", "nothing to judge: capture or import again")
        findings = sweep_readiness(sw, load_plan(survey))
        for f in findings:
            typer.echo(f"{'ok ' if f.ok else 'no '} {f.line()}")
        if sw.problems:
            typer.echo(f"no  frames: {len(sw.problems)} line(s) of frames.jsonl skipped (first: {sw.problems[0]})")
        missing = sum(not f.ok for f in findings)
        typer.echo(f"{sweep}: " + ("ready for a report in metres and ship terms" if not missing
                                    else f"{missing} thing(s) to provide; the report states each as a limitation"))
        return
    if survey is not None:  # checked on its own: one line, or the one-line error of a bad plan
        plan = load_plan(survey)
        typer.echo(f"ok  survey plan {survey}: {plan.vessel.name}, {plan.compartment.name}, {plan.wall.name.value}")
    rows = backends()
    width = max(len(f"{b.kind} {b.name}") for b in rows)
    for b in rows:
        mark = "ok " if b.usable else "no "
        typer.echo(f"{mark} {(b.kind + ' ' + b.name).ljust(width)}  {b.why}  [{b.spec}]")
    for dev in v4l2.list_v4l2_devices():
        how, modes = v4l2.camera_modes(dev)
        name = v4l2.device_name(dev)
        label = f"{dev} ({name})" if name else dev
        if not modes:
            typer.echo(f"    {label}: no capture formats (a metadata node, or the camera is busy) [{how}]")
            continue
        typer.echo(f"    {label}: {len(modes)} modes [{how}]")
        for m in modes:
            typer.echo(f"      {m.line()}" + (f"  ({m.description})" if m.description else ""))
