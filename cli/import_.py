"""``inspect-pipe import FRAMES --log FLIGHT -o SWEEP``: footage from any drone plus its flight log."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from cli._common import SURVEY_HELP, load_plan, note, one_line_errors

HELP = "\n\n".join([
    "Import footage from any drone (a folder of images or a video) plus the autopilot's flight log into a sweep (inspect_pipe.sweep/1), as capture writes it: mosaic, run and report read it unchanged.",
    'FRAMES: a folder of images (capture time from EXIF DateTimeOriginal + SubSecTimeOriginal + OffsetTimeOriginal) or a video file (frame times from the container after its creation time; --video-start when it has none). Frames are resampled to 10 Hz.',
    '--log: a PX4 ULog (.ulg), an ArduPilot DataFlash log (.bin) or a MAVLink telemetry log (.tlog). Each frame gets the vehicle state interpolated at the instant it was taken.',
    'Camera clocks are off by seconds: the offset (camera time minus log time) is found by matching the image motion between frames with the logged motion over the whole flight, and recorded in sweep.json as time_alignment; --time-offset gives it instead.',
    'Examples:',
    'inspect-pipe import DCIM/100MEDIA --log flight.ulg -o out/hold2_sweep --camera camera.yaml',
    'inspect-pipe import inspection.mp4 --log 2026-11-20.tlog -o out/sweep --video-start 2026-11-20T10:31:02Z',
    'inspect-pipe import photos/ --log 00000042.BIN -o out/sweep --time-offset 2.35',
    "Exit 0 on success, 2 on bad input (one line naming the file and the problem; nothing is left under SWEEP's name).",
])


@one_line_errors
def import_(
    frames: Annotated[Path, typer.Argument(help="folder of images, or a video file")],
    log: Annotated[Path, typer.Option("--log", help="flight log: PX4 .ulg, ArduPilot .bin or MAVLink .tlog")],
    out: Annotated[Path, typer.Option("-o", "--out", help="sweep directory to write (new or empty)")],
    camera: Annotated[Optional[Path], typer.Option("--camera", help="camera calibration (OpenCV camera.yaml from `inspect-pipe calibrate`, or ROS camera_info); without it a 60 deg uncalibrated guess")] = None,
    time_offset: Annotated[Optional[float], typer.Option("--time-offset", help="camera clock offset in seconds (camera time minus log time); skips the automatic alignment")] = None,
    video_start: Annotated[Optional[str], typer.Option("--video-start", help="UTC time the video started (ISO 8601), when the file has no creation time")] = None,
    survey: Annotated[Optional[Path], typer.Option("--survey", help=SURVEY_HELP + " Stored in the sweep.")] = None,
) -> None:
    """Import footage from any drone plus its flight log into a sweep."""
    from inspect_pipe.importer import import_footage

    plan = load_plan(survey)
    res = import_footage(frames, log, out, camera_path=camera, time_offset_s=time_offset, video_start=video_start,
                         on_note=lambda m: note(f"note: {m}"), survey_plan=plan)
    a = res.alignment
    conf = "" if a.confidence is None else f", correlation {a.correlation:.3f}, confidence {a.confidence:.2f}"
    typer.echo(f"camera clock offset {a.camera_clock_offset_s:+.3f} s ({a.method}{conf})")
    typer.echo(f"sweep {res.sweep}: {res.frames_written} frames ({res.frames_resampled} of {res.frames_in_footage} at 10 Hz"
               + (f", {res.frames_outside_log} outside the log" if res.frames_outside_log else "") + f") with {res.log_kind} state")
