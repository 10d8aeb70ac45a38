"""Live vehicle state during capture: the autopilot's telemetry, its clock mapped onto the host's,
interpolated at each frame's mid-exposure; a dead link gives frames with state null."""

from __future__ import annotations

import json
import math
import socket
import threading
import time

import numpy as np
import pytest

pytest.importorskip("pymavlink")
from pymavlink.dialects.v20 import common as C  # noqa: E402

from inspect_pipe.capture._vehicle_feed import AutopilotStateTracker  # noqa: E402

MAV = C.MAVLink(None, srcSystem=1, srcComponent=1)


def _msgs(boot_s: float, x: float, y: float, yaw_ned: float, vx=0.0, vy=0.0, front_m: float | None = None):
    ms = int(round(boot_s * 1000))
    out = [C.MAVLink_attitude_message(ms, 0.0, 0.0, yaw_ned, 0, 0, 0),
           C.MAVLink_local_position_ned_message(ms, x, y, -1.5, vx, vy, 0.0)]
    if front_m is not None:
        out.append(C.MAVLink_distance_sensor_message(ms, 20, 700, int(round(front_m * 100)), 1, 0, 0, 0))
    return out


def test_state_is_interpolated_at_mid_exposure_not_the_last_message():
    # GIVEN an autopilot (booted 100 s before the host clock's zero) flying north at 1 m/s, 20 Hz,
    # whose messages arrive 30 ms after they are stamped
    tr = AutopilotStateTracker()
    for k in range(40):
        b = 100.0 + 0.05 * k
        for m in _msgs(b, x=0.05 * k, y=0.0, yaw_ned=0.0, vx=1.0, front_m=2.0 - 0.05 * k):
            tr.on_message(m, host_s=b - 100.0 + 0.03)
    # WHEN the state is asked for between two samples (host 1.025 s = boot 101.025 s)
    s = tr.state_at(1.025)
    # THEN the clock offset is the least delay seen (arrival bound), and the position lies between
    # the samples (1.025 m forward, not 1.0 or 1.05), the front range interpolated too
    assert tr.clock.offset_s == pytest.approx(-100.0 + 0.03, abs=1e-6)
    assert s.position_m[0] == pytest.approx(1.025 - 0.03, abs=1e-3)
    assert s.dist_front_m == pytest.approx(2.0 - (1.025 - 0.03), abs=1e-3)
    assert s.height_m == pytest.approx(1.5)


def test_timesync_beats_the_arrival_envelope():
    tr = AutopilotStateTracker()
    tr.on_message(_msgs(50.0, 0, 0, 0.0)[0], host_s=0.2)  # envelope: offset <= -49.8
    # a TIMESYNC round trip of 4 ms: sent at host 1.000, answered at autopilot 50.802, back at 1.004
    tr.clock.observe_timesync(int(50.802e9), 1.000, 1.004)
    assert tr.clock.method == "TIMESYNC"
    assert tr.clock.offset_s == pytest.approx(1.002 - 50.802, abs=1e-9)
    assert tr.clock.uncertainty_s == pytest.approx(0.002)


def test_positions_are_in_the_takeoff_frame():
    # GIVEN the vehicle took off heading east (NED yaw +90 deg) from the local origin
    tr = AutopilotStateTracker()
    yaw = math.pi / 2
    for k, (x, y) in enumerate([(0.0, 0.0), (0.0, 1.0), (-1.0, 1.0)]):
        for m in _msgs(10.0 + k, x, y, yaw):
            tr.on_message(m, host_s=k)
    # THEN moving 1 m east is 1 m forward; then 1 m south is 1 m to the right (y = -1 in x-fwd/y-left)
    fwd = tr.state_at(1.0)
    assert fwd.position_m[:2] == pytest.approx((1.0, 0.0), abs=1e-6)
    right = tr.state_at(2.0)
    assert right.position_m == pytest.approx((1.0, -1.0, 1.5), abs=1e-6)  # 1.5 m up (NED z = -1.5)


def test_a_gap_in_telemetry_gives_no_state():
    tr = AutopilotStateTracker(max_gap_s=0.5, max_extrapolate_s=0.1)
    for b in (1.0, 1.05, 3.0, 3.05):
        for m in _msgs(b, b, 0.0, 0.0):
            tr.on_message(m, host_s=b)
    assert tr.state_at(1.02) is not None
    assert tr.state_at(2.0) is None  # 2 s without a fix: the link was down
    assert tr.state_at(3.12) is not None  # 70 ms past the newest fix: carried with its velocity
    assert tr.state_at(3.5) is None


def test_capture_stamps_frames_from_a_live_autopilot_and_survives_its_death(tmp_path):
    from inspect_pipe.capture import CaptureConfig, MonotonicClock, run_capture
    from inspect_pipe.capture._vehicle_feed import MavlinkStateFeed
    from inspect_pipe.capture.sources.replay import ReplaySource
    import cv2

    from bench._faults import FakeAutopilot

    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(40):
        cv2.imwrite(str(frames / f"{i:03d}.png"), np.full((48, 64, 3), i * 5, np.uint8))
    # GIVEN an autopilot streaming to a port the feed listens on
    port_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    port_sock.bind(("127.0.0.1", 0))
    port = port_sock.getsockname()[1]
    port_sock.close()
    ap = FakeAutopilot(("127.0.0.1", port))  # the fault bench's PX4-like sender: x = 0.5 t north at 50 Hz
    try:
        clock = MonotonicClock()
        feed = MavlinkStateFeed(f"udp:127.0.0.1:{port}", clock=clock.now)
        time.sleep(0.3)
        # WHEN 4 s of frames are captured at 10 Hz and the autopilot falls silent after 2 s
        killer = threading.Timer(2.0, ap.die.set)
        killer.start()
        res = run_capture(ReplaySource(str(frames), clock=clock, rate_hz=10.0), tmp_path / "sweep", clock=clock,
                          config=CaptureConfig(rate_hz=10.0, duration_s=3.5), state_feed=feed,
                          sweep_extra={"odometry_frame": "takeoff", "vehicle": feed.describe()})
        killer.cancel()
        desc = feed.describe()
        feed.close()
    finally:
        ap.close()
    lines = [json.loads(x) for x in (tmp_path / "sweep" / "frames.jsonl").read_text().splitlines()]
    with_state = [x for x in lines if x["state"] is not None]
    without = [x for x in lines if x["state"] is None]
    # THEN every frame was written; the early ones carry the state, later ones state null, counted
    assert len(lines) == res.frames_written >= 30
    assert len(with_state) >= 12 and len(without) >= 10 and res.frames_without_state == len(without)
    assert desc["clock"]["method"] == "TIMESYNC"
    complete = json.loads((tmp_path / "sweep" / "COMPLETE").read_text())["summary"]
    assert complete["vehicle"]["clock"]["method"] == "TIMESYNC" and complete["vehicle"]["clock"]["offset_s"] is not None
    # positions advance at the autopilot's 0.5 m/s between consecutive stamped frames
    xs = np.array([x["state"]["position_m"][0] for x in with_state])
    ts = np.array([x["t_s"] for x in with_state])
    speed = np.polyfit(ts, xs, 1)[0]
    assert speed == pytest.approx(0.5, abs=0.03)


def test_a_link_that_never_answers_is_one_line_naming_the_url():
    from inspect_pipe.capture._vehicle_feed import MavlinkStateFeed
    from inspect_pipe.errors import InputError

    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    with pytest.raises(InputError) as err:
        MavlinkStateFeed(f"udp:127.0.0.1:{port}", heartbeat_timeout_s=0.3)
    assert str(err.value).startswith(f"udp:127.0.0.1:{port}: no heartbeat") and "\n" not in str(err.value)


def test_capture_cli_refuses_an_unknown_vehicle(tmp_path):
    from typer.testing import CliRunner

    from cli.main import app

    frames = tmp_path / "f"
    frames.mkdir()
    import cv2

    cv2.imwrite(str(frames / "0.png"), np.zeros((8, 8, 3), np.uint8))
    r = CliRunner().invoke(app, ["capture", "--source", f"replay:{frames}", "-o", str(tmp_path / "s"), "--vehicle", "carrier-pigeon"])
    assert r.exit_code == 2
    assert "--vehicle carrier-pigeon: unknown vehicle" in r.output
    assert not (tmp_path / "s").exists()
