"""Entry point of the ``inspect-pipe`` console script.

Each command lives in its own module of this package and is registered here, once.
"""

from __future__ import annotations

import inspect
import os
from typing import Annotated

import typer

# FFmpeg (under OpenCV's video reader) prints its own lines for a damaged file ("moov atom not found") before the
# command's one-line error; quiet unless the user sets the level (OpenCV reads it when it first opens a video)
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")

import inspect_pipe
from cli._common import VerbosityGroup
from cli import mosaic as _mosaic
from cli import detect as _detect
from cli import fly as _fly
from cli import base_station as _base_station
from cli import capture as _capture
from cli import calibrate as _calibrate
from cli import doctor as _doctor
from cli import report as _report
from cli import run as _run
from cli import demo as _demo
from cli import campaign as _campaign
from cli import import_ as _import
from cli import compare as _compare
from cli import review as _review

app = typer.Typer(
    cls=VerbosityGroup,  # -q/--quiet and -v/--verbose on the app and on every command
    name="inspect-pipe",
    help="Supervised-autonomy MAV inspection of cargo holds: fly, capture, mosaic, detect, report.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"inspect-pipe {inspect_pipe.__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[bool, typer.Option("--version", is_eager=True, callback=_print_version, help="Print the version and exit.")] = False,
) -> None:
    """Supervised-autonomy MAV inspection of cargo holds: fly, capture, mosaic, detect, report."""


def reflow(text: str) -> str:
    """A help text with its prose paragraphs joined into one line each, so the terminal wraps them
    to its own width (typer keeps single line breaks, so a text hard-wrapped at 100 columns came
    out ragged in an 80-column terminal). Paragraphs with indented lines (examples), list items or
    command lines keep their lines."""
    out = []
    for para in inspect.cleandoc(text).split("\n\n"):
        lines = para.split("\n")
        keep = any(ln.startswith((" ", "\t", "- ", "* ", "inspect-pipe ", "$ ")) for ln in lines) or para.startswith("\b")
        out.append(para if keep else " ".join(ln.strip() for ln in lines))
    return "\n\n".join(out)


app.command("mosaic", help=reflow(_mosaic.HELP))(_mosaic.mosaic)


@app.command("version")
def version() -> None:
    """Print the software version."""
    typer.echo(inspect_pipe.__version__)


for _cmd in _detect.app.registered_commands:  # detect run / detect train: their docstrings
    _cmd.help = reflow(_cmd.help or _cmd.callback.__doc__ or "")
_detect.app.info.help = reflow(_detect.app.info.help or "")
app.add_typer(_detect.app, name="detect")
# each command with its module's HELP text, in the order --help lists them
for _name, _module, _command in (
    ("fly", _fly, _fly.fly),
    ("base-station", _base_station, _base_station.base_station),
    ("capture", _capture, _capture.capture),
    ("calibrate", _calibrate, _calibrate.calibrate),
    ("doctor", _doctor, _doctor.doctor),
    ("report", _report, _report.report),
    ("run", _run, _run.run),
    ("demo", _demo, _demo.demo),
    ("campaign", _campaign, _campaign.campaign),
    ("import", _import, _import.import_),
    ("compare", _compare, _compare.compare),
    ("review", _review, _review.review),
):
    app.command(_name, help=reflow(_module.HELP))(_command)


if __name__ == "__main__":  # pragma: no cover
    app()
