"""The V4L2 source's logic without a camera: a fake ``cv2.VideoCapture`` with V4L2's buffer
semantics (a fixed number of buffers; a frame that finds them all full is lost) on a fake driver
clock, injected through ``capture_factory``."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from inspect_pipe.capture import CaptureConfig, ManualClock, read_sweep, run_capture
from inspect_pipe.capture._source import SourceLost
from inspect_pipe.capture.sources.v4l2 import DriverClock, OpenCVSource


class FakeV4L2:
    """The stream starts at the first grab; frame k is stamped ``t0 + k / fps`` on the driver clock (= host clock + ``clock_offset_s``)
    and reaches the queue ``latency_s[k]`` later. ``dropped`` frames never come (a true drop);
    the driver holds at most ``buffers - 1`` filled frames (OpenCV keeps one dequeued) and loses
    what finds them full. ``grab()`` blocks (moves the host clock) until a frame is queued."""

    def __init__(self, clock: ManualClock, *, fps=30.0, t0=0.0, clock_offset_s=0.0, latency_s=None, dropped=(),
                 n_frames=10_000, vanish_after=None):
        self.clock, self.fps, self.t0, self.offset = clock, fps, t0, clock_offset_s
        self.latency = latency_s if latency_s is not None else (lambda k: 0.004)
        self.dropped, self.n_frames, self.vanish_after = set(dropped), n_frames, vanish_after
        self.sets: dict[int, float] = {}
        self.queue: list[int] = []
        self.next_k = 0  # the next frame the driver will deliver
        self.current: int | None = None
        self.driver_lost = 0

    # cv2.VideoCapture's surface ------------------------------------------------------------
    def isOpened(self):
        return True

    def set(self, prop, value):
        self.sets[prop] = value
        return True

    def get(self, prop):
        if prop == cv2.CAP_PROP_FPS:
            return self.fps
        if prop == cv2.CAP_PROP_FRAME_WIDTH:
            return 32
        if prop == cv2.CAP_PROP_FRAME_HEIGHT:
            return 24
        if prop == cv2.CAP_PROP_POS_MSEC:
            return 1000.0 * (self.stamp_host(self.current) + self.offset)
        return 0.0

    def getBackendName(self):
        return "FAKE_V4L2"

    def grab(self):
        if self.vanish_after is not None and self.current is not None and self.current >= self.vanish_after:
            return False
        if self.current is None and not self.queue and self.next_k == 0:  # the first grab starts the stream
            self.next_k = max(0, int(np.ceil((self.clock.now() - self.t0) * self.fps)))
        self._deliver(self.clock.now())
        while not self.queue:
            k = self._next_real()
            if k is None:
                return False
            self.clock.sleep_until(self.arrival(k))
            self._deliver(self.clock.now())
        self.current = self.queue.pop(0)
        return True

    def retrieve(self):
        img = np.zeros((24, 32, 3), np.uint8)
        img[0, 0, 0], img[0, 0, 1] = self.current % 256, self.current // 256
        return True, img

    def release(self):
        pass

    # the fake driver -------------------------------------------------------------------------
    def stamp_host(self, k):
        return self.t0 + k / self.fps

    def arrival(self, k):
        return self.stamp_host(k) + self.latency(k)

    def _next_real(self):
        k = self.next_k
        while k in self.dropped:
            k += 1
        return k if k < self.n_frames else None

    def _deliver(self, now):
        capacity = max(1, int(self.sets.get(cv2.CAP_PROP_BUFFERSIZE, 4)) - 1)
        while True:
            k = self._next_real()
            if k is None or self.arrival(k) > now:
                return
            self.next_k = k + 1
            if len(self.queue) < capacity:
                self.queue.append(k)
            else:
                self.driver_lost += 1  # all buffers full: V4L2 loses the new frame


def _index(img) -> int:
    return int(img[0, 0, 0]) + 256 * int(img[0, 0, 1])


def _source(fake, clock, **kw):
    return OpenCVSource("/dev/video0", clock=clock, api=cv2.CAP_V4L2, kind="v4l2", capture_factory=lambda dev, api: fake, **kw)


def test_camera_runs_at_its_own_rate_and_is_decimated_to_10_hz_without_drops(tmp_path):
    clock = ManualClock(4.0)
    fake = FakeV4L2(clock, fps=30.0)
    src = _source(fake, clock, rate_hz=10.0)
    res = run_capture(src, tmp_path / "sw", clock=clock, config=CaptureConfig(rate_hz=10.0, duration_s=3.0))
    assert cv2.CAP_PROP_FPS not in fake.sets  # the camera keeps its own rate
    assert fake.sets[cv2.CAP_PROP_BUFFERSIZE] == 4  # 3 frames per capture period + 1
    s = read_sweep(tmp_path / "sw")
    idx = [_index(cv2.imread(str(f.image_path))) for f in s.frames]
    assert len(idx) == 30 and np.all(np.diff(idx) == 3)  # every third frame
    assert res.drops == 0 and res.dropped_source == 0 and fake.driver_lost == 0
    assert src.frames_passed_over >= 58 and src.frames_lost == 0
    # capture time = the driver's stamp (same clock as the host), not the arrival 4 ms later
    for f, k in zip(s.frames, idx):
        assert f.t_device_s == pytest.approx(fake.stamp_host(k), abs=1e-6)
        assert f.t_host_s == pytest.approx(fake.arrival(k), abs=1e-6)
    t = np.array([f.t_s for f in s.frames])
    assert np.allclose(np.diff(t), 0.1, atol=1e-5)


@pytest.mark.parametrize("fps", [30.0, 15.0, 25.0, 60.0])
def test_each_grab_returns_the_frame_nearest_its_deadline_never_a_stale_one(fps):
    clock = ManualClock(4.0)
    fake = FakeV4L2(clock, fps=fps, latency_s=lambda k: 0.002 + 0.006 * ((k * 7919) % 13) / 13)
    src = _source(fake, clock, rate_hz=10.0)
    src.open()
    errors, lost = [], 0
    for j in range(60):
        deadline = 5.5 + 0.1 * j
        clock.sleep_until(deadline)
        g = src.grab(deadline)
        errors.append(g.t_exposure_start_s - deadline)
        lost += g.lost_before
        assert clock.now() - deadline <= 0.5 / fps + 0.01  # waited at most half a camera period (+ latency)
    assert max(abs(e) for e in errors) <= 0.5 / fps + 1e-9
    assert lost == 0 and fake.driver_lost == 0


def test_old_queued_frames_are_drained_not_returned():
    # GIVEN the capture loop stalled 0.35 s (a slow disk): the driver has queued 3 old frames
    clock = ManualClock(4.0)
    fake = FakeV4L2(clock, fps=30.0)
    src = _source(fake, clock, rate_hz=10.0)
    src.open()
    clock.sleep_until(5.0)
    src.grab(5.0)
    clock.sleep_until(5.35)
    g = src.grab(5.35)
    # THEN the frame returned is the newest (at most half a period from the deadline), and the
    # frames the driver lost while its buffers were full are counted as what they are
    assert abs(g.t_exposure_start_s - 5.35) <= 1 / 60 + 1e-9
    assert g.lost_before == fake.driver_lost > 0


def test_true_drops_are_counted_once_whatever_the_decimation(tmp_path):
    clock = ManualClock(4.0)
    fake = FakeV4L2(clock, fps=30.0, dropped={130, 131, 160, 161, 162, 197})  # 6 frames the camera never delivered (the stream starts at frame 120)
    src = _source(fake, clock, rate_hz=10.0)
    res = run_capture(src, tmp_path / "sw", clock=clock, config=CaptureConfig(rate_hz=10.0, duration_s=3.0))
    assert res.dropped_source == 6 == src.frames_lost
    assert fake.driver_lost == 0 and res.frames_written == 30


def test_a_driver_clock_other_than_the_hosts_is_mapped_by_the_least_delayed_frame():
    clock = ManualClock(4.0)
    lat = lambda k: 0.003 + 0.015 * (((k * 2654435761) % 1000) / 1000.0)  # 3..18 ms arrival jitter  # noqa: E731
    fake = FakeV4L2(clock, fps=30.0, clock_offset_s=-3.75, latency_s=lat)  # the driver's clock is 3.75 s behind
    src = _source(fake, clock, rate_hz=10.0)
    src.open()
    got = []
    for j in range(100):
        d = 5.5 + 0.1 * j
        clock.sleep_until(d)
        got.append(src.grab(d))
    t = np.array([g.t_exposure_start_s for g in got[20:]])
    arrival = np.array([g.t_host_s for g in got[20:]])
    true = np.array([g.t_device_s + 3.75 for g in got[20:]])
    err = t - true - 0.003  # above the least latency the fake has (3 ms)
    assert np.all(err >= -1e-9) and np.all(np.diff(err) <= 1e-9) and err[0] < 0.002 and err[-1] < 0.0005  # converges from above
    assert np.median(np.abs(np.diff(t) - 0.1)) < 1e-6 < 0.003 < np.std(np.diff(arrival))  # arrival jitter does not reach the time stamps


def test_driver_clock_same_clock_is_kept_exactly():
    dc = DriverClock()
    assert dc.to_host(100.0, 100.004) == 100.0 and dc.same_clock
    dc = DriverClock()
    assert dc.to_host(2.0, 100.010) == pytest.approx(100.010) and not dc.same_clock
    assert dc.to_host(2.1, 100.104) == pytest.approx(100.104)  # a smaller delay tightens the offset
    assert dc.to_host(2.2, 100.220) == pytest.approx(100.204)


def test_a_camera_that_vanishes_mid_capture_ends_the_sweep_readable(tmp_path):
    clock = ManualClock(4.0)
    fake = FakeV4L2(clock, fps=30.0, vanish_after=165)  # 1.5 s after the stream started (frame 120)
    res = run_capture(_source(fake, clock, rate_hz=10.0), tmp_path / "sw", clock=clock, config=CaptureConfig(rate_hz=10.0, duration_s=5.0))
    assert res.reason.name == "SOURCE_LOST" and "no frame" in res.detail
    s = read_sweep(tmp_path / "sw")
    assert 14 <= len(s.frames) <= 16 and s.complete


def test_the_source_lost_error_is_raised_by_grab():
    clock = ManualClock(4.0)
    src = _source(FakeV4L2(clock, fps=30.0, vanish_after=0), clock, rate_hz=10.0)
    src.open()
    src.grab(5.0)
    with pytest.raises(SourceLost):
        src.grab(5.1)


# --------------------------------------------------------------------------- doctor: formats and rates

LIST_FORMATS_EXT = """ioctl: VIDIOC_ENUM_FMT
\tType: Video Capture

\t[0]: 'MJPG' (Motion-JPEG, compressed)
\t\tSize: Discrete 1920x1080
\t\t\tInterval: Discrete 0.033s (30.000 fps)
\t\t\tInterval: Discrete 0.040s (25.000 fps)
\t\tSize: Discrete 1280x720
\t\t\tInterval: Discrete 0.017s (60.000 fps)
\t\t\tInterval: Discrete 0.033s (30.000 fps)
\t[1]: 'YUYV' (YUYV 4:2:2)
\t\tSize: Discrete 640x480
\t\t\tInterval: Discrete 0.033s (30.000 fps)
\t\t\tInterval: Discrete 0.067s (15.000 fps)
\t\t\tInterval: Discrete 0.133s (7.500 fps)
\t[2]: 'GREY' (8-bit Greyscale)
\t\tSize: Stepwise 16x16 - 752x480 with step 4/2
\t\t\tInterval: Stepwise 0.011s - 1.000s with step 0.000s (1.000-87.000 fps)
"""


def test_v4l2_ctl_formats_are_parsed():
    from inspect_pipe.capture.sources.v4l2 import parse_list_formats_ext

    modes = parse_list_formats_ext(LIST_FORMATS_EXT)
    assert [m.line() for m in modes] == [
        "MJPG 1920x1080 @ 30, 25 fps", "MJPG 1280x720 @ 60, 30 fps", "YUYV 640x480 @ 30, 15, 7.5 fps", "GREY 16x16-752x480 @ 1-87 fps"]
    assert modes[0].description == "Motion-JPEG, compressed"
    assert parse_list_formats_ext("ioctl: VIDIOC_ENUM_FMT\n\tType: Video Capture\n") == []  # a metadata node


def test_camera_modes_prefers_v4l2_ctl_and_falls_back_to_probing():
    from subprocess import CompletedProcess

    from inspect_pipe.capture.sources.v4l2 import camera_modes

    calls = []

    def run(cmd, **kw):
        calls.append(cmd)
        return CompletedProcess(cmd, 0, LIST_FORMATS_EXT, "")

    how, modes = camera_modes("/dev/video0", which=lambda n: "/usr/bin/v4l2-ctl", run=run)
    assert how == "v4l2-ctl" and len(modes) == 4 and calls == [["/usr/bin/v4l2-ctl", "-d", "/dev/video0", "--list-formats-ext"]]

    class Probe:  # a camera that takes MJPG at 640x480 (30 fps) and 1280x720 (15 fps), nothing else
        def __init__(self):
            self.p = {}

        def isOpened(self):
            return True

        def set(self, prop, v):
            self.p[prop] = v

        def get(self, prop):
            fcc = int(self.p.get(cv2.CAP_PROP_FOURCC, 0))
            size = (self.p.get(cv2.CAP_PROP_FRAME_WIDTH), self.p.get(cv2.CAP_PROP_FRAME_HEIGHT))
            ok = fcc == cv2.VideoWriter_fourcc(*"MJPG") and size in ((640, 480), (1280, 720))
            if prop == cv2.CAP_PROP_FOURCC:
                return fcc if ok else cv2.VideoWriter_fourcc(*"YUYV") * 0
            if prop == cv2.CAP_PROP_FRAME_WIDTH:
                return size[0] if ok else 640
            if prop == cv2.CAP_PROP_FRAME_HEIGHT:
                return size[1] if ok else 480
            if prop == cv2.CAP_PROP_FPS:
                return 30.0 if size == (640, 480) else 15.0
            return 0.0

        def release(self):
            pass

    how, modes = camera_modes("/dev/video0", which=lambda n: None, capture_factory=lambda d, a: Probe())
    assert how.startswith("probed with OpenCV")
    assert sorted(m.line() for m in modes) == ["MJPG 1280x720 @ 15 fps", "MJPG 640x480 @ 30 fps"]


def test_doctor_lists_each_cameras_modes(monkeypatch, tmp_path):
    from typer.testing import CliRunner

    from cli.main import app
    from inspect_pipe.capture.sources import v4l2

    monkeypatch.setattr(v4l2, "list_v4l2_devices", lambda: ["/dev/video0", "/dev/video1"])
    monkeypatch.setattr(v4l2, "camera_modes", lambda dev: ("v4l2-ctl", v4l2.parse_list_formats_ext(LIST_FORMATS_EXT if dev.endswith("0") else "")))
    monkeypatch.setattr(v4l2, "device_name", lambda dev: "UVC Camera (046d:0825)")
    res = CliRunner().invoke(app, ["doctor"])
    assert res.exit_code == 0, res.output
    assert "/dev/video0 (UVC Camera (046d:0825)): 4 modes [v4l2-ctl]" in res.output
    assert "MJPG 1280x720 @ 60, 30 fps  (Motion-JPEG, compressed)" in res.output
    assert "/dev/video1 (UVC Camera (046d:0825)): no capture formats" in res.output


def test_device_name_reads_sysfs(tmp_path):
    from inspect_pipe.capture.sources.v4l2 import device_name

    (tmp_path / "video3").mkdir()
    (tmp_path / "video3" / "name").write_text("USB 2.0 Camera: HD USB Camera\n")
    assert device_name("/dev/video3", sys_root=str(tmp_path)) == "USB 2.0 Camera: HD USB Camera"
    assert device_name("/dev/video9", sys_root=str(tmp_path)) == ""
