"""``inspect-pipe doctor``: which camera and vehicle back-ends work here, and why not."""

from __future__ import annotations

import typer

from cli._common import one_line_errors
from inspect_pipe.capture import backends
from inspect_pipe.capture.sources import v4l2

HELP = """List every camera and vehicle back-end, whether it is usable on this machine, and why
(not): missing SDK, missing runtime, no device attached. Under the list, each V4L2 camera's pixel
formats, frame sizes and frame rates (v4l2-ctl --list-formats-ext when v4l-utils is installed,
else probed through OpenCV): `capture` runs the camera at its own rate and keeps the frame
nearest each --rate deadline.

Example:

  inspect-pipe doctor

Exit 0 (the list is the result, whatever it says).
"""


@one_line_errors
def doctor() -> None:
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
