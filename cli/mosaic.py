"""``inspect-pipe mosaic INPUT -o OUT``."""

from __future__ import annotations

import json
import time
from pathlib import Path

import typer

from cli._common import SURVEY_HELP, StageProgress, choices, fail, load_plan, one_line_errors
from inspect_pipe.capture import load_camera
from inspect_pipe.capture._calibration import scaled_note
from inspect_pipe.mosaic import DETECTORS, MosaicParams, RegisterParams, is_sweep, run_mosaic_folder, run_mosaic_sweep

HELP = """Mosaic a sweep (or a folder of overlapping images, sorted by name) into one seamless image.

Writes OUT/mosaic.png (BGRA: alpha marks covered wall), OUT/mosaic.json (per frame: the 3x3
homography H from frame pixels to mosaic pixels; frames that could not be placed under
"unplaced" with the reason) and, if the sweep falls into disconnected groups, one
OUT/mosaic_group<k>.png per further group. A sweep (a directory with sweep.json, written by
`capture` or `fly --sweep`) is undistorted and rectified with its camera model, and mosaic.json
also gets m_per_px and wall_from_mosaic (mosaic pixel -> wall metres u, v).

--camera camera.yaml (from `inspect-pipe calibrate`, or a ROS camera_info YAML) gives the
calibrated K and distortion: a folder's images are undistorted and the mosaic rectified with it;
a sweep's own camera model is overridden. A calibration of another resolution is scaled when the
aspect ratio is the same (and said so), refused otherwise. mosaic.json records the camera used
(input.camera, with its calibration's source and sha256).

Examples:

  inspect-pipe mosaic ../shared/data/mosaic/synth_rust_sweep/frames -o out/rust

  inspect-pipe mosaic frames/ -o out/m --focal-px 618   # known focal length (else self-calibrated)

  inspect-pipe mosaic frames/ -o out/m --camera camera.yaml   # calibrated camera: undistorted, rectified

  inspect-pipe mosaic out/demo/sweep -o out/demo/mosaic   # a sweep: metric, placed on the wall

Exit 0 on success; 2 on bad input (empty folder, unreadable or truncated images, images of
different sizes, no overlap, a --focal-px the images contradict: then the self-calibrated one is
used), after writing whatever could be mosaicked; OUT's earlier mosaic, if it was made without
such problems, is then kept and nothing replaced. A sweep is read as
`run` reads it: a last frames.jsonl line cut by a crash, a COMPLETE marker that lists more frames
than the disk holds, and frames that cannot be read (or, with --verify, whose sha256 differs
from COMPLETE's) give one warning line; those frames are listed as unplaced with the reason in
mosaic.json and the exit is 0 as long as some frames were placed.
"""

Detector = choices("Detector", DETECTORS)


#: A focal length beyond this many pixels is a typing error (a 6,000 px wide frame behind a 2-degree lens is 170,000)
MAX_FOCAL_PX = 1e6


@one_line_errors
def mosaic(
    input: Path = typer.Argument(..., help="Sweep directory or folder of images (sorted by name)."),
    out: Path = typer.Option(..., "-o", "--out", help="Output directory (created)."),
    detector: Detector = typer.Option("sift", help="Feature detector."),
    focal_px: float = typer.Option(0.0, "--focal-px", help="Camera focal length in pixels, if known. Without it, the focal length (and radial distortion k1, k2) is self-calibrated from the images; mosaic.json records what was found."),
    seed: int = typer.Option(0, min=0, help="Seed of the robust estimators (results are deterministic for a seed)."),
    verify: bool = typer.Option(False, "--verify", help="A sweep: check every file against the sha256 in its COMPLETE marker; frames that differ are unplaced."),
    camera: Path = typer.Option(None, "--camera", help="Camera calibration (camera.yaml from `inspect-pipe calibrate`, or ROS camera_info): K and distortion, over a sweep's own."),
    survey: Path = typer.Option(None, "--survey", help=SURVEY_HELP + " A sweep: the plan's wall and take-off tie place the mosaic on that wall (over the plan stored in the sweep)."),
) -> None:
    detector = detector.value
    plan = load_plan(survey)
    if focal_px < 0 or focal_px > MAX_FOCAL_PX:
        raise fail(f"--focal-px {focal_px:g}: must be positive and at most {MAX_FOCAL_PX:g} px")
    if focal_px and camera is not None:
        raise fail("--focal-px and --camera: give one (the camera file has the focal length)")
    cam = load_camera(camera) if camera is not None else None
    params = MosaicParams(register=RegisterParams(detector=detector, focal_px=focal_px or None, seed=seed))
    progress = StageProgress()  # rich bars on a terminal; none under -q
    t0 = time.monotonic()
    if is_sweep(input):  # camera model and vehicle states come with it
        result = run_mosaic_sweep(input, out, params=params, progress=progress, verify=verify, survey_plan=plan, camera=cam)
    else:
        if verify:
            raise fail(f"{input}: --verify needs a sweep directory (its COMPLETE marker holds the checksums)")
        if plan is not None:
            raise fail(f"{input}: --survey needs a sweep directory (a plain folder has no vehicle positions to place on the wall)")
        result = run_mosaic_folder(input, out, params=params, progress=progress, camera=cam)
    progress.close()
    if not result.published:  # bad input over a good earlier mosaic: that one is kept
        raise fail(result.problems[0])
    if cam is not None and (out / "mosaic.json").is_file():
        used = (json.loads((out / "mosaic.json").read_text()).get("input") or {}).get("camera") or {}
        if scaled_note(used):
            typer.echo(scaled_note(used), err=True)
    n = result.n_input
    unplaced = sum(f not in result.H for f in result.registration.unplaced)  # a lone frame is placed as its own mosaic
    typer.echo(
        f"{out / 'mosaic.json'}: {result.n_placed}/{n} frames placed in {len(result.images)} mosaic(s), "
        f"{unplaced} unplaced, {time.monotonic() - t0:.1f} s"
    )
    if result.warnings:
        more = f" (and {len(result.warnings) - 1} more, listed in mosaic.json)" if len(result.warnings) > 1 else ""
        typer.echo(f"warning: {result.warnings[0]}{more}", err=True)
    if result.problems:
        raise fail(result.problems[0])
