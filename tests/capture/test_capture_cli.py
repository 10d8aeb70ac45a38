"""``inspect-pipe capture``, ``doctor`` and ``fly --sweep``: exit codes and one-line errors."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from cli.main import app
from inspect_pipe.capture import read_sweep

from .conftest import write_scenario


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_capture_from_the_simulator(tmp_path):
    sc = write_scenario(tmp_path / "sc", duration_s=4.0)
    res = run("capture", "--source", f"sim:{sc}", "-o", tmp_path / "sw", "--duration", 2, "--vessel", "MV Test", "--frame-spacing", 0.8)
    assert res.exit_code == 0, res.output
    s = read_sweep(tmp_path / "sw")
    assert len(s.frames) == 20 and s.complete and s.meta.survey["vessel"] == "MV Test" and s.meta.survey["frame_spacing_m"] == 0.8
    assert "20 frames" in res.output and "drops 0" in res.output
    # the live mosaic ran beside the writer; this flight never turns inspection mode on, so it mosaicked nothing
    assert "live mosaic: waiting for inspection mode" in res.output, res.output
    res = run("capture", "--source", f"sim:{sc}", "-o", tmp_path / "sw2", "--duration", 1, "--no-live-mosaic")
    assert res.exit_code == 0 and "10 frames" in res.output and "live mosaic" not in res.output, res.output


def test_capture_shows_the_live_mosaic_of_the_inspection(tmp_path):
    sc = write_scenario(tmp_path / "sc", duration_s=6.0, operator=[
        {"t": 0.5, "button": "takeoff"}, {"t": 3.0, "button": "inspection_mode_on"},
        {"t": 3.5, "stick": {"vx": 0, "vy": -0.2, "vz": 0, "yaw_rate": 0}}])
    res = run("capture", "--source", f"sim:{sc}", "-o", tmp_path / "sw")
    assert res.exit_code == 0, res.output
    # the last line: what the inspection covered, the gaps, the frames placed of those taken in inspection mode
    live = [line for line in res.output.splitlines() if line.startswith("live mosaic:")]
    assert len(live) == 1 and "% covered" in live[0] and "gap" in live[0], res.output
    placed, taken = map(int, live[0].split(" frames placed")[0].rsplit(" ", 1)[1].split("/"))
    assert 20 <= taken <= 32 and placed >= taken - 2, live[0]


def test_fly_writes_the_sweep_of_the_flight(tmp_path):
    sc = write_scenario(tmp_path / "sc", duration_s=4.0)
    res = run("fly", "--scenario", sc, "--log", tmp_path / "log.jsonl", "--sweep", tmp_path / "sw")
    assert res.exit_code == 0, res.output
    s = read_sweep(tmp_path / "sw")
    log = [json.loads(line) for line in (tmp_path / "log.jsonl").read_text().splitlines()[1:]]
    assert len(s.frames) == 40 and s.meta.simulation["scenario"] == "tiny_wall"
    assert "live mosaic: waiting for inspection mode" in res.output, res.output  # no inspection mode in this flight
    # the frame's true position is the log's, interpolated at mid-exposure
    f = s.frames[20]
    k = int(f.t_s * 50)
    a, b = log[k], log[k + 1]
    w = (f.t_s - a["t"]) / (b["t"] - a["t"])
    z = a["pos_true"][2] + w * (b["pos_true"][2] - a["pos_true"][2])
    assert abs(f.position_true_m[2] - z) < 1e-3


def test_bad_source_and_bad_sweeps_are_one_line_exit_2(tmp_path, sweep_copy):
    res = run("capture", "--source", "webcam", "-o", tmp_path / "x")
    assert res.exit_code == 2 and res.output.count("\n") == 1 and "--source webcam: unknown source" in res.output
    res = run("capture", "--source", "v4l2:/dev/video42", "-o", tmp_path / "x")
    assert res.exit_code == 2 and "/dev/video42: no such device" in res.output and "Traceback" not in res.output
    # a manifest naming a missing image: the readable part is replayed, then a one-line error
    (sweep_copy / "images" / "000010.png").unlink()
    res = run("capture", "--source", f"replay:{sweep_copy}", "-o", tmp_path / "re", "--speed", 10)
    assert res.exit_code == 2 and "000010.png" in res.output.splitlines()[-1]
    re = read_sweep(tmp_path / "re")  # every readable frame was replayed (or counted as a writer drop)
    assert len(re.frames) + re.summary["dropped_backpressure"] == len(read_sweep(sweep_copy).frames)
    assert re.summary["dropped_backpressure"] <= 2
    meta = json.loads((sweep_copy / "sweep.json").read_text())
    meta["format"] = "inspect_pipe.sweep/9"
    (sweep_copy / "sweep.json").write_text(json.dumps(meta))
    res = run("capture", "--source", f"replay:{sweep_copy}", "-o", tmp_path / "re2")
    assert res.exit_code == 2 and "unknown format version" in res.output and res.output.count("\n") == 1
    res = run("capture", "--source", f"replay:{sweep_copy}", "-o", sweep_copy)
    assert res.exit_code == 2


def test_doctor_lists_every_backend(tmp_path):
    res = run("doctor")
    assert res.exit_code == 0
    names = [line.split()[2] for line in res.output.splitlines()]
    assert {"v4l2", "ids", "replay", "sim", "mavlink", "mavlink-serial"} <= set(names)
    assert all(line[:3] in ("ok ", "no ") for line in res.output.splitlines())


def test_doctor_says_whether_a_serial_autopilot_link_can_open(monkeypatch):
    # GIVEN pymavlink but no pyserial (the [serial] extra is not in the default install)
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "serial" else real(name, *a))
    from inspect_pipe.capture import backends

    row = next(b for b in backends() if b.name == "mavlink-serial")
    # THEN the serial row is not usable and names the extra, while udp/tcp links stay usable
    assert not row.usable and "inspect-pipe[serial]" in row.why
    assert next(b for b in backends() if b.name == "mavlink").usable


def test_a_cut_video_is_one_line_without_ffmpegs_own_chatter(tmp_path):
    # GIVEN an MP4 cut before its index (a copy interrupted): FFmpeg prints "moov atom not found" on its own
    import os
    import subprocess
    import sys

    import cv2
    import numpy as np

    vw = cv2.VideoWriter(str(tmp_path / "v.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (64, 48))
    for i in range(20):
        vw.write(np.full((48, 64, 3), 10 * i, np.uint8))
    vw.release()
    (tmp_path / "cut.mp4").write_bytes((tmp_path / "v.mp4").read_bytes()[:1000])
    env = {k: v for k, v in os.environ.items() if k != "OPENCV_FFMPEG_LOGLEVEL"}
    # WHEN the command replays it (a real process: the console script's environment, not the test runner's)
    res = subprocess.run([sys.executable, "-m", "cli.main", "capture", "--source", f"replay:{tmp_path / 'cut.mp4'}",
                          "-o", str(tmp_path / "s")], capture_output=True, text=True, env=env, timeout=120)
    # THEN exactly one line, the command's
    lines = [ln for ln in (res.stdout + res.stderr).splitlines() if ln.strip()]
    assert res.returncode == 2 and len(lines) == 1 and lines[0].startswith("error:") and "cut.mp4" in lines[0], lines
