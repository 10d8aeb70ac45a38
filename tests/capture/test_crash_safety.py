"""A capture killed with SIGKILL at a random moment leaves a sweep that reads back up to its last
whole frame: no frame listed that is not on disk, no image left out except possibly the last."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from inspect_pipe.capture import read_sweep

CAPTURE = r"""
import sys, numpy as np
from inspect_pipe.capture import CameraModel, CaptureConfig, Grab, MonotonicClock, SourceInfo, run_capture

class Noise:
    def __init__(self, clock): self.clock, self.rng, self.k = clock, np.random.default_rng(1), 0
    def open(self): return SourceInfo("test", "noise", CameraModel.from_hfov(320, 240, 60), triggered=True)
    def grab(self, deadline):
        self.clock.sleep_until(deadline)
        self.k += 1
        img = self.rng.integers(0, 255, (240, 320, 3), dtype=np.uint8)
        return Grab(img, deadline, 0.001, self.clock.now(), frame_id=self.k)
    def close(self): pass

clock = MonotonicClock()
print("started", flush=True)
run_capture(Noise(clock), sys.argv[1], clock=clock, config=CaptureConfig(rate_hz=100, duration_s=60))
"""


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_sigkill_at_a_random_moment(tmp_path, seed):
    rng = np.random.default_rng(seed)
    sweep = tmp_path / "sw"
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2]))
    proc = subprocess.Popen([sys.executable, "-c", CAPTURE, str(sweep)], stdout=subprocess.PIPE, env=env)
    assert proc.stdout.readline().strip() == b"started"
    time.sleep(float(rng.uniform(0.4, 1.2)))
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    proc.stdout.close()

    s = read_sweep(sweep)
    assert not s.complete
    assert all("truncated" in str(p) for p in s.problems), s.problems  # nothing else can go wrong
    assert len(s.frames) >= 5
    listed = {f.image for f in s.frames}
    for f in s.frames:  # every listed image is whole
        assert cv2.imread(str(f.image_path)) is not None, f.image
    on_disk = {f"images/{p.name}" for p in (sweep / "images").glob("*.png")}
    assert listed <= on_disk
    extra = sorted(on_disk - listed)
    assert len(extra) <= 1
    if extra:
        assert extra[0] > max(listed)  # only the frame being committed
    assert [f.index for f in s.frames] == sorted(f.index for f in s.frames)
