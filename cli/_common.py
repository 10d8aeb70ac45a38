"""Shared CLI plumbing: one-line errors with exit code 2; -q/-v verbosity and the progress console."""

from __future__ import annotations

import errno
import functools
import math
from enum import Enum
from pathlib import Path
import logging
import sys
from typing import Annotated, Callable, TypeVar

import typer
import typer.main
from rich.console import Console
from rich.logging import RichHandler
from typer._click.exceptions import NoArgsIsHelpError, UsageError
from typer.core import TyperGroup

from inspect_pipe.errors import InputError

F = TypeVar("F", bound=Callable)


def fail(message: str, code: int = 2) -> "typer.Exit":
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(code)


def os_error_line(err: OSError) -> str:
    """One line for an operating-system error while reading or writing: the path, the problem, what to do."""
    where = err.filename or "output"
    what = (err.strerror or err.__class__.__name__).lower()
    if err.errno in (errno.ENOSPC, errno.EDQUOT):
        return f"{where}: {what} (free space or give -o a folder on another disk, then run again; no file is left half-written)"
    if err.errno == errno.EROFS:
        return f"{where}: {what} (give -o a writable folder)"
    return f"{where}: {what}"


def one_line_errors(func: F) -> F:
    """Turn :class:`InputError` (and a few OS errors) into ``error: ...`` on stderr and exit 2."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        for name, value in kwargs.items():  # no command takes a NaN or an infinity for a number
            if isinstance(value, float) and not math.isfinite(value):
                raise fail(f"--{name.replace('_', '-')} {value}: must be a finite number")
        try:
            return func(*args, **kwargs)
        except InputError as err:
            raise fail(str(err)) from None
        except FileNotFoundError as err:
            raise fail(f"{err.filename}: not found") from None
        except PermissionError as err:
            raise fail(f"{err.filename}: permission denied") from None
        except (FileExistsError, NotADirectoryError) as err:  # a file where a folder is to be made
            if err.filename and Path(err.filename).is_file():
                raise fail(f"{err.filename}: a file is there, where a folder is written (give another -o, or move the file)") from None
            raise fail(os_error_line(err)) from None
        except OSError as err:  # a full or read-only disk, a failing device: one line, exit 2
            raise fail(os_error_line(err)) from None
        except KeyboardInterrupt:
            typer.echo("interrupted; everything written so far is kept", err=True)
            sys.exit(130)

    return wrapper  # type: ignore[return-value]


# --- verbosity: -q/--quiet and -v/--verbose on the app and on every command -------------------

#: Progress bars and notes go to this stderr console; ``-q`` makes it quiet. Results (stdout) and
#: errors are printed whatever the verbosity.
console = Console(stderr=True, highlight=False)
_log_console = Console(stderr=True, highlight=False)
log = logging.getLogger("inspect_pipe")


def set_verbosity(level: int) -> None:
    """-1: quiet (results and errors only), 0: normal (progress and notes), 1: verbose (debug log)."""
    console.quiet = level < 0
    log.setLevel(logging.WARNING if level < 0 else logging.DEBUG if level > 0 else logging.INFO)
    if not any(isinstance(h, RichHandler) for h in log.handlers):
        log.addHandler(RichHandler(console=_log_console, show_time=False, show_path=False, markup=False))
        log.propagate = False


def note(message: str) -> None:
    """An informational line on stderr (step skipped, file written ...); silent under ``-q``."""
    if not console.quiet:
        typer.echo(message, err=True)


def progress_enabled() -> bool:
    """Live progress only on a terminal and without ``-q``."""
    return console.is_terminal and not console.quiet


def _on_quiet(value: bool) -> None:
    if value:
        set_verbosity(-1)


def _on_verbose(value: bool) -> None:
    if value:
        set_verbosity(1)


def _verbosity_template(
    quiet: Annotated[bool, typer.Option("-q", "--quiet", is_eager=True, expose_value=False, callback=_on_quiet,
                                        help="Results and errors only: no progress, no notes.")] = False,
    verbose: Annotated[bool, typer.Option("-v", "--verbose", is_eager=True, expose_value=False, callback=_on_verbose,
                                          help="Also debug messages on stderr.")] = False,
) -> None:
    """Only its parameters are used: typer builds them as it builds every other option."""


def _verbosity_options() -> list:
    probe = typer.Typer(add_completion=False)
    probe.command()(_verbosity_template)
    return list(typer.main.get_command(probe).params)


def add_verbosity(cmd) -> None:
    """Give ``cmd`` (and, for a group, every command under it) the -q/-v options, once."""
    names = {n for p in cmd.params for n in getattr(p, "opts", ())}
    cmd.params.extend(p for p in _verbosity_options() if not names & set(p.opts))
    for sub in getattr(cmd, "commands", {}).values():
        add_verbosity(sub)


class VerbosityGroup(TyperGroup):
    """The app's click group: every command under it gets ``-q/--quiet`` and ``-v/--verbose``, so
    that ``inspect-pipe -q CMD`` and ``inspect-pipe CMD -q`` both work without each command
    declaring them."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        set_verbosity(0)  # a fresh invocation (tests run many in one process)
        add_verbosity(self)

    # A usage error (unknown option, a value not among an option's choices, a missing argument)
    # is one line on stderr and exit 2, like every other bad input; --help shows the rest.
    def make_context(self, *args, **kwargs):
        try:
            return super().make_context(*args, **kwargs)
        except UsageError as err:
            raise _usage_exit(err) from None

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except UsageError as err:
            raise _usage_exit(err) from None


def _usage_exit(err: "UsageError") -> Exception:
    if isinstance(err, NoArgsIsHelpError):  # a bare group or command: its help, as click shows it
        return err
    where = err.ctx.command_path if err.ctx is not None else "inspect-pipe"
    return fail(f"{where}: {err.format_message()} (see {where} --help)")


class StageProgress:
    """Per-stage rich progress bars (``progress(stage, done, total)``) on a terminal; silent
    otherwise and under ``-q``."""

    def __init__(self, label: str = "", enabled: bool = True) -> None:
        self.label = label
        self.tasks: dict[str, object] = {}
        self.bar = None
        if enabled and progress_enabled():
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

            self.bar = Progress(TextColumn("{task.description:28s}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                                console=console, transient=False)
            self.bar.start()

    def __call__(self, stage: str, done: int, total: int) -> None:
        if not self.bar:
            return
        key = f"{self.label} {stage}".strip()
        if key not in self.tasks:
            self.tasks[key] = self.bar.add_task(key, total=max(total, 1))
        self.bar.update(self.tasks[key], completed=done, total=max(total, 1))

    def close(self) -> None:
        if self.bar:
            self.bar.stop()
            self.bar = None


def choices(name: str, values) -> type[Enum]:
    """A str Enum of ``values`` for an option, so that ``--help`` lists them and a wrong value is
    refused in one line (typer turns an Enum annotation into a choice)."""
    return Enum(name, {str(v): str(v) for v in values}, type=str)


# --- the survey plan (--survey PLAN.yaml) on capture, import, mosaic, run and report ----------

SURVEY_HELP = ("Survey plan (YAML, format inspect_pipe.survey_plan/1, docs/ship.md): vessel, survey, hold frames, "
               "the wall surveyed and the take-off point; locations in the report are given in ship terms from it.")


def load_plan(path):
    """The ``--survey`` file as ``inspect_pipe.ship.SurveyPlan`` (None when not given); a bad plan
    is one line naming the file and the field. Its warnings (e.g. an IMO check digit) are noted."""
    if path is None:
        return None
    from inspect_pipe.ship import load_survey_plan

    plan = load_survey_plan(path)
    for w in plan.warnings:
        note(f"warning: {path}: {w}")
    return plan


def web_server_token(host: str, token, certfile, keyfile):
    """The checks every web page server (base station, review) makes before it binds: the web
    extra, the TLS pair, the token's length; off loopback a token is required (a new random one
    when none is given). Returns the token to require (None on loopback without one)."""
    from inspect_pipe.errors import InputError as _InputError
    from inspect_pipe.flight.base_station import check_tls, is_loopback_host, new_token, require_web

    require_web()
    check_tls(certfile, keyfile)
    if token is not None and len(token) < 12:
        raise _InputError("--token", "too short", "at least 12 characters")
    if not is_loopback_host(host) and token is None:
        token = new_token()
    return token
