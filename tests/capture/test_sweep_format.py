"""Sweep reader and writer: round trip, interrupted and damaged sweeps, checksums, metadata."""

from __future__ import annotations

import errno
import json
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from inspect_pipe.capture import (
    CameraModel,
    CaptureConfig,
    Grab,
    ManualClock,
    SourceInfo,
    StopReason,
    SweepWriter,
    read_sweep,
    run_capture,
    verify_checksums,
)
from inspect_pipe.errors import InputError


class CountingSource:
    """Triggered synthetic camera: frame k shows the value k; ``lose_at`` raises SourceLost."""

    def __init__(self, clock, n=1000, size=(64, 48), exposure_s=0.002, lose_at=None):
        self.clock, self.n, self.size, self.exposure_s, self.lose_at = clock, n, size, exposure_s, lose_at
        self.k = 0
        self.closed = False

    def open(self):
        return SourceInfo("test", "counting source", CameraModel.from_hfov(*self.size, 60.0), triggered=True)

    def grab(self, deadline_s):
        from inspect_pipe.capture import SourceLost

        if self.k >= self.n:
            raise StopIteration
        if self.lose_at is not None and self.k == self.lose_at:
            raise SourceLost("test camera: unplugged")
        self.clock.sleep_until(deadline_s + self.exposure_s)
        img = np.full((self.size[1], self.size[0], 3), self.k % 256, np.uint8)
        self.k += 1
        return Grab(img, deadline_s, self.exposure_s, self.clock.now(), frame_id=self.k, t_device_s=deadline_s * 1.0001 + 5.0)

    def close(self):
        self.closed = True


def capture(tmp_path, **kw):
    clock = ManualClock()
    src = CountingSource(clock, **{k: v for k, v in kw.items() if k in ("n", "lose_at", "size")})
    cfg = CaptureConfig(rate_hz=10, **{k: v for k, v in kw.items() if k in ("duration_s", "max_frames")})
    res = run_capture(src, tmp_path / "sw", clock=clock, config=cfg, writer_factory=kw.get("writer_factory", SweepWriter))
    return res, tmp_path / "sw", src


def test_round_trip_with_stamps_clock_fit_and_checksums(tmp_path):
    res, sw, src = capture(tmp_path, n=25, duration_s=100)
    assert res.reason is StopReason.SOURCE_ENDED and res.frames_written == 25 and res.drops == 0 and src.closed
    s = read_sweep(sw)
    assert s.complete and not s.problems and len(s) == 25
    # mid-exposure on the 10 Hz schedule, exactly (the clock is injected)
    assert [f.t_s for f in s.frames] == pytest.approx([0.1 * k + 0.001 for k in range(25)], abs=1e-9)
    assert all(f.exposure_s == 0.002 and f.image_path.is_absolute() and f.image_path.is_file() for f in s.frames)
    assert s.summary["device_to_host_clock"]["drift_ppm"] == pytest.approx(-100, abs=0.5)
    assert verify_checksums(sw) == []
    (sw / "images" / "000003.png").write_bytes((sw / "images" / "000004.png").read_bytes())
    assert verify_checksums(sw) == ["images/000003.png"]


def test_images_carry_exif_and_xmp_without_gps(tmp_path):
    _, sw, _ = capture(tmp_path, n=3, duration_s=10)
    s = read_sweep(sw)
    im = Image.open(s.frames[1].image_path)
    exif = im.getexif()
    assert exif[0x010F] == "test" and "inspect-pipe" in exif[0x0131]
    sub = exif.get_ifd(0x8769)
    assert float(sub[0x829A]) == pytest.approx(0.002)
    assert 0x8825 not in exif  # no GPS IFD
    xmp = im.info.get("XML:com.adobe.xmp", "")
    assert 'ip:frame_index="1"' in xmp and "ip:fx_px" in xmp


def test_truncated_frames_jsonl_reads_up_to_the_last_whole_frame(sweep_copy):
    full = read_sweep(sweep_copy)
    raw = (sweep_copy / "frames.jsonl").read_bytes()
    cut = raw.rfind(b"\n", 0, len(raw) - 1) + 40  # in the middle of the last line
    (sweep_copy / "frames.jsonl").write_bytes(raw[:cut])
    (sweep_copy / "COMPLETE").unlink()
    s = read_sweep(sweep_copy)
    assert len(s.frames) == len(full.frames) - 1 and not s.complete
    assert [f.index for f in s.frames] == [f.index for f in full.frames[:-1]]
    assert len(s.problems) == 1 and "truncated" in str(s.problems[0]) and "frames.jsonl" in str(s.problems[0])
    with pytest.raises(InputError, match="truncated"):
        read_sweep(sweep_copy, strict=True)


def test_a_missing_image_is_skipped_and_named(sweep_copy):
    n = len(read_sweep(sweep_copy).frames)
    (sweep_copy / "images" / "000005.png").unlink()
    s = read_sweep(sweep_copy)
    assert len(s.frames) == n - 1 and 5 not in [f.index for f in s.frames]
    assert "000005.png" in str(s.problems[0]) and "missing" in str(s.problems[0])


def test_unknown_format_version_and_non_sweeps_are_input_errors(sweep_copy, tmp_path):
    meta = json.loads((sweep_copy / "sweep.json").read_text())
    meta["format"] = "inspect_pipe.sweep/2"
    (sweep_copy / "sweep.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"sweep.json: unknown format version 'inspect_pipe.sweep/2'"):
        read_sweep(sweep_copy)
    with pytest.raises(InputError, match="not found"):
        read_sweep(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="sweep.json: missing"):
        read_sweep(tmp_path / "empty")
    (sweep_copy / "sweep.json").write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        read_sweep(sweep_copy)


def test_simulated_sweep_carries_state_truth_and_texture(sim_sweep):
    s = read_sweep(sim_sweep)
    m = s.meta
    assert m.camera.K.shape == (3, 3) and m.width == 320 and m.height == 240 and len(m.dist) == 5
    assert m.time_base == "simulation_s" and m.rate_hz == 10
    assert m.wall_texture is not None and m.wall_texture.image.is_file() and m.wall_texture.m_per_px == 0.004
    assert m.wall_texture.origin_uv == (3.8, 2.0)
    assert set(m.survey) >= {"vessel", "hold", "wall", "frame_spacing_m", "reference_frame"}
    f = s.frames[-1]
    assert f.fsm == "flying" and f.est_mode is not None and f.inspection_mode is False
    assert f.position_true_m is not None and abs(f.position_m[2] - f.position_true_m[2]) < 0.1
    assert abs(f.dist_front_m - (12.0 - f.position_true_m[0])) < 0.1
    # the truth homography maps the wall point straight ahead of the camera near the image centre
    t = f.truth
    axis = t.R_world_cam[:, 2]
    hit = t.cam_center_m + axis * (12.0 - t.cam_center_m[0]) / axis[0]
    q = t.H_wall_m_to_frame @ np.array([5.0 - hit[1], hit[2], 1.0])
    assert np.allclose(q[:2] / q[2], m.camera.K[:2, 2], atol=1e-3)
    assert t.H_wall_px_to_frame is not None


def test_writer_backpressure_drops_are_counted_never_blocking(tmp_path):
    def slow_write(path: Path, data: bytes) -> None:
        time.sleep(0.05)
        path.write_bytes(data)

    w = SweepWriter(tmp_path / "sw", {"camera": CameraModel.from_hfov(64, 48, 60).to_json()}, queue_frames=3, encoders=1,
                    write_bytes=slow_write)
    img = np.zeros((48, 64, 3), np.uint8)
    t0 = time.perf_counter()
    accepted = [w.submit(i, img, {"t_s": i * 0.1, "exposure_s": 0.001}) for i in range(20)]
    assert time.perf_counter() - t0 < 0.05  # submit never waits for the disk
    stats = w.close({})
    assert sum(accepted) == stats.written and stats.dropped_backpressure == 20 - stats.written >= 15
    s = read_sweep(tmp_path / "sw")
    assert len(s.frames) == stats.written and s.summary["dropped_backpressure"] == stats.dropped_backpressure


def test_disk_full_stops_cleanly_and_the_sweep_stays_readable(tmp_path):
    calls = []

    def filling_disk(path: Path, data: bytes) -> None:
        calls.append(path)
        if len(calls) > 7:
            raise OSError(errno.ENOSPC, "No space left on device")
        path.write_bytes(data)

    res, sw, src = capture(tmp_path, n=100, duration_s=100,
                           writer_factory=lambda *a, **k: SweepWriter(*a, write_bytes=filling_disk, **k))
    assert res.reason is StopReason.WRITER_FAILED and "disk full" in res.detail and src.closed
    assert res.frames_written == 7
    s = read_sweep(sw)
    assert len(s.frames) == 7 and not s.problems


def test_camera_unplugged_stops_with_a_reason(tmp_path):
    res, sw, _ = capture(tmp_path, n=100, lose_at=12, duration_s=100)
    assert res.reason is StopReason.SOURCE_LOST and "unplugged" in res.detail
    s = read_sweep(sw)
    assert len(s.frames) == 12 and s.complete and s.summary["stop_reason"] == "camera lost"


def test_simulated_frames_match_the_wall_texture_through_their_truth_homography(sim_sweep):
    # GIVEN a simulated sweep read back from disk (PNG, reader, texture path resolution)
    import cv2

    s = read_sweep(sim_sweep)
    m = s.meta
    tex = cv2.imread(str(m.wall_texture.image), cv2.IMREAD_GRAYSCALE)
    flying = [f for f in s.frames if f.fsm == "flying"]
    assert len(flying) > 20
    for f in flying[::10]:
        # WHEN the texture is warped by the frame's H_wall_px_to_frame and the frame is undistorted
        und = cv2.cvtColor(cv2.undistort(cv2.imread(str(f.image_path)), m.K, m.dist), cv2.COLOR_BGR2GRAY)
        warped = cv2.warpPerspective(tex, f.truth.H_wall_px_to_frame, (m.width, m.height))
        cover = cv2.warpPerspective(np.full(tex.shape, 255, np.uint8), f.truth.H_wall_px_to_frame, (m.width, m.height))
        cover = cv2.erode(cover, np.ones((9, 9), np.uint8)) > 0
        assert cover.mean() > 0.3
        # THEN they agree up to photometry (vignetting, exposure, noise, resampling): correlation > 0.9
        a, b = (cv2.GaussianBlur(x.astype(np.float32), (0, 0), 1.5)[cover] for x in (und, warped))
        assert np.corrcoef(a, b)[0, 1] > 0.9
        # and a one-pixel error in the homography would show
        shifted = cv2.GaussianBlur(np.roll(warped, 2, axis=1).astype(np.float32), (0, 0), 1.5)[cover]
        assert np.corrcoef(a, shifted)[0, 1] < np.corrcoef(a, b)[0, 1] - 0.1


def test_a_state_feed_gives_each_frame_the_state_at_mid_exposure(tmp_path):
    # GIVEN telemetry at 50 Hz of a vehicle moving at 1 m/s along x, and a camera exposing 2 ms
    from inspect_pipe.capture import TrajectoryFeed, VehicleState

    feed = TrajectoryFeed([VehicleState(k * 0.02, (10.0 + k * 0.02, 0.0, 1.0), 2.0 - k * 0.02, 1.0, (1.0, 0.0, 0.0), 1, "flying", True)
                           for k in range(200)])
    clock = ManualClock()
    run_capture(CountingSource(clock, n=20), tmp_path / "sw", clock=clock, config=CaptureConfig(), state_feed=feed)
    s = read_sweep(tmp_path / "sw")
    # THEN the position is the one at deadline + exposure / 2, interpolated between telemetry samples
    assert len(s.frames) == 20
    for f in s.frames:
        assert f.position_m[0] == pytest.approx(10.0 + f.t_s, abs=1e-4) and f.t_s == pytest.approx(0.1 * f.index + 0.001)
        assert f.dist_front_m == pytest.approx(2.0 - f.t_s, abs=1e-4) and f.raw["state"]["t_s"] == pytest.approx(f.t_s)
        assert f.truth is None and f.position_true_m is None
