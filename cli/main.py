"""Entry point of the ``inspect-pipe`` console script.

Each command lives in its own module of this package and is registered here, once.
"""

from __future__ import annotations

import inspect
from typing import Annotated

import typer

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
app.command("fly", help=reflow(_fly.HELP))(_fly.fly)
app.command("base-station", help=reflow(_base_station.HELP))(_base_station.base_station)
app.command("capture", help=reflow(_capture.HELP))(_capture.capture)
app.command("calibrate", help=reflow(_calibrate.HELP))(_calibrate.calibrate)
app.command("doctor", help=reflow(_doctor.HELP))(_doctor.doctor)
app.command("report", help=reflow(_report.HELP))(_report.report)
app.command("run", help=reflow(_run.HELP))(_run.run)
app.command("demo", help=reflow(_demo.HELP))(_demo.demo)
app.command("campaign", help=reflow(_campaign.HELP))(_campaign.campaign)
app.command("import", help=reflow(_import.HELP))(_import.import_)
app.command("compare", help=reflow(_compare.HELP))(_compare.compare)
app.command("review", help=reflow(_review.HELP))(_review.review)


if __name__ == "__main__":  # pragma: no cover
    app()
