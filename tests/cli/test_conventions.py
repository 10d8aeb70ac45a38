"""The command line's conventions: --version, -q/-v on every command, choices on enumerated
options (listed in --help, a wrong value refused in one line), rich progress."""

from __future__ import annotations

import io
import logging
from enum import Enum
from importlib.metadata import version

import pytest
import typer.main
from rich.console import Console
from typer.testing import CliRunner

import inspect_pipe
from cli import _common
from cli.main import app

runner = CliRunner()


def _commands(cmd=None, path=()):
    """Every leaf command of the app, as its argument path."""
    cmd = cmd or typer.main.get_command(app)
    subs = getattr(cmd, "commands", None)
    if not subs:
        yield path, cmd
        return
    for name, sub in subs.items():
        yield from _commands(sub, (*path, name))


def _choices(param) -> tuple[str, ...]:
    """The choices of an option typed with an Enum (typer's choice), else ()."""
    ann = getattr(getattr(param, "type_descriptor", None), "annotation", None)
    return tuple(m.value for m in ann) if isinstance(ann, type) and issubclass(ann, Enum) else ()


COMMANDS = list(_commands())
CHOICE_OPTIONS = [(p, o) for p, c in COMMANDS for o in c.params if o.opts[0].startswith("-") and _choices(o)]


def test_version_flag_prints_the_installed_distribution_version():
    res = runner.invoke(app, ["--version"])
    assert res.exit_code == 0
    assert res.output.strip() == f"inspect-pipe {version('inspect-pipe')}"
    assert inspect_pipe.__version__ == version("inspect-pipe")


def test_every_command_is_found():
    names = {" ".join(p) for p, _ in COMMANDS}
    assert {"mosaic", "capture", "run", "report", "fly", "doctor", "base-station", "detect run", "detect train"} <= names


@pytest.mark.parametrize("path", [p for p, _ in COMMANDS], ids=lambda p: " ".join(p))
def test_every_command_takes_quiet_and_verbose(path):
    for flag in ("-q", "--quiet", "-v", "--verbose"):
        res = runner.invoke(app, [*path, flag, "--help"])
        assert res.exit_code == 0, (path, flag, res.output)
    help_text = runner.invoke(app, [*path, "--help"], env={"COLUMNS": "300"}).output
    assert "--quiet" in help_text and "--verbose" in help_text


def test_quiet_and_verbose_set_the_console_and_log_level_before_or_after_the_command():
    assert runner.invoke(app, ["doctor", "-q"]).exit_code == 0
    assert _common.console.quiet and _common.log.level == logging.WARNING
    assert runner.invoke(app, ["-v", "doctor"]).exit_code == 0
    assert not _common.console.quiet and _common.log.level == logging.DEBUG
    assert runner.invoke(app, ["doctor"]).exit_code == 0  # each invocation starts at normal
    assert not _common.console.quiet and _common.log.level == logging.INFO


def test_enumerated_options_are_choices():
    found = {(" ".join(p), o.opts[-1]) for p, o in CHOICE_OPTIONS}
    for want in [("run", "--kind"), ("run", "--rerun-from"), ("run", "--scheme"), ("run", "--engine"),
                 ("report", "--scheme"), ("fly", "--autopilot"), ("detect run", "--kind"), ("detect run", "--engine"),
                 ("capture", "--format"), ("mosaic", "--detector"), ("campaign", "--shield"),
                 ("calibrate", "--pattern"), ("calibrate", "--dictionary")]:
        assert want in found, want


def test_choices_match_the_library():
    from inspect_pipe.campaign import SHIELDS
    from inspect_pipe.flight.mavlink_codec import Autopilot
    from inspect_pipe.pipeline import STEP_NAMES
    from inspect_pipe.report import SCHEMES

    by = {(" ".join(p), o.opts[-1]): _choices(o) for p, o in CHOICE_OPTIONS}
    assert by[("campaign", "--shield")] == SHIELDS
    assert set(by[("fly", "--autopilot")]) == {a.value for a in Autopilot}
    assert by[("run", "--rerun-from")] == STEP_NAMES
    assert set(by[("run", "--scheme")]) == set(SCHEMES) == set(by[("report", "--scheme")])


@pytest.mark.parametrize("path,opt", CHOICE_OPTIONS, ids=lambda x: x if isinstance(x, str) else " ".join(x) if isinstance(x, tuple) else x.opts[-1])
def test_a_wrong_choice_is_one_line_and_exit_2(path, opt):
    help_text = runner.invoke(app, [*path, "--help"], env={"COLUMNS": "300"}).output
    flat = "".join(ch for ch in help_text if not ch.isspace() and ch != "│")  # a long list wraps in its column
    assert all(str(c) in flat for c in _choices(opt)), help_text
    res = runner.invoke(app, [*path, opt.opts[-1], "no-such-value"])
    assert res.exit_code == 2
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "no-such-value" in lines[0] and opt.opts[-1] in lines[0], res.output


def test_unknown_option_and_missing_argument_are_one_line():
    for args in (["--bogus"], ["run"], ["mosaic", "x", "--nope"]):
        res = runner.invoke(app, args)
        assert res.exit_code == 2 and len(res.output.strip().splitlines()) == 1 and res.output.startswith("error: "), res.output


def test_stage_progress_draws_rich_bars_on_a_terminal_and_nothing_under_quiet(monkeypatch):
    buf = io.StringIO()
    monkeypatch.setattr(_common, "console", Console(file=buf, force_terminal=True, width=100))
    bar = _common.StageProgress("sweep1")
    bar("register", 3, 13)
    bar("register", 13, 13)
    bar.close()
    out = buf.getvalue()
    assert "sweep1 register" in out and "13/13" in out
    buf.truncate(0)
    buf.seek(0)
    _common.console.quiet = True
    bar = _common.StageProgress("sweep1")
    bar("register", 3, 13)
    bar.close()
    assert buf.getvalue() == ""


def test_verbosity_sets_what_the_librarys_loggers_show(capsys):
    lg = logging.getLogger("inspect_pipe.capture.sources.v4l2")
    try:
        _common.set_verbosity(1)
        lg.debug("shown-debug-line")
        _common.set_verbosity(0)
        lg.debug("hidden-debug-line")
        lg.info("shown-info-line")
        _common.set_verbosity(-1)
        lg.info("hidden-info-line")
        lg.warning("shown-warning-line")
    finally:
        _common.set_verbosity(0)
    err = capsys.readouterr().err
    assert "shown-debug-line" in err and "shown-info-line" in err and "shown-warning-line" in err
    assert "hidden-debug-line" not in err and "hidden-info-line" not in err


def test_capture_draws_a_rich_live_line_on_a_terminal(monkeypatch, tmp_path):
    import cv2
    import numpy as np

    import cli.capture

    buf = io.StringIO()
    term = Console(file=buf, force_terminal=True, width=120)
    monkeypatch.setattr(_common, "console", term)
    monkeypatch.setattr(cli.capture, "console", term)
    folder = tmp_path / "imgs"
    folder.mkdir()
    for k in range(6):
        cv2.imwrite(str(folder / f"f{k:02d}.png"), np.full((40, 60, 3), 30 * k, np.uint8))
    res = runner.invoke(app, ["capture", "--source", f"replay:{folder}", "-o", str(tmp_path / "sw"), "--rate", "4"])  # 1.5 s
    assert res.exit_code == 0, res.output
    out = buf.getvalue()
    assert "frames" in out and "Hz" in out and "drops 0" in out  # the live line, drawn by rich.live
    buf.truncate(0)
    buf.seek(0)
    res = runner.invoke(app, ["capture", "-q", "--source", f"replay:{folder}", "-o", str(tmp_path / "sw2"), "--rate", "50", "--speed", "50"])
    assert res.exit_code == 0 and buf.getvalue() == ""  # -q: no live line


def test_help_prose_is_reflowed_to_the_terminal_width():
    from cli.main import app, reflow

    # GIVEN a help text hard-wrapped in the source, with an examples block
    text = "First line.\n\nSome prose\nwrapped at 100 columns\nin the source.\n\nExamples:\n\n  inspect-pipe a\n  inspect-pipe b\n"
    # THEN prose paragraphs become one line each (the terminal wraps them) and examples keep their lines
    assert reflow(text) == "First line.\n\nSome prose wrapped at 100 columns in the source.\n\nExamples:\n\n  inspect-pipe a\n  inspect-pipe b"
    # AND every command's help, as registered, has no hard-wrapped prose paragraph left
    for cmd in app.registered_commands:
        for para in (cmd.help or "").split("\n\n"):
            lines = para.split("\n")
            if len(lines) > 1:
                assert any(ln.startswith((" ", "- ", "* ", "inspect-pipe ")) for ln in lines), (cmd.name, para[:80])
