"""``inspect-pipe import`` and ``fly --tlog``: a simulated flight left behind as a real drone leaves it
(JPEGs with a shifted EXIF clock + the MAVLink telemetry log), imported and checked against the
simulator's own sweep; the flight-log readers on real PX4 ULogs; bad input."""

from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from inspect_pipe.capture._sweep import read_sweep
from inspect_pipe.errors import InputError
from inspect_pipe.importer import open_footage, read_flight_log, resample, write_drone_footage
from inspect_pipe.importer._footage import FootageFrame
from inspect_pipe.ship import hold_from_takeoff, parse_survey_plan

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "import"
SHARED_ULOGS = Path(__file__).resolve().parents[3] / "shared" / "data" / "flight_logs" / "px4_ulog"
CLOCK_OFFSET_S = -2.437  # the camera's clock is this far behind... ahead of the log (camera minus log)


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """A 12 s simulated flight: its own sweep, its tlog, and its frames as a drone's JPEGs."""
    d = tmp_path_factory.mktemp("flight")
    res = CliRunner().invoke(app, ["fly", "--scenario", str(FIXTURES / "short_sweep.yaml"), "--log", str(d / "f.jsonl"),
                                   "--sweep", str(d / "sweep"), "--tlog", str(d / "f.tlog")])
    assert res.exit_code == 0, res.output
    n = write_drone_footage(d / "sweep", d / "DCIM", clock_offset_s=CLOCK_OFFSET_S, utc_offset_h=2.0)
    assert n == 120
    cam = read_sweep(d / "sweep").meta.camera
    fs = cv2.FileStorage(str(d / "camera.yaml"), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", cam.width)
    fs.write("image_height", cam.height)
    fs.write("camera_matrix", np.asarray(cam.K, float))
    fs.write("distortion_coefficients", np.asarray(cam.dist, float).reshape(1, -1))
    fs.release()
    return d


def test_fly_tlog_streams_what_an_autopilot_streams(flight):
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(flight / "f.tlog"), dialect="common")
    counts: dict[str, int] = {}
    first_time = None
    while (m := conn.recv_match()) is not None:
        counts[m.get_type()] = counts.get(m.get_type(), 0) + 1
        if m.get_type() == "SYSTEM_TIME" and first_time is None:
            first_time = m
    # 12 s at the 50 Hz control tick; range sensors at 10 Hz, four of them; 1 Hz heartbeat and clock
    assert counts["ATTITUDE"] == counts["LOCAL_POSITION_NED"] == 601
    assert counts["DISTANCE_SENSOR"] == 4 * 121
    assert counts["HEARTBEAT"] == counts["SYSTEM_TIME"] == 13
    assert first_time.time_unix_usec == 1_700_000_000_000_000 and first_time.time_boot_ms == 0
    assert not (flight / "f.tlog.part").exists()


def test_import_finds_the_camera_clock_offset_and_interpolates_the_state(flight, tmp_path):
    out = tmp_path / "imported"
    res = CliRunner().invoke(app, ["import", str(flight / "DCIM"), "--log", str(flight / "f.tlog"), "-o", str(out),
                                   "--camera", str(flight / "camera.yaml")])
    assert res.exit_code == 0, res.output
    doc = json.loads((out / "sweep.json").read_text())
    ta = doc["time_alignment"]
    assert ta["method"] == "image_motion_xcorr"
    assert abs(ta["camera_clock_offset_s"] - CLOCK_OFFSET_S) < 0.020, ta
    assert ta["correlation"] > 0.9 and ta["confidence"] > 0.5  # doctor flags below 0.5
    assert doc["camera"]["dist"][0] == pytest.approx(-0.06)
    direct = read_sweep(flight / "sweep")
    imp = read_sweep(out, strict=True)
    assert imp.complete and len(imp) >= 115
    assert imp.meta.odometry_frame == "takeoff"
    # a survey plan's take-off tie puts the imported positions in the hold, where the direct sweep has them
    plan = parse_survey_plan({
        "format": "inspect_pipe.survey_plan/1", "vessel": {"name": "MV Sim"}, "survey": {"type": "test", "date": "2026-11-20"},
        "compartment": {"name": "hold"}, "hold": {"aft_bulkhead_frame": 100, "frame_spacing_m": 0.8, "length_m": 12, "width_m": 10},
        "wall": "fore_transverse_bulkhead", "takeoff": {"position_m": [10.5, 0.5, 0.0], "heading_deg": 0}}, "plan.yaml")
    hold = hold_from_takeoff(plan, np.array([f.position_m for f in imp.frames]))
    start = np.array([10.5, 0.5, 0.0])  # the scenario's take-off point: the log's local origin
    assert np.allclose(hold, np.array([f.position_m for f in imp.frames]) + start, atol=1e-3)
    by_time = {round(f.t_s, 3): f for f in direct.frames}
    errs, dist_errs, fsm_same = [], [], []
    for f in imp.frames:
        src = int(f.raw["source_frame"][4:8]) - 1  # DJI_0001.JPG is the direct sweep's frame 0
        g = direct.frames[src]
        assert abs(f.t_s - g.t_s) < 0.02  # the frame's time on the log's clock, after the offset
        errs.append(np.linalg.norm(np.asarray(f.position_m) + start * [1, 1, 0] - np.asarray(g.position_m)))
        if f.dist_front_m is not None and g.dist_front_m is not None:
            dist_errs.append(abs(f.dist_front_m - g.dist_front_m))
        fsm_same.append(f.fsm == {"descending": "flying"}.get(g.fsm, g.fsm))
    assert by_time  # the direct sweep is on the same clock
    assert np.mean(fsm_same) >= 0.95  # the landed state is streamed at 5 Hz: transitions within 0.2 s
    # the state at each frame's instant (interpolated, not the last sample: 50 Hz log, 0.3 m/s)
    assert np.percentile(errs, 95) < 0.01, np.percentile(errs, 95)
    assert np.median(dist_errs) < 0.01


def test_time_offset_overrides_the_alignment(flight, tmp_path):
    out = tmp_path / "given"
    res = CliRunner().invoke(app, ["import", str(flight / "DCIM"), "--log", str(flight / "f.tlog"), "-o", str(out), "--time-offset", "-2.5"])
    assert res.exit_code == 0, res.output
    ta = json.loads((out / "sweep.json").read_text())["time_alignment"]
    assert ta == {"camera_clock_offset_s": -2.5, "method": "given", "confidence": None}


def test_video_footage_takes_frame_times_from_the_container(flight, tmp_path):
    imgs = sorted((flight / "DCIM").glob("*.JPG"))[:40]
    first = cv2.imread(str(imgs[0]))
    video = tmp_path / "clip.avi"
    vw = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (first.shape[1], first.shape[0]))
    for p in imgs:
        vw.write(cv2.imread(str(p)))
    vw.release()
    fo = open_footage(video, video_start="2023-11-14T22:13:20.500Z")
    assert len(fo.frames) == 40 and fo.kind == "video"
    t = np.array([f.t_camera_s for f in fo.frames])
    assert t[0] == pytest.approx(1_700_000_000.5) and np.diff(t) == pytest.approx(1 / 30, abs=1e-3)
    kept = resample(fo.frames, 10.0)  # 30 fps -> every third frame
    assert [f.video_index for f in kept] == list(range(0, 40, 3))
    with pytest.raises(InputError, match="no creation time"):
        open_footage(video)


def test_resample_keeps_slow_footage_whole_and_thins_fast_footage():
    fast = [FootageFrame(100 + k / 25, f"f{k}") for k in range(50)]
    kept = resample(fast, 10.0)
    gaps = np.diff([f.t_camera_s for f in kept])
    assert len(kept) == 21 and np.all((gaps >= 0.08 - 1e-9) & (gaps <= 0.12 + 1e-9))  # grid 100.0 .. 102.0 s
    slow = [FootageFrame(100 + k * 2.0, f"f{k}") for k in range(5)]
    assert resample(slow, 10.0) == slow


def test_every_shared_ulog_reads_in_two_seconds():
    logs = sorted(SHARED_ULOGS.glob("*.ulg")) or [FIXTURES / "sample_appended_multiple.ulg"]
    for p in logs:
        t0 = time.perf_counter()
        tr = read_flight_log(p)
        assert time.perf_counter() - t0 <= 2.0, p
        assert len(tr.t_pos) > 50 and len(tr.t_att) > 50 and tr.duration_s > 5
        assert np.allclose(np.linalg.norm(tr.quat, axis=1), 1.0)


def test_ulog_fixture_reads_position_attitude_and_landed_state():
    tr = read_flight_log(FIXTURES / "sample_appended_multiple.ulg")
    assert tr.kind == "ulog" and len(tr.t_pos) == 95 and len(tr.t_att) == 306
    assert tr.start_s == pytest.approx(12.263164) and tr.end_s == pytest.approx(21.803961)
    assert tr.landed is not None and tr.utc_offset_s is None  # no GPS in this log


def test_a_ulog_without_the_local_position_topic_is_named(flight, tmp_path):
    # the same real log with the topic renamed everywhere (its format and subscription): a valid
    # ULog that lacks vehicle_local_position
    raw = (FIXTURES / "sample_appended_multiple.ulg").read_bytes()
    bad = tmp_path / "no_lpos.ulg"
    bad.write_bytes(raw.replace(b"vehicle_local_position", b"vehicle_local_positiox"))
    msg = _run_bad(tmp_path, flight / "DCIM", bad)
    assert "no vehicle_local_position topic" in msg and str(bad) in msg


def _run_bad(tmp_path, frames, log, *extra):
    out = tmp_path / "never"
    res = CliRunner().invoke(app, ["import", str(frames), "--log", str(log), "-o", str(out), *extra])
    assert res.exit_code == 2, res.output
    assert len(res.output.strip().splitlines()) == 1, res.output
    assert "Traceback" not in res.output
    assert not out.exists() and not list(tmp_path.glob(".never*"))  # nothing half-written
    return res.output


def test_images_without_timestamps(flight, tmp_path):
    plain = tmp_path / "plain"
    plain.mkdir()
    cv2.imwrite(str(plain / "a.jpg"), np.zeros((48, 64, 3), np.uint8))
    msg = _run_bad(tmp_path, plain, flight / "f.tlog")
    assert "a.jpg" in msg and "DateTimeOriginal" in msg


def test_a_log_that_does_not_cover_the_frames(flight, tmp_path):
    msg = _run_bad(tmp_path, flight / "DCIM", flight / "f.tlog", "--time-offset", "30")
    assert "f.tlog" in msg and "frames fall inside" in msg
    later = tmp_path / "later"
    write_drone_footage(flight / "sweep", later, clock_offset_s=3600.0)
    msg = _run_bad(tmp_path, later, flight / "f.tlog")
    assert "f.tlog" in msg and "covers" in msg
    # a camera an hour off (its time zone set wrong): --time-offset brings it in
    res = CliRunner().invoke(app, ["import", str(later), "--log", str(flight / "f.tlog"), "-o", str(tmp_path / "hour"), "--time-offset", "3600"])
    assert res.exit_code == 0, res.output
    assert len(read_sweep(tmp_path / "hour").frames) >= 115


def test_a_log_cut_short_is_named_not_the_images(flight, tmp_path):
    # GIVEN the flight's tlog cut to its first 30 % (the download stopped early)
    raw = (flight / "f.tlog").read_bytes()
    cut = tmp_path / "cut.tlog"
    cut.write_bytes(raw[: int(0.3 * len(raw))])
    msg = _run_bad(tmp_path, flight / "DCIM", cut)
    # THEN the line names the log and says how few frames it can hold at any offset searched
    assert str(cut) in msg and "frames fall inside it at any camera clock offset searched" in msg and "DCIM" not in msg


def test_garbled_bytes_in_a_tlog_are_skipped_and_said(flight, tmp_path):
    # GIVEN the flight's tlog with 400 random bytes written over its middle
    raw = bytearray((flight / "f.tlog").read_bytes())
    mid = len(raw) // 2
    raw[mid:mid + 400] = bytes(np.random.default_rng(5).integers(0, 256, 400, dtype=np.uint8))
    bad = tmp_path / "garbled.tlog"
    bad.write_bytes(bytes(raw))
    res = CliRunner().invoke(app, ["import", str(flight / "DCIM"), "--log", str(bad), "-o", str(tmp_path / "sw")])
    # THEN the import succeeds, says the log had garbled stretches, and the sweep's meta records them
    assert res.exit_code == 0, res.output
    assert f"{bad}: 1 garbled stretch(es) skipped" in res.output
    assert read_sweep(tmp_path / "sw").meta.source["flight_log"]["skipped_garbled_stretches"] == 1
    # AND the log as it was has none
    res = CliRunner().invoke(app, ["import", str(flight / "DCIM"), "--log", str(flight / "f.tlog"), "-o", str(tmp_path / "sw2")])
    assert res.exit_code == 0 and "garbled stretch" not in res.output
    assert "skipped_garbled_stretches" not in read_sweep(tmp_path / "sw2").meta.source["flight_log"]


def test_a_video_the_decoder_refuses(flight, tmp_path):
    bad = tmp_path / "broken.mp4"
    bad.write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 20)
    msg = _run_bad(tmp_path, bad, flight / "f.tlog", "--video-start", "2023-11-14T22:13:20Z")
    assert "broken.mp4" in msg and "decoder" in msg


@pytest.mark.parametrize("content", [b"", b"\xfd\x09garbage" * 300, bytes(np.random.default_rng(1).integers(0, 256, 5000, dtype=np.uint8))])
def test_an_empty_or_garbled_tlog(flight, tmp_path, content):
    bad = tmp_path / "bad.tlog"
    bad.write_bytes(content)
    msg = _run_bad(tmp_path, flight / "DCIM", bad)
    assert "bad.tlog" in msg


def test_a_tlog_without_attitude_is_named(flight, tmp_path):
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(flight / "f.tlog"), dialect="common")
    kept = bytearray()
    while (m := conn.recv_match()) is not None:
        if m.get_type() != "ATTITUDE":
            kept += int(m._timestamp * 1e6).to_bytes(8, "big") + m.get_msgbuf()
    bad = tmp_path / "no_att.tlog"
    bad.write_bytes(bytes(kept))
    msg = _run_bad(tmp_path, flight / "DCIM", bad)
    assert "no ATTITUDE (attitude) in the log" in msg


def test_a_dataflash_log_gives_the_same_state_as_the_tlog(flight, tmp_path):
    from ._dataflash import tlog_to_dataflash

    tlog_to_dataflash(flight / "f.tlog", tmp_path / "f.bin")
    df, tl = read_flight_log(tmp_path / "f.bin"), read_flight_log(flight / "f.tlog")
    assert df.kind == "dataflash" and df.utc_source == "GPS week time"
    assert df.utc_offset_s == pytest.approx(tl.utc_offset_s, abs=1e-3)
    assert np.allclose(df.pos_ned, tl.pos_ned, atol=1e-4) and np.allclose(np.abs(df.quat @ tl.quat.T).diagonal(), 1.0, atol=1e-6)
    assert set(df.ranges) == {"forward", "left", "right", "down"}
    out = tmp_path / "from_bin"
    res = CliRunner().invoke(app, ["import", str(flight / "DCIM"), "--log", str(tmp_path / "f.bin"), "-o", str(out)])
    assert res.exit_code == 0, res.output
    ta = json.loads((out / "sweep.json").read_text())["time_alignment"]
    assert abs(ta["camera_clock_offset_s"] - CLOCK_OFFSET_S) < 0.020, ta


def test_a_garbled_dataflash_log_is_one_line(flight, tmp_path):
    bad = tmp_path / "junk.bin"
    bad.write_bytes(bytes(np.random.default_rng(2).integers(0, 256, 4000, dtype=np.uint8)))
    msg = _run_bad(tmp_path, flight / "DCIM", bad)
    assert "junk.bin" in msg and "DataFlash" in msg


def test_tlog_is_for_headless_flights(tmp_path):
    res = CliRunner().invoke(app, ["fly", "--scenario", str(FIXTURES / "short_sweep.yaml"), "--log", str(tmp_path / "f.jsonl"),
                                   "--tlog", str(tmp_path / "f.tlog"), "--mavlink-sim", "udp:127.0.0.1:14999"])
    assert res.exit_code == 2 and "--tlog" in res.output and len(res.output.strip().splitlines()) == 1
    assert not (tmp_path / "f.tlog").exists() and not (tmp_path / "f.tlog.part").exists()


def test_motion_the_log_does_not_explain_gets_a_low_confidence(flight):
    from inspect_pipe.importer import find_offset

    tr = read_flight_log(flight / "f.tlog")
    t0 = np.arange(1.0, 11.0, 0.1)
    shift = np.random.default_rng(3).normal(0.0, 3.0, (len(t0), 2))  # image motion unrelated to the flight
    a = find_offset(tr, t0, t0 + 0.1, shift, search=(-1.0, 1.0))
    assert a.confidence < 0.3 and a.correlation < 0.6


def test_a_video_with_its_start_time_is_imported_and_aligned(flight, tmp_path):
    # the 120 frames as a 10 fps video whose recorder clock starts CLOCK_OFFSET_S off
    direct = read_sweep(flight / "sweep")
    first = cv2.imread(str(direct.frames[0].image_path))
    video = tmp_path / "flight.avi"
    vw = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (first.shape[1], first.shape[0]))
    for f in direct.frames:
        vw.write(cv2.imread(str(f.image_path)))
    vw.release()
    start = 1_700_000_000.0 + direct.frames[0].t_s + CLOCK_OFFSET_S
    out = tmp_path / "from_video"
    res = CliRunner().invoke(app, ["import", str(video), "--log", str(flight / "f.tlog"), "-o", str(out),
                                   "--video-start", _iso(start)])
    assert res.exit_code == 0, res.output
    doc = json.loads((out / "sweep.json").read_text())
    assert doc["source"]["footage"]["kind"] == "video" and doc["image_format"] == "png"
    assert abs(doc["time_alignment"]["camera_clock_offset_s"] - CLOCK_OFFSET_S) < 0.020, doc["time_alignment"]
    assert len(read_sweep(out).frames) >= 115


def _iso(t: float) -> str:
    import datetime as dt

    return dt.datetime.fromtimestamp(t, dt.timezone.utc).isoformat(timespec="microseconds").replace("+00:00", "Z")


def test_a_log_without_utc_is_searched_whole(flight, tmp_path):
    # an ArduPilot log without GPS (indoors): only the boot clock; the offset is camera UTC minus boot time
    from ._dataflash import tlog_to_dataflash

    tlog_to_dataflash(flight / "f.tlog", tmp_path / "nogps.bin", gps=False)
    assert read_flight_log(tmp_path / "nogps.bin").utc_offset_s is None
    out = tmp_path / "s"
    res = CliRunner().invoke(app, ["import", str(flight / "DCIM"), "--log", str(tmp_path / "nogps.bin"), "-o", str(out)])
    assert res.exit_code == 0, res.output
    ta = json.loads((out / "sweep.json").read_text())["time_alignment"]
    assert abs(ta["camera_clock_offset_s"] - (1_700_000_000.0 + CLOCK_OFFSET_S)) < 0.020, ta
    f = read_sweep(out).frames[0]
    assert f.raw["t_utc"] is None and 0.0 <= f.t_s <= 12.0


def test_a_tlog_keeps_the_vehicle_and_ignores_another_system(flight, tmp_path):
    # a second system on the link (another vehicle, sysid 7) streams its own position: not mixed in
    from pymavlink.dialects.v20 import common

    other = common.MAVLink(None, srcSystem=7, srcComponent=1)
    raw = bytearray((flight / "f.tlog").read_bytes())
    t = 1_700_000_003_000_000
    for k in range(100):
        msg = common.MAVLink_local_position_ned_message(3000 + 10 * k, 50.0, 50.0, -9.0, 0.0, 0.0, 0.0)
        raw += t.to_bytes(8, "big") + msg.pack(other)
    mixed = tmp_path / "mixed.tlog"
    mixed.write_bytes(bytes(raw))
    tr, ref = read_flight_log(mixed), read_flight_log(flight / "f.tlog")
    assert len(tr.t_pos) == len(ref.t_pos) and np.abs(tr.pos_ned).max() < 20


def test_a_video_s_creation_time_is_read_from_the_container(tmp_path):
    av = pytest.importorskip("av")
    path = tmp_path / "clip.mp4"
    with av.open(str(path), "w") as c:
        c.metadata["creation_time"] = "2023-11-14T22:13:18Z"  # an MP4 keeps whole seconds
        s = c.add_stream("mpeg4", rate=10)
        s.width, s.height, s.pix_fmt = 64, 48, "yuv420p"
        for k in range(12):
            for p in s.encode(av.VideoFrame.from_ndarray(np.full((48, 64, 3), 10 * k, np.uint8), format="rgb24")):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    fo = open_footage(path)
    assert fo.time_note.startswith("container creation_time") and len(fo.frames) == 12
    t = np.array([f.t_camera_s for f in fo.frames])
    assert t[0] == pytest.approx(1_700_000_000.0 - 2.0) and np.diff(t) == pytest.approx(0.1, abs=1e-3)
    # --video-start wins over the container's time
    assert open_footage(path, video_start="2023-11-14T22:13:20.25Z").frames[0].t_camera_s == pytest.approx(1_700_000_000.25)


def test_the_log_of_another_flight_is_refused_not_imported_at_a_guessed_offset(flight, tmp_path):
    # GIVEN the same hold and wall flown another way (up first, then to port): a log that is not this footage's
    import yaml

    doc = yaml.safe_load((FIXTURES / "short_sweep.yaml").read_text())
    doc["world"]["front_wall_texture"]["image"] = str((FIXTURES / doc["world"]["front_wall_texture"]["image"]).resolve())
    doc["operator"] = [{"t": 0.5, "button": "takeoff"}, {"t": 3.5, "stick": {"vx": 0, "vy": 0, "vz": 0.3, "yaw_rate": 0}},
                       {"t": 5.0, "stick": {"vx": 0, "vy": 0.3, "vz": 0, "yaw_rate": 0}},
                       {"t": 9.0, "stick": {"vx": 0, "vy": 0, "vz": 0, "yaw_rate": 0}}]
    (tmp_path / "other.yaml").write_text(yaml.safe_dump(doc))
    res = CliRunner().invoke(app, ["fly", "--scenario", str(tmp_path / "other.yaml"), "--log", str(tmp_path / "o.jsonl"),
                                   "--tlog", str(tmp_path / "other.tlog")])
    assert res.exit_code == 0, res.output
    # WHEN this flight's footage is imported with it
    res = CliRunner().invoke(app, ["import", str(flight / "DCIM"), "--log", str(tmp_path / "other.tlog"), "-o", str(tmp_path / "s")])
    # THEN one line names the log and the weak fit, and no sweep is written
    assert res.exit_code == 2, res.output
    assert "other.tlog: does not explain the footage's motion" in res.output and "confidence 0." in res.output
    assert len(res.output.strip().splitlines()) == 1 and not (tmp_path / "s").exists()
