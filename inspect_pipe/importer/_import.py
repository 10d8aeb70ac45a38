"""``inspect-pipe import``: footage from any drone plus its flight log -> a sweep.

The sweep is the same ``inspect_pipe.sweep/1`` directory ``capture`` writes (``SweepWriter``), so
``mosaic``, ``run`` and ``report`` read it unchanged. Each frame carries the vehicle state
interpolated at the instant it was taken (on the log's clock, after the camera clock offset):

- ``position_m``: the autopilot's local position (NED) in the flight's *take-off frame*
  (``odometry_frame: takeoff`` in sweep.json, as ``capture --vehicle mavlink:`` writes it): origin
  at the log's local origin (where the estimator started: the take-off point), x along the heading
  of the log's first attitude sample, y to its left, z up. A survey plan's ``takeoff`` (``mosaic
  --survey``, ``run --survey``) ties it to the hold.
- ``dist_front_m``: the forward range sensor (None without one, or with no echo);
  ``height_m``: the downward range sensor, else the height above the local origin.
- ``velocity_m_s``: the logged velocity in the heading frame (x forward, y left, z up), as the
  simulator's sweeps record it; ``rpy_rad``: roll, pitch, and yaw in the take-off frame.
- ``fsm``: the landed state where the log has it (``landed``, ``taking_off``, ``flying``,
  ``landing``), so mosaic skips the frames taken on the ground.

Everything is written into a temporary directory beside ``SWEEP`` and renamed into place at the
end: a failed import leaves nothing under the sweep's name.
"""

from __future__ import annotations

import datetime as _dt
import math
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from inspect_pipe.capture._clock import utc_iso
from inspect_pipe.capture._geometry import CameraModel
from inspect_pipe.capture._source import default_cam_to_body
from inspect_pipe.capture._sweep import SweepWriter
from inspect_pipe.errors import InputError
from inspect_pipe.importer._align import Alignment, find_offset, image_motion, interp_quat
from inspect_pipe.importer._footage import Footage, open_footage, resample
from inspect_pipe.importer._logs import FlightTrack, read_flight_log

#: Below this confidence of the camera clock offset the import is refused (docs/import.md): the right logs of
#: the measured flights gave 0.79-0.93, another flight's log 0.13-0.25, a log of another vehicle 0.00.
MIN_CONFIDENCE = 0.5

__all__ = ["ImportResult", "import_footage", "DEFAULT_HFOV_DEG", "MAX_OFFSET_S"]

DEFAULT_HFOV_DEG = 60.0  # the uncalibrated guess every real camera source makes
MAX_OFFSET_S = 10.0  # camera clock offsets searched when log and camera both keep UTC
MAX_RANGE_GAP_S = 0.5  # a range reading is interpolated only between samples this close


@dataclass(frozen=True)
class ImportResult:
    sweep: Path
    frames_in_footage: int
    frames_resampled: int
    frames_written: int
    frames_outside_log: int
    alignment: Alignment
    log_kind: str
    seconds: dict


def _interp_range(t: np.ndarray, r: np.ndarray, tq: np.ndarray) -> np.ndarray:
    """Range at ``tq``, NaN where a neighbour has no echo or the readings are too far apart."""
    if len(t) == 0:
        return np.full(len(tq), np.nan)
    i = np.clip(np.searchsorted(t, tq), 1, max(1, len(t) - 1))
    if len(t) == 1:
        return np.where(np.abs(tq - t[0]) < 1e-9, r[0], np.nan)
    t0, t1, r0, r1 = t[i - 1], t[i], r[i - 1], r[i]
    w = np.clip((tq - t0) / np.maximum(t1 - t0, 1e-9), 0.0, 1.0)
    out = r0 + w * (r1 - r0)
    bad = (t1 - t0 > MAX_RANGE_GAP_S) | (tq < t[0]) | (tq > t[-1])
    return np.where(bad, np.nan, out)


def _euler(q: np.ndarray) -> np.ndarray:
    """(N, 3) roll, pitch, yaw (ZYX) of body FRD -> NED quaternions."""
    w, x, y, z = q.T
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=1)


def frame_states(track: FlightTrack, t_log: np.ndarray) -> list[dict]:
    """The vehicle state (sweep ``state`` objects) at each log time (all inside the log), in the
    flight's take-off frame (``odometry_frame: takeoff``, as ``capture --vehicle mavlink:`` writes):
    origin at the log's local origin, x along the heading of the log's first attitude, y left, z up."""
    pos = np.stack([np.interp(t_log, track.t_pos, track.pos_ned[:, i]) for i in range(3)], axis=1)
    vel = np.stack([np.interp(t_log, track.t_pos, track.vel_ned[:, i]) for i in range(3)], axis=1)
    rpy_ned = _euler(interp_quat(track, t_log))
    yaw0 = float(_euler(track.quat[:1])[0, 2])  # the take-off heading (NED)
    ranges = {k: _interp_range(t, r, t_log) for k, (t, r) in track.ranges.items()}
    nan = np.full(len(t_log), np.nan)
    front, down = ranges.get("forward", nan), ranges.get("down", nan)
    fsm: list[str | None] = [None] * len(t_log)
    if track.landed is not None:
        lt, ls = track.landed
        j = np.searchsorted(lt, t_log, side="right") - 1
        fsm = [ls[max(k, 0)] for k in j]  # before the first report: the first one
    c0, s0 = math.cos(yaw0), math.sin(yaw0)
    out = []
    for k in range(len(t_log)):
        n, e, d = pos[k]
        vn, ve, vd = vel[k]
        roll, pitch, yaw_ned = rpy_ned[k]
        x, y = c0 * n + s0 * e, -(-s0 * n + c0 * e)  # NED -> take-off frame (forward, left)
        vx, vy = c0 * vn + s0 * ve, -(-s0 * vn + c0 * ve)
        yaw = -(yaw_ned - yaw0)  # heading in the take-off frame (counter-clockwise from its x)
        c, s = math.cos(yaw), math.sin(yaw)
        out.append({
            "t_s": round(float(t_log[k]), 6),
            "position_m": [round(float(x), 4), round(float(y), 4), round(float(-d), 4)],
            "dist_front_m": None if not np.isfinite(front[k]) else round(float(front[k]), 4),
            "height_m": round(float(down[k] if np.isfinite(down[k]) else -d), 4),
            "velocity_m_s": [round(c * vx + s * vy, 4), round(-s * vx + c * vy, 4), round(float(-vd), 4)],
            "est_mode": None,
            "fsm": fsm[k],
            "inspection_mode": None,
            "rpy_rad": [round(float(roll), 5), round(float(-pitch), 5), round(float(math.atan2(s, c)), 5)],
        })
    return out


def _camera(camera_path: Path | None, footage: Footage) -> CameraModel:
    if camera_path is None:
        return CameraModel.from_hfov(footage.width, footage.height, DEFAULT_HFOV_DEG, name="uncalibrated")
    from inspect_pipe.capture._calibration import fit_camera, load_camera

    return fit_camera(load_camera(camera_path), footage.width, footage.height, where=str(camera_path),
                      frames=f"the frames of {footage.source}")


class _ImportWriter(SweepWriter):
    """The sweep writer, taking a JPEG's own bytes as they are (no decoding, no second lossy
    encoding: the drone's file, EXIF included, is the sweep's image)."""

    def _encode(self, image, image_meta):  # type: ignore[override]
        if isinstance(image, (bytes, bytearray)):
            return bytes(image)
        return super()._encode(image, image_meta)


def _check_out(out: Path) -> None:
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise InputError(str(out), "exists and is not an empty directory", "give a new sweep directory")


def import_footage(
    frames_path: str | Path,
    log_path: str | Path,
    out: str | Path,
    *,
    camera_path: str | Path | None = None,
    time_offset_s: float | None = None,
    video_start: str | None = None,
    rate_hz: float = 10.0,
    max_offset_s: float = MAX_OFFSET_S,
    on_note: Callable[[str], None] | None = None,
    survey_plan=None,
) -> ImportResult:
    """Import footage + flight log into a new sweep at ``out`` (see the module docstring).
    ``survey_plan`` (``inspect_pipe.ship.SurveyPlan``) is stored in the sweep."""
    note = on_note or (lambda _m: None)
    out = Path(out)
    _check_out(out)
    secs: dict[str, float] = {}
    t0 = time.perf_counter()
    footage = open_footage(frames_path, video_start=video_start)
    frames = resample(footage.frames, rate_hz)
    secs["footage"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    track = read_flight_log(log_path)
    secs["log"] = time.perf_counter() - t0
    if track.skipped:
        note(f"{log_path}: {track.skipped} garbled stretch(es) skipped, with the messages they cut; the others "
             "were read (the sweep's meta records it)")
    camera = _camera(Path(camera_path) if camera_path is not None else None, footage)
    base = track.utc_offset_s or 0.0
    tc = np.array([f.t_camera_s for f in frames]) - base  # camera times on the log's clock, before the offset
    if track.utc_offset_s is not None:
        lo_ok, hi_ok = track.start_s - max_offset_s, track.end_s + max_offset_s
        if time_offset_s is None and (tc[-1] < lo_ok or tc[0] > hi_ok):
            zone = " (the images have no OffsetTimeOriginal: their local time was taken as UTC)" if "taken as UTC" in footage.time_note else ""
            raise InputError(str(log_path), f"covers {utc_iso(track.start_s + base)} .. {utc_iso(track.end_s + base)}, "
                             f"but the frames were taken {utc_iso(tc[0] + base)} .. {utc_iso(tc[-1] + base)} by the camera's clock{zone}",
                             "give the log of this flight, or --time-offset when the camera clock is off by more than "
                             f"{max_offset_s:g} s")
        search = (-max_offset_s, max_offset_s)
    else:
        mid = 0.5 * (tc[0] + tc[-1])
        search = (mid - track.end_s, mid - track.start_s)
    t0 = time.perf_counter()
    if time_offset_s is not None:
        align = Alignment(float(time_offset_s), "given", None)
    else:
        if len(frames) < 10:
            raise InputError(str(frames_path), f"only {len(frames)} frames", "finding the camera clock offset needs a moving sequence; give --time-offset")
        imgs = (img for _f, img in footage.load(frames, reduce=4))
        a, b, s = image_motion(imgs, list(tc))
        align = find_offset(track, a, b, s, search=search)
        if align.correlation is None and align.pairs >= 5:  # the images registered; the log holds too little of them
            lags = np.arange(search[0], search[1] + 0.05, 0.05)
            most = max(int(((tc - L >= track.start_s) & (tc - L <= track.end_s)).sum()) for L in lags)
            raise InputError(str(log_path), f"covers {track.end_s - track.start_s:.1f} s of its clock, and at most {most} of the "
                             f"{len(frames)} frames fall inside it at any camera clock offset searched ({search[0]:+.1f} .. "
                             f"{search[1]:+.1f} s), too few to find the offset", "give the whole log of this flight, or "
                             "--time-offset S, the camera time minus the log time")
        if align.correlation is None:
            raise InputError(str(frames_path), f"only {align.pairs} pairs of consecutive frames could be registered, too "
                             "few to find the camera clock offset", "give --time-offset S (camera time minus log time)")
        if align.confidence is not None and align.confidence < MIN_CONFIDENCE:
            raise InputError(str(log_path), f"does not explain the footage's motion: the best camera clock offset, "
                             f"{align.camera_clock_offset_s:+.3f} s, has confidence {align.confidence:.2f} (correlation "
                             f"{align.correlation:.3f}; below {MIN_CONFIDENCE:g} another offset fits as well, or the motion "
                             "is not this log's)", "give the log of this flight, or --time-offset S when the offset is known")
    secs["align"] = time.perf_counter() - t0
    t_log = tc - align.camera_clock_offset_s
    inside = (t_log >= track.start_s) & (t_log <= track.end_s)
    if inside.sum() < max(1, 0.5 * len(frames)):
        raise InputError(str(log_path), f"covers {track.start_s:.2f} .. {track.end_s:.2f} s of its clock, but only "
                         f"{int(inside.sum())} of {len(frames)} frames fall inside it (camera clock offset "
                         f"{align.camera_clock_offset_s:+.3f} s)", "give the log of this flight, or --time-offset")
    kept = [f for f, k in zip(frames, inside) if k]
    states = frame_states(track, t_log[inside])
    meta = {
        "created_utc": utc_iso(time.time()),
        "source": {"kind": "import", "description": f"{footage.kind} {footage.source.name} + {track.kind} log {track.path.name}",
                   "footage": {"path": str(footage.source.resolve()), "kind": footage.kind, "frames": len(footage.frames),
                               "time_source": footage.time_note, "width": footage.width, "height": footage.height},
                   "flight_log": track.summary()},
        "rate_hz": rate_hz,
        "time_base": "flight_log_s",
        "camera": camera.to_json(),
        "cam_to_body": default_cam_to_body().to_json(),
        "survey": {"vessel": None, "hold": None, "wall": None, "frame_spacing_m": None, "reference_frame": None},
        "odometry_frame": "takeoff",
        "time_alignment": align.to_json(),
    }
    if survey_plan is not None:
        meta["survey_plan"] = survey_plan.to_json()
    t0 = time.perf_counter()
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.importing-", dir=out.parent))
    try:
        copy_jpeg = footage.kind == "images" and all(f.path.suffix.lower() in (".jpg", ".jpeg") for f in kept)
        writer = _ImportWriter(tmp, meta, image_format="jpg" if copy_jpeg else "png", overwrite=True, adaptive=False, queue_frames=16)
        frames_iter = ((f, f.path.read_bytes()) for f in kept) if copy_jpeg else footage.load(kept)
        try:
            for k, (f, img) in enumerate(frames_iter):
                st = states[k]
                utc = utc_iso(st["t_s"] + track.utc_offset_s) if track.utc_offset_s is not None else None
                rec = {"t_s": st["t_s"], "t_utc": utc, "t_camera_utc": utc_iso(f.t_camera_s), "source_frame": f.name,
                       "exposure_s": 0.0, "state": st}
                writer.wait_for_room()
                writer.submit(k, img, rec)
                if writer.error:
                    break
        finally:
            stats = writer.close({"stop_reason": "imported", "frames_outside_log": int((~inside).sum()),
                                  "time_alignment": align.to_json()})
        if writer.error:
            raise InputError(str(out), writer.error)
        if out.exists():
            out.rmdir()  # empty (checked above)
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    secs["write"] = time.perf_counter() - t0
    if (~inside).any():
        note(f"{int((~inside).sum())} frame(s) outside the log's time span were not imported")
    return ImportResult(out, len(footage.frames), len(frames), stats.written, int((~inside).sum()), align, track.kind,
                        {k: round(v, 3) for k, v in secs.items()})
