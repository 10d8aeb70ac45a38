"""The live mosaic beside a capture: a bounded queue that skips rather than blocks, the status line,
a stalled stream, and the capture service's tap."""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest

from inspect_pipe.capture import CaptureConfig, ManualClock, MonotonicClock, read_sweep, run_capture
from inspect_pipe.capture._source import Grab, SourceInfo
from inspect_pipe.capture._geometry import CameraModel
from inspect_pipe.mosaic import LiveFeed, LiveMosaic
from inspect_pipe.mosaic._live_feed import coverage_figures
from inspect_pipe.mosaic.metrics import coverage_error_sim
from inspect_pipe.mosaic.synthetic import SweepPath, lawnmower_homographies, render_frame, textured_wall

FRAME_WH = (752, 480)


@pytest.fixture(scope="module")
def frames():
    rng = np.random.default_rng(5)
    path = SweepPath(passes=2, per_pass=20, step_px=30, row_px=300, frame_wh=FRAME_WH, focal_px=650, margin_px=60)
    wall = textured_wall(60 * 2 + 752 + 30 * 20 + 100, 60 * 2 + 480 + 300 * 2 + 100, rng)
    return [render_frame(wall, H, FRAME_WH) for H in lawnmower_homographies(path, rng)]


def test_the_feed_places_every_frame_and_publishes_status_and_pictures(frames):
    feed = LiveFeed(pictures=True)
    for i, img in enumerate(frames):
        assert feed.submit(img, {"t_s": 0.1 * i}, block=True)
    st = feed.close()
    assert (st.frames, st.placed, st.skipped, st.queued) == (len(frames), len(frames), 0, 0)
    assert st.covered_pct > 90 and st.problem == "" and st.version == len(frames)
    assert f"{st.covered_pct:.0f} % covered" in st.line() and f"{len(frames)}/{len(frames)} frames placed" in st.line()
    version, mosaic, cover = feed.pictures()
    assert version == len(frames) and mosaic.shape == cover.shape and mosaic.shape[1] > mosaic.shape[0]  # two passes: wide
    assert max(mosaic.shape[:2]) <= 640 and mosaic.any(axis=2).mean() > 0.8  # cropped to what was seen


def test_a_slow_mosaicer_never_blocks_submit_it_skips_and_says_how_far_behind(frames, monkeypatch):
    # GIVEN a mosaicer far slower than the camera (0.3 s a frame)
    real = LiveMosaic.add_frame

    def slow(self, image, state=None):
        time.sleep(0.3)
        return real(self, image, state)

    monkeypatch.setattr(LiveMosaic, "add_frame", slow)
    feed = LiveFeed(queue_frames=3)
    # WHEN 20 frames come at 10 Hz THEN handing each over takes no time, and the frames it cannot keep are skipped
    waits = []
    for i, img in enumerate(frames[:20]):
        t0 = time.perf_counter()
        feed.submit(img, {"t_s": 0.1 * i})
        waits.append(time.perf_counter() - t0)
        time.sleep(0.1)
    st = feed.status()
    # (a submit that waited for room would take ~0.3 s once the queue is full; percentiles, not the max: a loaded
    # machine can hold any thread back once)
    assert np.median(waits) < 0.005 and np.percentile(waits, 90) < 0.1, waits
    assert st.skipped >= 8 and st.queued >= 1, st
    assert f"behind by {st.queued}" in st.line() and f"({st.skipped} skipped)" in st.line()
    st = feed.close()
    assert st.placed == 20 - st.skipped and st.queued == 0


def test_a_stalled_stream_is_one_line_and_what_was_placed_stays(frames):
    now = [0.0]
    feed = LiveFeed(clock=lambda: now[0], stall_s=3.0)
    for i, img in enumerate(frames[:8]):
        now[0] = 0.1 * i
        feed.submit(img, {"t_s": now[0]}, block=True)
    feed.drain()
    assert feed.status().problem == ""
    now[0] += 2.0  # quiet, but not yet a stall
    assert feed.status().problem == ""
    now[0] += 2.2
    st = feed.status()
    assert st.problem == "live stream stalled: no frame for 4.2 s (8 frames so far); the 8 placed are kept", st.problem
    assert st.placed == 8 and "\n" not in st.line() and st.line().endswith(st.problem)
    feed.expect(False)  # frames not expected (e.g. inspection mode off): not a stall
    assert feed.status().problem == ""
    feed.expect(True)
    now[0] += 3.5
    assert "no frame for 3.5 s" in feed.status().problem
    feed.submit(frames[8], {"t_s": now[0]}, block=True)  # frames again: the stall is over, the gap is said once
    feed.drain()
    st = feed.status()
    assert st.placed == 9 and "stalled: no frame for 7.7 s before frame 8" in st.problem
    feed.close()


def test_gap_figures_count_regions_not_slivers():
    covered = np.zeros((100, 200), bool)
    covered[:, :90] = covered[:, 110:] = True  # a 20 px band not imaged
    gaps = ~covered
    gaps[0, 0] = True  # a one-pixel sliver is not a gap region
    pct, n, gap_pct = coverage_figures(covered, gaps)
    assert n == 1 and pct == pytest.approx(90.0, abs=0.1) and gap_pct == pytest.approx(10.0, abs=0.1)


class _Camera:
    """A 10 Hz triggered source over the frames, real time, with a vehicle state."""

    def __init__(self, frames, clock):
        self.frames, self.clock, self.k = frames, clock, 0

    def open(self):
        cam = CameraModel.from_hfov(FRAME_WH[0], FRAME_WH[1], 60.0)
        return SourceInfo(kind="test", description="frames", camera=cam, triggered=True)

    def grab(self, deadline_s):
        if self.k >= len(self.frames):
            raise StopIteration
        self.k += 1
        t = self.clock.now()
        return Grab(self.frames[self.k - 1], t_exposure_start_s=t, exposure_s=0.002, t_host_s=t, frame_id=self.k)

    def close(self):
        pass


def test_capture_feeds_the_live_mosaic_without_slowing_down(frames, tmp_path, monkeypatch):
    # GIVEN a real-time 10 Hz capture whose live mosaicer is made three times too slow
    real = LiveMosaic.add_frame

    def slow(self, image, state=None):
        time.sleep(0.3)
        return real(self, image, state)

    monkeypatch.setattr(LiveMosaic, "add_frame", slow)
    clock = MonotonicClock()
    feed = LiveFeed(clock=clock.now, queue_frames=2)
    tap, spent = feed.tap(), []

    def timed(image, record, camera):
        t0 = time.perf_counter()
        tap(image, record, camera)
        spent.append(time.perf_counter() - t0)

    res = run_capture(_Camera(frames[:30], clock), tmp_path / "sw", clock=clock, config=CaptureConfig(rate_hz=10.0), on_frame=timed)
    st = feed.close()
    # THEN the capture keeps its pace: every frame written in about 3 s (9 s if it waited for the mosaicer), the tap
    # taking no time in the grabbing loop (timing only in percentiles: a loaded machine delays any thread now and then);
    # the mosaic skipped what it could not take
    assert res.frames_written == 30 and res.elapsed_s < 5.0, res
    assert np.median(spent) < 0.005 and np.percentile(spent, 90) < 0.1, spent
    assert st.skipped > 10 and st.frames == 30 - st.skipped and st.placed == st.frames


def test_capture_from_the_simulator_waits_for_the_live_mosaic(tmp_path):
    from tests.capture.conftest import write_scenario
    from inspect_pipe.capture.sources.sim import SimSource
    from inspect_pipe.flight import load_scenario

    sc = load_scenario(write_scenario(tmp_path / "sc", duration_s=6.0, operator=[
        {"t": 0.5, "button": "takeoff"}, {"t": 3.0, "button": "inspection_mode_on"},
        {"t": 3.5, "stick": {"vx": 0, "vy": -0.2, "vz": 0, "yaw_rate": 0}}]))
    clock = ManualClock()
    feed = LiveFeed(clock=clock.now)
    res = run_capture(SimSource(sc, clock=clock), tmp_path / "sw", clock=clock,
                      config=CaptureConfig(time_base="simulation_s", rate_hz=10, wait_for_writer=True),
                      on_frame=feed.tap(block=True))
    st = feed.close()
    # simulated time: nothing is late, so nothing is skipped; the frames before inspection mode are left out, every
    # other is placed, and the odometry scale comes from the range to the wall
    assert res.frames_written == 60 and st.skipped == 0 and 20 <= st.frames <= 32 and st.not_inspecting == 60 - st.frames
    assert st.placed >= st.frames - 2 and st.covered_pct > 80 and "stalled" not in st.problem, st
    assert feed.m_per_px == pytest.approx(1.5 / (320 / 2 / np.tan(np.radians(30))), rel=0.3)
    # AND its coverage map matches the simulator's truth (true homographies and motion blur of the frames it was fed)
    frames = [f for f in read_sweep(tmp_path / "sw").frames if f.inspection_mode]
    err, _ = coverage_error_sim(feed.live_mosaic(), frames)
    assert len(frames) == st.frames and err < 0.03, err
