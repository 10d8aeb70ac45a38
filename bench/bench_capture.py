"""Capture benchmark.

    python -m bench --only capture            # 60 s of real-time capture per size
    BENCH_CAPTURE_S=600 python -m bench --only capture   # the full 10 minutes per size

* Real-time capture at 10 Hz on the host monotonic clock, at 752x480 and 1280x1024, from a
  triggered source serving simulated wall frames (rendered beforehand, so the measurement is the
  service: scheduler, stamping, EXIF, PNG encoding, atomic writes): dropped frames (writer
  back-pressure, late deadlines), timestamp jitter (exposure start minus its deadline, and
  frame-to-frame interval minus 100 ms), p99 and max. Goal: 0 drops, p99 <= 5 ms.
* Writer headroom: frames/s the sweep writer sustains (lossless PNG, 2 encoder threads, one
  committer) when fed as fast as it accepts frames. Goal: >= 30 frames/s (3x the 10 Hz rate).
* Simulated camera: render time per frame of the textured-wall scenario (``fly --sweep`` cost).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

from inspect_pipe.capture import (
    CameraModel,
    CaptureConfig,
    Grab,
    ManualClock,
    MonotonicClock,
    SourceInfo,
    SweepWriter,
    read_sweep,
    run_capture,
)
from inspect_pipe.capture._geometry import rotation_from_rpy
from inspect_pipe.capture._source import default_cam_to_body
from inspect_pipe.capture._geometry import Pose
from inspect_pipe.capture.sources.sim import SimCameraParams, SimSource, WallRenderer
from inspect_pipe.flight import load_scenario
from inspect_pipe.ship import wall_frame

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "scenarios" / "inspection_sweep_wall.yaml"
SIZES = ((752, 480), (1280, 1024))


def _frames(size: tuple[int, int], n: int = 24) -> list[np.ndarray]:
    """Simulated wall frames along a lateral pass (realistic content for the PNG encoder)."""
    import cv2

    sc = load_scenario(SCENARIO)
    tex = sc.world.front_wall_texture
    cam = CameraModel.from_hfov(size[0], size[1], 60.0, SimCameraParams().dist)
    r = WallRenderer(cam, cv2.imread(str(tex.image)), tex.m_per_px, tex.origin_uv, wall_frame("front", 12.0, 10.0), 16.0, SimCameraParams())
    c2b = default_cam_to_body()
    rng = np.random.default_rng(0)
    out = []
    for k in range(n):
        R = rotation_from_rpy(0.01, -0.02, 0.0)
        pose = Pose(R @ c2b.R, np.array([10.5, 0.8 - 0.05 * k, 1.8]) + R @ c2b.t)
        out.append(r.render([pose], 1.0, rng)[0])
    return out


class _BankSource:
    """Software-triggered camera serving pre-rendered frames on the real clock."""

    def __init__(self, clock, frames, exposure_s=0.004):
        self.clock, self.frames, self.exposure_s, self.k = clock, frames, exposure_s, 0
        h, w = frames[0].shape[:2]
        self.cam = CameraModel.from_hfov(w, h, 60.0)

    def open(self):
        return SourceInfo("bench", "pre-rendered wall frames", self.cam, triggered=True)

    def grab(self, deadline_s):
        self.clock.sleep_until(deadline_s)
        t0 = self.clock.now()  # "trigger"
        img = self.frames[self.k % len(self.frames)]
        self.k += 1
        return Grab(img, t0, self.exposure_s, self.clock.now(), frame_id=self.k, t_device_s=t0)

    def close(self):
        pass


def _realtime(frames, seconds: float, tmp: Path) -> dict:
    clock = MonotonicClock()
    src = _BankSource(clock, frames)
    res = run_capture(src, tmp, clock=clock, config=CaptureConfig(rate_hz=10.0, duration_s=seconds))
    s = read_sweep(tmp)
    start_err = np.abs(np.array([f.t_s for f in s.frames]) - np.array([f.t_s for f in s.frames])[0]
                       - 0.1 * np.array([f.index for f in s.frames]))  # exposure start vs k * 100 ms
    iv = np.abs(np.asarray(res.interval_error_s))
    return {
        "frames": res.frames_written, "expected": int(round(seconds * 10)), "drops": res.drops,
        "drops_writer": res.dropped_backpressure, "late": res.skipped_deadlines,
        "start_p99_ms": float(np.percentile(start_err, 99)) * 1e3, "start_max_ms": float(start_err.max()) * 1e3,
        "iv_p99_ms": float(np.percentile(iv, 99)) * 1e3, "iv_max_ms": float(iv.max()) * 1e3,
        "mib": res.bytes_written / 2**20,
    }


def _headroom(frames, n: int, tmp: Path, adaptive: bool) -> dict:
    h, w = frames[0].shape[:2]
    wr = SweepWriter(tmp, {"camera": CameraModel.from_hfov(w, h, 60.0).to_json()}, queue_frames=8, encoders=2, adaptive=adaptive)
    t0 = time.perf_counter()
    i = 0
    while i < n:
        if wr.queued < wr.queue_frames:
            wr.submit(i, frames[i % len(frames)], {"t_s": i * 0.1, "exposure_s": 0.004})
            i += 1
        else:
            time.sleep(0.0005)
    stats = wr.close({})
    dt = time.perf_counter() - t0
    return {"fps": n / dt, "mib_per_frame": stats.bytes_written / n / 2**20, "stored": stats.stored_uncompressed}


def _sim_render_ms(n: int, tmp: Path) -> float:
    sc = load_scenario(SCENARIO)
    clock = ManualClock()
    src = SimSource(sc, clock=clock)
    src.open()  # flies the scenario
    t0 = time.perf_counter()
    for k in range(n):
        src.grab(8.0 + 0.1 * k)
    return (time.perf_counter() - t0) / n * 1e3


def run(data: Path) -> str:  # noqa: ARG001 - the capture benchmark brings its own scenes
    seconds = float(os.environ.get("BENCH_CAPTURE_S", "60"))
    load0 = os.getloadavg()[0]
    rows_rt, rows_hr = [], []
    with tempfile.TemporaryDirectory(prefix="bench_capture_") as td:
        for size in SIZES:
            frames = _frames(size)
            rt = _realtime(frames, seconds, Path(td) / f"rt_{size[0]}")
            hr = _headroom(frames, 120, Path(td) / f"hr_{size[0]}", adaptive=False)
            ha = _headroom(frames, 120, Path(td) / f"ha_{size[0]}", adaptive=True)
            rows_rt.append((size, rt))
            rows_hr.append((size, hr, ha))
        sim_ms = _sim_render_ms(50, Path(td))
    load1 = os.getloadavg()[0]
    lines = [
        "## Capture",
        "",
        f"Real-time capture at 10 Hz on the host monotonic clock, {seconds:.0f} s per size "
        "(`BENCH_CAPTURE_S=600` for the 10-minute run), from a software-triggered source serving "
        "pre-rendered simulated wall frames: the whole service (scheduler, stamping, EXIF/XMP, lossless "
        "PNG, atomic writes, flushed `frames.jsonl`). Jitter: exposure start minus its 100 ms grid, and "
        "frame interval minus 100 ms. Goals: 0 drops, p99 <= 5 ms, writer >= 30 frames/s. "
        f"Machine load average {load0:.1f} at the start, {load1:.1f} at the end, on {os.cpu_count()} cores shared "
        "with other jobs (this process niced): with the cores busy elsewhere the grabbing thread waits for a "
        "core, and the p99 of this table grows with the load; compare runs at equal load.",
        "",
        "| size | frames | drops (writer / late) | start jitter p99 / max | interval jitter p99 / max | disk |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for (w, h), r in rows_rt:
        lines.append(
            f"| {w}x{h} | {r['frames']} / {r['expected']} | {r['drops']} ({r['drops_writer']} / {r['late']}) | "
            f"{r['start_p99_ms']:.2f} / {r['start_max_ms']:.2f} ms | {r['iv_p99_ms']:.2f} / {r['iv_max_ms']:.2f} ms | {r['mib']:.0f} MiB |"
        )
    lines += ["", "Writer fed as fast as it accepts frames (120 frames, queue of 8): compressed PNG only, and as "
              "shipped (adaptive: while the queue is over half full, PNGs are stored uncompressed, still lossless).", "",
              "| size | compressed PNG: sustained (headroom) | per frame | adaptive: sustained (headroom) | stored frames | per frame |",
              "|---|---:|---:|---:|---:|---:|"]
    for (w, h), r, a in rows_hr:
        lines.append(f"| {w}x{h} | {r['fps']:.1f} frames/s ({r['fps'] / 10:.1f}x) | {r['mib_per_frame']:.2f} MiB | "
                     f"{a['fps']:.1f} frames/s ({a['fps'] / 10:.1f}x) | {a['stored']}/120 | {a['mib_per_frame']:.2f} MiB |")
    lines += ["", f"Simulated camera (`fly --sweep`, 752x480, textured wall, distortion, noise): {sim_ms:.1f} ms per frame "
              f"({1000 / sim_ms:.0f} frames/s of simulated time, one process)."]
    return "\n".join(lines) + "\n"
