"""The capture service: a rate scheduler on an injected clock, one source, per-frame stamping
(device and host time, UTC, frame counter, exposure, the vehicle state at mid-exposure), and the
sweep writer. Writing never blocks grabbing; every lost frame is counted by cause."""

from __future__ import annotations

import enum
import shutil
import sys
import threading
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

import inspect_pipe
from inspect_pipe.capture._clock import Clock
from inspect_pipe.capture._geometry import CameraModel
from inspect_pipe.capture._exif import ImageMeta
from inspect_pipe.capture._scheduler import RateScheduler
from inspect_pipe.capture._source import FrameSource, Grab, SourceInfo, SourceLost
from inspect_pipe.capture._state import StateFeed, VehicleState
from inspect_pipe.capture._sweep import SweepWriter

__all__ = ["CaptureConfig", "CaptureResult", "Progress", "StopReason", "clock_fit", "run_capture", "state_to_json"]


class StopReason(str, enum.Enum):
    DURATION = "duration reached"
    FRAMES = "frame count reached"
    SOURCE_ENDED = "source ended"
    SOURCE_LOST = "camera lost"
    WRITER_FAILED = "writing failed"
    DISK_LOW = "disk almost full"
    INTERRUPTED = "interrupted"


@dataclass(frozen=True)
class CaptureConfig:
    rate_hz: float = 10.0
    duration_s: float | None = None
    max_frames: int | None = None
    image_format: str = "png"
    png_compression: int | None = None  # None: fast lossless (SUB filter, Huffman-only)
    queue_frames: int = 32
    encoders: int = 2
    min_free_bytes: int = 200 * 2**20  # stop cleanly before the disk is full
    survey: dict = field(default_factory=dict)  # vessel, hold, wall, frame_spacing_m, reference_frame
    survey_plan: dict | None = None  # the survey plan (inspect_pipe.ship.SurveyPlan.to_json()), stored in sweep.json
    time_base: str = "host_monotonic_s"  # or "simulation_s" with a simulated clock
    overwrite: bool = False
    wait_for_writer: bool = False  # simulated time only: wait for the writer instead of dropping
    camera: CameraModel | None = None  # --camera: the calibrated model recorded instead of the source's (fit to its frame size)


@dataclass(frozen=True)
class Progress:
    frames: int
    elapsed_s: float
    rate_hz: float
    drops: int
    bytes_written: int
    queued: int
    no_state: int = 0  # frames written with state null although a vehicle feed was given (link down)


@dataclass(frozen=True)
class CaptureResult:
    reason: StopReason
    detail: str
    frames_grabbed: int
    frames_written: int
    dropped_backpressure: int
    dropped_source: int  # device counter gaps / timestamp gaps
    skipped_deadlines: int  # the loop came back a whole period late
    jitter_s: tuple[float, ...]  # per frame: mid-exposure time minus its schedule
    interval_error_s: tuple[float, ...]  # per frame pair: interval minus nominal
    elapsed_s: float
    bytes_written: int
    clock_fit: dict | None
    writer_error: str | None
    frames_without_state: int = 0  # with a vehicle feed: frames its telemetry did not cover

    @property
    def drops(self) -> int:
        return self.dropped_backpressure + self.dropped_source + self.skipped_deadlines

    def jitter_p99_s(self) -> float:
        e = np.abs(np.asarray(self.interval_error_s))
        return float(np.percentile(e, 99)) if e.size else 0.0

    @property
    def ok(self) -> bool:
        return self.reason in (StopReason.DURATION, StopReason.FRAMES, StopReason.SOURCE_ENDED)


def state_to_json(s: VehicleState | None) -> dict | None:
    if s is None:
        return None

    def r(x, nd=4):
        return None if x is None else round(float(x), nd)

    return {
        "t_s": round(s.t_s, 6),
        "position_m": None if s.position_m is None else [r(v) for v in s.position_m],
        "dist_front_m": r(s.dist_front_m),
        "height_m": r(s.height_m),
        "velocity_m_s": None if s.velocity_m_s is None else [r(v) for v in s.velocity_m_s],
        "est_mode": s.est_mode,
        "fsm": s.fsm,
        "inspection_mode": s.inspection_mode,
    }


def clock_fit(device_s: list[float], host_s: list[float]) -> dict | None:
    """Least-squares ``host = offset + scale * device`` over a sweep (needs >= 3 stamps)."""
    if len(device_s) < 3:
        return None
    d, h = np.asarray(device_s), np.asarray(host_s)
    d0 = d[0]
    A = np.vstack([np.ones_like(d), d - d0]).T
    (off, scale), *_ = np.linalg.lstsq(A, h, rcond=None)
    res = h - A @ np.array([off, scale])
    return {
        "host_s_at_first_device_s": float(off), "first_device_s": float(d0), "scale": float(scale),
        "drift_ppm": float((scale - 1.0) * 1e6), "residual_rms_s": float(np.sqrt(np.mean(res ** 2))), "n": int(len(d)),
    }


def _meta_for(info: SourceInfo, cfg: CaptureConfig, clock: Clock, extra: dict | None) -> dict:
    survey = {"vessel": None, "hold": None, "wall": None, "frame_spacing_m": None, "reference_frame": None}
    survey.update(cfg.survey)
    doc = {
        "created_utc": clock.utc(clock.now()),
        "software_version": inspect_pipe.__version__,
        "source": {"kind": info.kind, "description": info.description, "triggered": info.triggered, **info.extra},
        "rate_hz": None if info.paced else cfg.rate_hz,
        "time_base": cfg.time_base,
        "camera": info.camera.to_json(),
        "cam_to_body": info.cam_to_body.to_json(),
        "survey": survey,
    }
    if cfg.survey_plan is not None:
        doc["survey_plan"] = cfg.survey_plan
    if extra:
        doc.update(extra)
    return doc


def run_capture(
    source: FrameSource,
    sweep_dir: str | Path,
    *,
    clock: Clock,
    config: CaptureConfig = CaptureConfig(),
    state_feed: StateFeed | None = None,
    sweep_extra: Callable[[], dict] | dict | None = None,
    on_progress: Callable[[Progress], None] | None = None,
    progress_every_s: float = 1.0,
    stop: threading.Event | None = None,
    writer_factory: Callable[..., SweepWriter] = SweepWriter,
    on_frame: Callable[[np.ndarray, dict, CameraModel], None] | None = None,
) -> CaptureResult:
    """Capture from ``source`` into ``sweep_dir`` until the duration, frame count, end of source,
    a lost camera, a write failure or ``stop``. The sweep is readable whatever the reason.

    ``on_frame(image, record, camera)`` sees each frame the writer accepted (its
    frames.jsonl record and the sweep's camera model): the live mosaic's tap
    (``inspect_pipe.mosaic.LiveFeed.tap``). It must not block: it runs in the grabbing loop."""
    info = source.open()
    try:
        if config.camera is not None:  # checked against the frame size before anything is written
            from inspect_pipe.capture._calibration import fit_camera

            info = replace(info, camera=fit_camera(config.camera, info.camera.width, info.camera.height,
                                                   frames=f"the frames of {info.description}"))
        extra = dict((sweep_extra() if callable(sweep_extra) else sweep_extra) or {})
        if hasattr(source, "sweep_extra"):  # a simulated source describes its world
            extra.update(source.sweep_extra(Path(sweep_dir)))
        writer = writer_factory(
            sweep_dir, _meta_for(info, config, clock, extra), image_format=config.image_format,
            png_compression=config.png_compression, queue_frames=config.queue_frames, encoders=config.encoders,
            overwrite=config.overwrite,
        )
    except BaseException:
        source.close()
        raise
    # The grabbing thread must get the GIL back within a fraction of a millisecond of its deadline;
    # Python's default switch interval (5 ms) would show up as timestamp jitter while the writer's
    # threads run Python code. Restored when the capture ends.
    switch = sys.getswitchinterval()
    sys.setswitchinterval(min(switch, 0.0005))
    sched = None if info.paced else RateScheduler(config.rate_hz, clock)
    t_origin = 0.0 if config.time_base == "simulation_s" else clock.now()
    reason, detail = StopReason.SOURCE_ENDED, ""
    grabbed = 0
    no_state = 0
    dropped_source = 0
    jitter: list[float] = []
    intervals: list[float] = []
    dev, host = [], []
    last_id: int | None = None
    last_mid: float | None = None
    last_sched: float | None = None
    last_progress = clock.now()
    t_start = clock.now()
    try:
        while True:
            if stop is not None and stop.is_set():
                reason = StopReason.INTERRUPTED
                break
            if config.max_frames is not None and grabbed >= config.max_frames:
                reason = StopReason.FRAMES
                break
            if sched is not None:
                if config.duration_s is not None and sched.next_deadline_s - sched.t0 >= config.duration_s - 1e-9:
                    reason = StopReason.DURATION
                    break
                tick = sched.wait()
                deadline = tick.deadline_s
            else:
                if config.duration_s is not None and clock.now() - t_start >= config.duration_s:
                    reason = StopReason.DURATION
                    break
                deadline = clock.now()
            try:
                g: Grab = source.grab(deadline)
            except StopIteration:
                reason = StopReason.SOURCE_ENDED
                break
            except SourceLost as err:
                reason, detail = StopReason.SOURCE_LOST, str(err)
                break
            t_mid = g.t_mid_s
            if g.scheduled_mid_s is not None:
                sched_mid = g.scheduled_mid_s
            elif sched is not None and info.triggered:
                sched_mid = deadline + g.exposure_s / 2
            else:
                sched_mid = t_mid  # free-running: the camera's phase is its own; intervals still tell jitter
            jitter.append(t_mid - sched_mid)
            if last_mid is not None:
                nominal = (sched_mid - last_sched) if sched_mid != t_mid or sched is None else (sched.period_s if sched else 0.0)
                intervals.append((t_mid - last_mid) - nominal)
            last_mid, last_sched = t_mid, sched_mid
            if g.frame_id is not None:
                if last_id is not None and g.frame_id > last_id + 1:
                    dropped_source += g.frame_id - last_id - 1
                last_id = g.frame_id
            dropped_source += g.lost_before
            if g.t_device_s is not None:
                dev.append(g.t_device_s)
                host.append(g.t_exposure_start_s)
            state = g.state if g.state is not None else (state_feed.state_at(t_mid) if state_feed is not None else None)
            if state_feed is not None and state is None:
                no_state += 1  # the link is down or late: the frame is kept, with state null
            utc = clock.utc(t_mid)
            record = {
                "t_s": round(t_mid - t_origin, 6),
                "t_host_s": round(g.t_host_s, 6),
                "t_utc": utc,
                "t_device_s": None if g.t_device_s is None else round(g.t_device_s, 6),
                "frame_id": g.frame_id,
                "exposure_s": round(g.exposure_s, 7),
                "gain": g.gain,
                "state": state_to_json(state),
            }
            if g.truth is not None:
                record["truth"] = g.truth
            h, w = g.image.shape[:2]
            fx, fy, cx, cy = (float(info.camera.K[0, 0]), float(info.camera.K[1, 1]), float(info.camera.K[0, 2]), float(info.camera.K[1, 2]))
            xmp = {"frame_index": grabbed, "t_s": record["t_s"], "exposure_s": record["exposure_s"], "fx_px": round(fx, 3),
                   "fy_px": round(fy, 3), "cx_px": round(cx, 3), "cy_px": round(cy, 3),
                   "dist": " ".join(f"{d:.6g}" for d in info.camera.dist)}
            if state is not None and state.position_m is not None:
                xmp.update({"position_m": " ".join(f"{v:.4f}" for v in state.position_m), "dist_front_m": record["state"]["dist_front_m"]})
            meta = ImageMeta(make=info.kind, model=info.description[:60], software=f"inspect-pipe {inspect_pipe.__version__}",
                             datetime_utc=utc, exposure_s=g.exposure_s, width=w, height=h, xmp=xmp)
            if config.wait_for_writer:
                writer.wait_for_room()
            written = writer.submit(grabbed, g.image, record, meta)
            if on_frame is not None and written:
                on_frame(g.image, record, info.camera)
            grabbed += 1
            if writer.error is not None:
                reason, detail = StopReason.WRITER_FAILED, writer.error
                break
            now = clock.now()
            if now - last_progress >= progress_every_s:
                last_progress = now
                free = shutil.disk_usage(writer.path).free
                if free < config.min_free_bytes:
                    reason, detail = StopReason.DISK_LOW, f"{writer.path}: only {free / 2**20:.0f} MiB free"
                    break
                if on_progress is not None:
                    el = now - t_start
                    on_progress(Progress(writer.stats.written, el, grabbed / el if el > 0 else 0.0,
                                         writer.stats.dropped_backpressure + dropped_source + (sched.skipped_total if sched else 0),
                                         writer.stats.bytes_written, writer.queued, no_state))
    except KeyboardInterrupt:
        reason = StopReason.INTERRUPTED
    finally:
        source.close()
        elapsed = clock.now() - t_start
        fit = clock_fit(dev, host)
        summary = {"stop_reason": reason.value, "detail": detail, "frames_grabbed": grabbed, "frames_without_state": no_state if state_feed is not None else None,
                   "dropped_source": dropped_source, "skipped_deadlines": sched.skipped_total if sched else 0,
                   "elapsed_s": round(elapsed, 3), "device_to_host_clock": fit}
        if state_feed is not None and hasattr(state_feed, "describe"):  # its clock map as it stood at the end
            summary["vehicle"] = state_feed.describe()
        stats = writer.close(summary)
        sys.setswitchinterval(switch)
    if writer.error is not None and reason not in (StopReason.WRITER_FAILED,):
        reason, detail = StopReason.WRITER_FAILED, writer.error
    return CaptureResult(
        reason=reason, detail=detail, frames_grabbed=grabbed, frames_written=stats.written,
        dropped_backpressure=stats.dropped_backpressure, dropped_source=dropped_source,
        skipped_deadlines=sched.skipped_total if sched else 0, jitter_s=tuple(jitter), interval_error_s=tuple(intervals),
        elapsed_s=elapsed, bytes_written=stats.bytes_written, clock_fit=fit, writer_error=writer.error,
        frames_without_state=no_state,
    )
