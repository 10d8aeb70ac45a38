"""``inspect-pipe capture --source SPEC -o SWEEP``: record a sweep from a camera."""

from __future__ import annotations

import json
import signal
import threading
from pathlib import Path
from typing import Annotated, Optional

import typer

from cli._common import SURVEY_HELP, choices, console, fail, load_plan, one_line_errors, progress_enabled
from inspect_pipe.capture import SOURCE_SPECS, CaptureConfig, MonotonicClock, Progress, load_camera, open_source, run_capture
from inspect_pipe.capture._calibration import scaled_note
from inspect_pipe.capture._vehicle_feed import open_vehicle_feed
from inspect_pipe.errors import InputError

HELP = f"""Capture a sweep (inspect_pipe.sweep/1: sweep.json, frames.jsonl, images/, COMPLETE) from a
camera at a fixed rate.

--source is one of {SOURCE_SPECS}. A simulated source (sim:SCENARIO) flies the scenario and renders
its camera on the simulation clock, faster than real time; replay:PATH plays a sweep, an image
folder or a video file at its recorded timing.

Examples:

  inspect-pipe capture --source sim:scenarios/inspection_sweep_wall.yaml -o out/sweep_sim

  inspect-pipe capture --source v4l2:/dev/video0 -o out/sweep1 --rate 10 --duration 600

  inspect-pipe capture --source ids --exposure 0.002 -o out/hold2 --vessel "MV Example" --hold 2 --wall fwd

  inspect-pipe capture --source v4l2:/dev/video0 --vehicle mavlink:udp:0.0.0.0:14550 --survey plan.yaml -o out/s2

With --vehicle each frame carries the autopilot's state at mid-exposure (LOCAL_POSITION_NED,
ATTITUDE, DISTANCE_SENSOR by orientation, landed state), interpolated between messages on a clock
mapped with TIMESYNC; if the link dies, frames keep coming with state null and the live line
counts them. --survey stores the survey plan in the sweep (docs/ship.md).

--camera camera.yaml (from `inspect-pipe calibrate`, or a ROS camera_info YAML) records the
calibrated camera in sweep.json, with where it came from (camera.calibration: source, sha256,
rms_px); without it a real camera is an uncalibrated 60 deg guess and sweep.json says so. A
simulated source renders through the calibrated lens. A calibration of another resolution is
scaled when the aspect ratio is the same (and said so), refused otherwise (exit 2, nothing
written).

  inspect-pipe capture --source v4l2:/dev/video0 --camera camera.yaml -o out/sweep1

  inspect-pipe capture --source replay:out/sweep1 -o out/sweep1_copy

The live mosaic (on by default; --no-live-mosaic): each frame taken in inspection mode (every frame
when the source has no vehicle state) is placed on a low-resolution mosaic on its own thread beside
the writer; when it falls behind it skips frames, never the capture. The live line shows the share
of the swept wall imaged at usable resolution and sharpness, the gaps, how far behind it is, and a
stream that stalls (no frame for 3 s); the last line is its summary.

Ctrl-C stops cleanly (the sweep gets its COMPLETE marker). Exit 0 when the sweep ended as asked
(duration, end of the source), 1 when the camera was lost or writing failed (the sweep stays
readable), 2 on bad input.
"""

ImageFormat = choices("ImageFormat", ("png", "jpg"))


class _LiveLine:
    """One live status line (rich.live) on a terminal; nothing otherwise or under -q. With the live
    mosaic, a second line: coverage, gaps, how far behind, a stalled stream. The line is redrawn
    4 times a second from the last progress and the mosaic's status, so a stream that stops shows."""

    def __init__(self, feed=None) -> None:
        self.live = None
        self.feed = feed
        self.text = "starting capture"
        if progress_enabled():
            from rich.live import Live
            from rich.text import Text

            self._text = Text
            # the summary line replaces it
            self.live = Live(console=console, refresh_per_second=4, transient=True, get_renderable=self._render)
            self.live.start()

    def _render(self):
        return self._text(self.text + ("\n" + self.feed.status().line() if self.feed is not None else ""))

    def __call__(self, p: Progress) -> None:
        self.text = (f"{p.frames} frames  {p.elapsed_s:6.1f} s  {p.rate_hz:5.2f} Hz  drops {p.drops}  "
                     f"{p.bytes_written / 2**20:7.1f} MiB  queue {p.queued}" + (f"  no vehicle state {p.no_state}" if p.no_state else ""))

    def close(self) -> None:
        if self.live is not None:
            self.live.stop()
            self.live = None


@one_line_errors
def capture(
    source: Annotated[str, typer.Option("--source", help=SOURCE_SPECS)],
    out: Annotated[Path, typer.Option("-o", "--out", help="sweep directory to create")],
    rate: Annotated[float, typer.Option("--rate", help="frames per second")] = 10.0,
    duration: Annotated[Optional[float], typer.Option("--duration", help="seconds to capture (default: until the source ends or Ctrl-C)")] = None,
    frames: Annotated[Optional[int], typer.Option("--frames", help="stop after this many frames")] = None,
    image_format: Annotated[ImageFormat, typer.Option("--format", help="png (lossless) or jpg")] = ImageFormat.png,
    exposure: Annotated[Optional[float], typer.Option("--exposure", help="manual exposure, s (default: the camera's)")] = None,
    speed: Annotated[float, typer.Option("--speed", help="replay: play this many times faster than recorded")] = 1.0,
    vessel: Annotated[Optional[str], typer.Option("--vessel", help="survey: vessel name")] = None,
    hold: Annotated[Optional[str], typer.Option("--hold", help="survey: cargo hold")] = None,
    wall: Annotated[Optional[str], typer.Option("--wall", help="survey: wall (e.g. fwd bulkhead)")] = None,
    frame_spacing: Annotated[Optional[float], typer.Option("--frame-spacing", help="survey: ship frame spacing, m")] = None,
    reference_frame: Annotated[Optional[str], typer.Option("--reference-frame", help="survey: ship frame number at the wall's left edge")] = None,
    vehicle: Annotated[Optional[str], typer.Option("--vehicle", help="vehicle state for every frame: mavlink:URL (a PX4/ArduPilot autopilot; e.g. mavlink:udp:0.0.0.0:14550) or sim:SCENARIO.yaml; interpolated at mid-exposure")] = None,
    camera: Annotated[Optional[Path], typer.Option("--camera", help="camera calibration (camera.yaml from `inspect-pipe calibrate`, or ROS camera_info); default: the source's own model (a 60 deg guess for real cameras)")] = None,
    survey_plan: Annotated[Optional[Path], typer.Option("--survey", help=SURVEY_HELP + " Stored in the sweep.")] = None,
    live_mosaic: Annotated[bool, typer.Option("--live-mosaic/--no-live-mosaic", help="place each frame on a low-resolution live mosaic beside the writer and show its coverage and gaps on the live line")] = True,
) -> None:
    if not (0 < rate <= 200):
        raise fail(f"--rate {rate}: must be in (0, 200] Hz")
    if duration is not None and duration <= 0:
        raise fail(f"--duration {duration}: must be > 0 s")
    if frames is not None and frames < 1:
        raise fail(f"--frames {frames}: must be at least 1")
    if exposure is not None and not (0 < exposure <= 1.0):
        raise fail(f"--exposure {exposure}: must be in (0, 1] s")
    if frame_spacing is not None and frame_spacing <= 0:
        raise fail(f"--frame-spacing {frame_spacing}: must be > 0 m")
    image_format = image_format.value
    if ":" not in source and source != "ids":
        raise InputError(f"--source {source}", "unknown source", f"one of {SOURCE_SPECS}")
    survey = {k: v for k, v in {"vessel": vessel, "hold": hold, "wall": wall, "frame_spacing_m": frame_spacing,
                                "reference_frame": reference_frame}.items() if v is not None}
    if not (0 < speed <= 1000):
        raise fail(f"--speed {speed}: must be in (0, 1000]")
    plan = load_plan(survey_plan)
    cam = load_camera(camera) if camera is not None else None
    src, clock, time_base = open_source(source, clock=MonotonicClock(), rate_hz=rate, exposure_s=exposure, speed=speed, camera=cam)
    feed, extra = None, {}
    if vehicle is not None:
        if time_base == "simulation_s":
            src.close()
            raise fail(f"--vehicle {vehicle}: a simulated camera already carries its vehicle's state")
        try:
            feed, odometry = open_vehicle_feed(vehicle, clock=clock.now)
        except BaseException:
            src.close()
            raise
        extra = {"odometry_frame": odometry, "vehicle": feed.describe()}
    if time_base == "simulation_s":  # the scenario's camera section sets the simulated camera
        rate = src.scenario.camera.fps if rate == 10.0 else rate
    cfg = CaptureConfig(rate_hz=rate, duration_s=duration, max_frames=frames, image_format=image_format,
                        survey=survey, time_base=time_base, wait_for_writer=time_base == "simulation_s",
                        survey_plan=None if plan is None else plan.to_json(), camera=cam)
    stop = threading.Event()
    old = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    mosaic = None
    if live_mosaic:
        from inspect_pipe.mosaic import LiveFeed

        mosaic = LiveFeed(clock=clock.now)  # the stream's clock: simulated time for sim:
    live = _LiveLine(mosaic)
    try:
        res = run_capture(src, out, clock=clock, config=cfg, on_progress=live, stop=stop, state_feed=feed, sweep_extra=extra,
                          on_frame=None if mosaic is None else mosaic.tap(block=cfg.wait_for_writer))
    except KeyboardInterrupt:  # pragma: no cover - run_capture handles it; belt and braces
        res = None
    finally:
        live.close()
        final = mosaic.close() if mosaic is not None else None
        signal.signal(signal.SIGTERM, old)
        if feed is not None:
            feed.close()
    if res is None:
        raise typer.Exit(130)
    if cam is not None and (out / "sweep.json").is_file():
        note = scaled_note(json.loads((out / "sweep.json").read_text()).get("camera"))
        if note:
            typer.echo(note, err=True)
    jit = res.jitter_p99_s() * 1000
    typer.echo(
        f"{out}: {res.frames_written} frames, {res.reason.value}{': ' + res.detail if res.detail else ''}; "
        f"drops {res.drops} (writer {res.dropped_backpressure}, camera {res.dropped_source}, late {res.skipped_deadlines}); "
        f"interval jitter p99 {jit:.2f} ms; {res.bytes_written / 2**20:.1f} MiB"
        + (f"; {res.frames_without_state} frames without vehicle state (link down or late)" if feed is not None else "")
    )
    if final is not None:
        typer.echo(f"{final.line()}; {final.p95_cpu_ms:.0f} ms CPU a frame (p95)")
    problems = getattr(src, "problems", ())
    if problems:
        raise fail(str(problems[0]))
    if not res.ok and res.reason.name != "INTERRUPTED":
        typer.echo(f"error: {res.detail or res.reason.value}", err=True)
        raise typer.Exit(1)
