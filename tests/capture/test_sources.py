"""Camera back-ends: V4L2 where a device exists, the same OpenCV path on a video file, replay of
folders and videos, IDS without its SDK."""

from __future__ import annotations

import glob
import importlib.util

import cv2
import numpy as np
import pytest

from inspect_pipe.capture import CaptureConfig, ManualClock, MonotonicClock, StopReason, read_sweep, run_capture
from inspect_pipe.capture.sources.replay import ReplaySource
from inspect_pipe.capture.sources.v4l2 import OpenCVSource, V4L2Source
from inspect_pipe.errors import InputError


def write_video(path, n=30, fps=10.0, size=(160, 120)):
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, size)
    assert vw.isOpened(), "OpenCV cannot write MJPG here"
    for k in range(n):
        img = np.full((size[1], size[0], 3), 8 * k, np.uint8)
        cv2.putText(img, str(k), (20, 80), cv2.FONT_HERSHEY_SIMPLEX, 2, (255, 255, 255), 3)
        vw.write(img)
    vw.release()
    return path


@pytest.mark.skipif(not glob.glob("/dev/video*"), reason="no /dev/video* device on this machine (no camera attached)")
def test_v4l2_camera_captures_at_10hz(tmp_path):  # pragma: no cover - needs hardware
    dev = sorted(glob.glob("/dev/video*"))[0]
    clock = MonotonicClock()
    res = run_capture(V4L2Source(dev, clock=clock, fps=10), tmp_path / "sw", clock=clock, config=CaptureConfig(duration_s=3.0))
    s = read_sweep(tmp_path / "sw")
    assert res.ok and 25 <= len(s.frames) <= 31
    assert res.jitter_p99_s() < 0.02


def test_v4l2_rejects_a_bad_device_with_a_one_line_error():
    with pytest.raises(InputError, match=r"/dev/video99: no such device"):
        V4L2Source("/dev/video99", clock=MonotonicClock())
    with pytest.raises(InputError, match="not a V4L2 device"):
        V4L2Source("/tmp/x", clock=MonotonicClock())


def test_the_opencv_capture_path_on_a_video_file(tmp_path):
    # GIVEN a 30-frame video file, read through the same class V4L2 uses (another OpenCV api)
    video = write_video(tmp_path / "v.avi")
    clock = ManualClock()
    src = OpenCVSource(str(video), clock=clock, api=cv2.CAP_ANY, fps=10)
    res = run_capture(src, tmp_path / "sw", clock=clock, config=CaptureConfig(rate_hz=10))
    # THEN every frame is captured, in order, then the source ends
    assert res.reason is StopReason.SOURCE_ENDED and res.frames_written == 30 and res.drops == 0
    s = read_sweep(tmp_path / "sw")
    means = [float(cv2.imread(str(f.image_path)).mean()) for f in s.frames]
    assert all(b > a for a, b in zip(means, means[1:]))
    assert s.frames[5].t_device_s == pytest.approx(0.5, abs=1e-3)  # the container's frame time


def test_replay_of_a_video_and_of_an_image_folder(tmp_path):
    video = write_video(tmp_path / "v.avi", n=12, fps=5.0)
    clock = ManualClock(10.0)
    res = run_capture(ReplaySource(video, clock=clock), tmp_path / "sv", clock=clock, config=CaptureConfig())
    s = read_sweep(tmp_path / "sv")
    assert res.frames_written == 12 and s.frames[-1].t_host_s - s.frames[0].t_host_s == pytest.approx(11 / 5.0, abs=1e-6)
    folder = tmp_path / "imgs"
    folder.mkdir()
    for k in range(6):
        cv2.imwrite(str(folder / f"f{k:02d}.png"), np.full((40, 60, 3), 30 * k, np.uint8))
    clock = ManualClock()
    res = run_capture(ReplaySource(folder, clock=clock, rate_hz=4.0), tmp_path / "sf", clock=clock, config=CaptureConfig())
    s = read_sweep(tmp_path / "sf")
    assert [round(f.t_host_s, 6) for f in s.frames] == [0.0, 0.25, 0.5, 0.75, 1.0, 1.25]
    assert [int(cv2.imread(str(f.image_path))[0, 0, 0]) for f in s.frames] == [0, 30, 60, 90, 120, 150]


@pytest.mark.skipif(importlib.util.find_spec("ids_peak") is not None or importlib.util.find_spec("pyueye") is not None,
                    reason="an IDS SDK is installed here")
def test_ids_without_sdk_says_what_to_install():
    from inspect_pipe.capture.sources.ids import ids_status, open_ids

    with pytest.raises(InputError, match=r"ids: no IDS camera SDK found.*pip install 'inspect-pipe\[ids\]'"):
        open_ids(clock=MonotonicClock())
    ok, why = ids_status()
    assert not ok and "IDS peak not installed" in why
