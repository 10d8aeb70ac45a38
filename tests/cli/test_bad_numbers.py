"""Nonsense numbers and outputs on the command line: one line, exit 2, nothing written (the CLI audit of
2026-11-29 found each of these ending in a traceback, a hang, a clobbered device or exit 0)."""

from __future__ import annotations

import os
import shutil
import stat
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.main import app

FIXTURE = Path(__file__).resolve().parent.parent / "fixtures" / "mosaic" / "synth_rust_mini"
runner = CliRunner()


@pytest.fixture
def frames(tmp_path: Path) -> Path:
    d = tmp_path / "frames"
    d.mkdir()
    for p in sorted(FIXTURE.glob("*.jpg"))[:4]:
        shutil.copy(p, d / p.name)
    return d


@pytest.mark.parametrize("args, words", [
    (["mosaic", "{frames}", "--focal-px", "nan"], "--focal-px nan: must be a finite number"),
    (["mosaic", "{frames}", "--focal-px", "inf"], "--focal-px inf: must be a finite number"),
    (["mosaic", "{frames}", "--seed", "-1"], "--seed"),
    (["mosaic", "{frames}", "--focal-px", "1e30"], "--focal-px 1e+30: must be positive and at most 1e+06 px"),
    (["run", "{frames}", "--area-m", "nan", "--m-per-px", "0.003"], "--area-m nan: must be a finite number"),
    (["run", "{frames}", "--area-m", "1e-9", "--m-per-px", "0.003"], "below 0.1 m"),
    (["run", "{frames}", "--m-per-px", "-1"], "--m-per-px: -1 is not positive"),
    (["run", "{frames}", "--m-per-px", "0.003", "--focal-px", "-1"], "--focal-px: -1 is not positive"),
    (["run", "{frames}", "--m-per-px", "0.003", "--keyframe-spacing", "-1"], "--keyframe-spacing: -1 is negative"),
    (["capture", "--source", "replay:{frames}", "--frames", "0"], "--frames 0: must be at least 1"),
    (["capture", "--source", "replay:{frames}", "--exposure", "-1"], "--exposure -1.0: must be in (0, 1] s"),
    (["capture", "--source", "replay:{frames}", "--frame-spacing", "-1"], "--frame-spacing -1.0: must be > 0 m"),
])
def test_a_nonsense_number_is_one_line_exit_2_and_writes_nothing(tmp_path, frames, args, words):
    out = tmp_path / "out"
    res = runner.invoke(app, [a.replace("{frames}", str(frames)) for a in args] + ["-o", str(out)])
    assert res.exit_code == 2, res.output
    assert words in res.output and "Traceback" not in res.output
    assert not out.exists()


def test_an_output_that_is_a_device_is_refused_not_replaced(tmp_path):
    # GIVEN an output path that is a named pipe (a device such as /dev/full behaves the same)
    from inspect_pipe._files import atomic_write

    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    # WHEN a result is written there THEN it is refused, and the pipe is still a pipe
    with pytest.raises(OSError, match="not a regular file"):
        atomic_write(fifo, b"x")
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert not any(p.name.startswith(".pipe.") for p in tmp_path.iterdir())  # no temporary left beside it


def test_training_into_a_directory_is_refused_before_it_starts(tmp_path):
    res = runner.invoke(app, ["detect", "train", str(tmp_path), "-o", str(tmp_path)])
    assert res.exit_code == 2 and "is a directory" in res.output
