"""``inspect-pipe doctor``: which camera and vehicle back-ends work here, and why not."""

from __future__ import annotations

import typer

from cli._common import one_line_errors
from inspect_pipe.capture import backends

HELP = """List every camera and vehicle back-end, whether it is usable on this machine, and why
(not): missing SDK, missing runtime, no device attached.

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
