"""Fault injection, the suite's share (the bench runs hundreds: bench/bench_faults.py): SIGKILL in
the middle of a mosaic, a full and a read-only output disk, the camera vanishing mid-capture and
the MAVLink link dying mid-capture. For each: no file half-written, the rerun finishes, and its
result equals the uninterrupted run's."""

from __future__ import annotations

import numpy as np
import pytest

from bench import _faults as F


@pytest.fixture(scope="module")
def fx(tmp_path_factory):
    return F.build(tmp_path_factory.mktemp("faults"), duration_s=4.0, only=("capture", "mosaic"))


def _check(r: F.Result):
    assert r.injected, r
    assert r.recovered and r.lost == 0, r


def test_sigkill_mid_mosaic_then_rerun_equals_uninterrupted(fx, tmp_path):
    # The reference duration was timed once; on a machine that has since become faster a late
    # moment can fall after the command finished (not injected): draw again, earlier, a few times.
    rng = np.random.default_rng(4)
    for attempt in range(4):
        r = F.kill(fx, "mosaic", tmp_path / f"k{attempt}", rng, frac=(0.05, 0.95 / 2 ** attempt))
        if r.injected:
            break
    _check(r)


@pytest.mark.parametrize("read_only", [False, True])
def test_full_or_read_only_disk_is_one_line_then_rerun_equals(fx, tmp_path, read_only):
    if not F.can_mount(tmp_path):
        pytest.skip("mounting a small tmpfs needs root")
    rng = np.random.default_rng(5)
    r = F.disk_full(fx, "mosaic", tmp_path / "d", rng, read_only=read_only)
    _check(r)
    assert ("read-only" if read_only else "no space left") in r.detail.lower(), r.detail


def test_camera_vanishing_keeps_every_frame_before(fx, tmp_path):
    _check(F.camera_lost(fx, tmp_path / "c", np.random.default_rng(6)))


def test_link_dying_mid_capture_keeps_every_frame(fx, tmp_path):
    pytest.importorskip("pymavlink")
    r = F.link_died(fx, tmp_path / "l", np.random.default_rng(7))
    _check(r)
    assert "0 without state" not in r.detail, r.detail


def test_enospc_in_the_atomic_write_helper_names_the_file_and_leaves_nothing(tmp_path, monkeypatch):
    # without root (no tmpfs): ENOSPC injected in the one atomic-write helper
    import errno
    import os
    import types

    from cli._common import os_error_line
    from inspect_pipe import _files

    def full(fd, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    proxy = types.SimpleNamespace(**{k: getattr(os, k) for k in dir(os) if not k.startswith("__")})
    proxy.write = full
    monkeypatch.setattr(_files, "os", proxy)
    target = tmp_path / "mosaic.json"
    target.write_text("old, whole\n")
    with pytest.raises(OSError) as err:
        _files.write_json(target, {"format": "x"})
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(target)
    assert target.read_text() == "old, whole\n" and [p.name for p in tmp_path.iterdir()] == ["mosaic.json"]
    line = os_error_line(err.value)
    assert line.startswith(f"{target}: no space left on device (free space") and "\n" not in line
