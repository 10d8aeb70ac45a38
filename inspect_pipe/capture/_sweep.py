"""The sweep directory (``inspect_pipe.sweep/1``): its writer and its reader.

    SWEEP/sweep.json     format, camera model, camera-to-body pose, survey, source (written first, atomically)
    SWEEP/frames.jsonl   one line per frame, appended and flushed after the frame's image is on disk
    SWEEP/images/NNNNNN.png|jpg   written to a temporary name, then renamed
    SWEEP/COMPLETE       written last: frame count, stop reason, drops, clock fit, sha256 of every file

Because an image is renamed into place before its line is appended, a sweep killed at any moment
lists no frame whose image is missing, and at most the frame being committed has an image on disk
without a line. The reader stops at a partial last line.
"""

from __future__ import annotations

import concurrent.futures as cf
import hashlib
import json
import math
import os
import queue
import re
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np

import inspect_pipe
from inspect_pipe.capture._exif import ImageMeta, embed
from inspect_pipe._files import atomic_write
from inspect_pipe.capture._geometry import SIM_CALIBRATION, CameraModel, Pose
from inspect_pipe.errors import InputError

__all__ = [
    "COMPLETE_NAME",
    "FORMAT",
    "FrameRecord",
    "FrameTruth",
    "Sweep",
    "SweepMeta",
    "SweepWriter",
    "WallTextureInfo",
    "WriterStats",
    "read_sweep",
]

FORMAT = "inspect_pipe.sweep/1"
COMPLETE_FORMAT = "inspect_pipe.sweep_complete/1"
COMPLETE_NAME = "COMPLETE"
_FORMAT_RE = re.compile(r"^inspect_pipe\.sweep/(\d+)$")
# Lossless PNG, chosen by measurement on noisy 1280x1024 camera frames: SUB filter + Huffman-only
# coding is 2.4x faster than zlib level 1 (36 vs 88 ms) and 7 % smaller; level 0 (stored) takes 5 ms.
PNG_FAST = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB,
            cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY]
PNG_STORE = [cv2.IMWRITE_PNG_COMPRESSION, 0, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE]


# =========================================================================== typed records


@dataclass(frozen=True)
class WallTextureInfo:
    """The simulated front wall's texture (ground truth for mosaics and reports)."""

    image: Path  # absolute
    m_per_px: float
    origin_uv: tuple[float, float]  # wall (u, v) m of the image's top-left corner; rows run down
    defects_mask: Path | None = None
    wall_width_m: float | None = None
    wall_height_m: float | None = None

    def to_json(self, sweep_dir: Path) -> dict:
        def both(p: Path | None) -> dict | None:
            if p is None:
                return None
            return {"path": str(Path(p).resolve()), "relative": os.path.relpath(Path(p).resolve(), sweep_dir.resolve())}

        return {
            "image": both(self.image),
            "m_per_px": self.m_per_px,
            "origin_uv": list(self.origin_uv),
            "defects_mask": both(self.defects_mask),
            "wall_width_m": self.wall_width_m,
            "wall_height_m": self.wall_height_m,
        }


@dataclass(frozen=True)
class SweepMeta:
    format: str
    camera: CameraModel  # K (3x3), dist, width, height
    cam_to_body: Pose  # p_body = R @ p_cam + t
    survey: dict[str, Any]  # vessel, hold, wall, frame_spacing_m, reference_frame (None when unknown)
    software_version: str
    source: dict[str, Any]  # kind, description, ...
    rate_hz: float | None
    image_format: str
    created_utc: str | None
    time_base: str  # what t_s counts: "host_monotonic_s" or "simulation_s"
    simulation: dict[str, Any] | None = None  # scenario name, hold dimensions (simulated sweeps)
    wall_texture: WallTextureInfo | None = None  # simulated sweeps: the texture of the wall surveyed
    raw: dict[str, Any] = field(default_factory=dict, repr=False)
    survey_plan: Any = None  # inspect_pipe.ship.SurveyPlan given to capture/import (--survey), or None
    # What frame positions (``position_m``) are in: "hold" (the simulator knows the hold) or
    # "takeoff" (a real autopilot's local frame turned to the take-off heading, origin at take-off;
    # the survey plan's ``takeoff`` ties it to the hold).
    odometry_frame: str = "hold"
    sim_wall: str | None = None  # the simulator's wall the camera faced (front/back/left/right)

    def hold_dims(self) -> tuple[float | None, float | None]:
        """(length_m, width_m) of the hold: the plan's, else the simulation's."""
        hold = (self.simulation or {}).get("hold") if isinstance(self.simulation, dict) else None
        L = _num(hold.get("length_m")) if isinstance(hold, dict) else None
        W = _num(hold.get("width_m")) if isinstance(hold, dict) else None
        if self.survey_plan is not None:
            L = self.survey_plan.hold.length_m or L
            W = self.survey_plan.hold.width_m or W
        if W is None and self.wall_texture is not None:
            W = self.wall_texture.wall_width_m
        if W is None and isinstance((self.survey or {}).get("wall_width_m"), (int, float)):
            W = float(self.survey["wall_width_m"])
        return L, W

    def wall_frame(self):
        """The surveyed wall's frame (``inspect_pipe.ship.WallFrame``): the plan's wall, else the
        simulated wall the camera faced, else the front wall. A dimension the frame needs but
        nobody gave is taken as 0 (u then counts from the centreline), which ``wall_frame_note`` says."""
        from inspect_pipe.ship import Wall, wall_frame

        wall = self.survey_plan.wall.name if self.survey_plan is not None else Wall.parse(self.sim_wall or "front")
        L, W = self.hold_dims()
        try:
            return wall_frame(wall, L, W)
        except ValueError:
            return wall_frame(wall, L or 0.0, W or 0.0)

    def wall_frame_note(self) -> str | None:
        from inspect_pipe.ship import Wall, wall_frame

        wall = self.survey_plan.wall.name if self.survey_plan is not None else Wall.parse(self.sim_wall or "front")
        try:
            wall_frame(wall, *self.hold_dims())
        except ValueError as err:
            return f"{err}: wall u counted from the hold's centreline / aft bulkhead instead (add it to the survey plan's hold)"
        return None

    def to_hold(self, position_m) -> np.ndarray:
        """(N, 3) frame positions -> hold coordinates (the plan's take-off tie for "takeoff")."""
        from inspect_pipe.ship import hold_from_takeoff

        p = np.asarray(position_m, float).reshape(-1, 3)
        return p.copy() if self.odometry_frame == "hold" else hold_from_takeoff(self.survey_plan, p)

    @property
    def K(self) -> np.ndarray:
        return self.camera.K

    @property
    def dist(self) -> np.ndarray:
        return self.camera.dist

    @property
    def width(self) -> int:
        return self.camera.width

    @property
    def height(self) -> int:
        return self.camera.height


@dataclass(frozen=True)
class FrameTruth:
    """Simulator ground truth at mid-exposure. Homographies map to *undistorted* frame pixels
    (``cv2.undistort(img, K, dist)`` the frame, or distort the mapped points with the camera's
    ``dist``)."""

    position_m: tuple[float, float, float]  # vehicle centre, world
    rpy_rad: tuple[float, float, float]  # vehicle roll, pitch, yaw (ZYX)
    velocity_m_s: tuple[float, float, float]
    R_world_cam: np.ndarray  # 3x3 camera-to-world rotation
    cam_center_m: np.ndarray  # (3,) camera centre, world
    H_wall_m_to_frame: np.ndarray  # 3x3: wall (u, v, 1) m -> frame pixel
    H_wall_px_to_frame: np.ndarray | None  # 3x3: texture pixel (col, row, 1) -> frame pixel
    motion_blur_px: float | None = None


@dataclass(frozen=True)
class FrameRecord:
    index: int
    image: str  # relative to the sweep
    image_path: Path  # absolute
    t_s: float  # mid-exposure, on the sweep's time base
    exposure_s: float
    t_host_s: float | None = None
    t_utc: str | None = None
    t_device_s: float | None = None
    frame_id: int | None = None
    gain: float | None = None
    # vehicle state at mid-exposure (None when no state feed)
    position_m: tuple[float, float, float] | None = None  # estimate, world frame
    dist_front_m: float | None = None
    height_m: float | None = None
    velocity_m_s: tuple[float, float, float] | None = None
    est_mode: int | None = None
    fsm: str | None = None
    inspection_mode: bool | None = None
    # simulated sweeps
    position_true_m: tuple[float, float, float] | None = None
    yaw_true_rad: float | None = None
    truth: FrameTruth | None = None
    raw: dict[str, Any] = field(default_factory=dict, repr=False)


@dataclass(frozen=True)
class Sweep:
    path: Path
    meta: SweepMeta
    frames: list[FrameRecord]
    complete: bool  # the COMPLETE marker is present
    summary: dict[str, Any] | None  # from COMPLETE: stop reason, drops, clock fit
    problems: tuple[InputError, ...] = ()  # what was skipped; the frames listed are all readable
    corrupt: dict[int, str] = field(default_factory=dict)  # position in ``frames`` -> why its image fails the check (read_sweep(verify=True))

    def __len__(self) -> int:
        return len(self.frames)

    def raise_first_problem(self) -> None:
        if self.problems:
            raise self.problems[0]

    def require_frames(self) -> None:
        """One-line :class:`InputError` for a sweep with no readable frame (nothing to mosaic)."""
        if not self.frames:
            why = f" ({self.problems[0]})" if self.problems else ""
            raise InputError(str(Path(self.path) / "frames.jsonl"), f"no readable frames{why}", "nothing to mosaic")


# =========================================================================== reading


def _vec(x, n: int) -> tuple[float, ...] | None:
    """A vector of ``n`` finite numbers, else None (a NaN in a state is no state, as :func:`_num` reads a scalar)."""
    if isinstance(x, list) and len(x) == n and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in x):
        return tuple(float(v) for v in x)
    return None


def _mat(x) -> np.ndarray | None:
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        return None
    return a if a.shape == (3, 3) and np.all(np.isfinite(a)) else None


def _num(x) -> float | None:
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) else None


def _resolve(sweep_dir: Path, entry) -> Path | None:
    if not isinstance(entry, dict):
        return None
    for cand in (entry.get("path"), entry.get("relative")):
        if isinstance(cand, str) and cand:
            p = Path(cand) if Path(cand).is_absolute() else (sweep_dir / cand)
            if p.exists():
                return p.resolve()
    cand = entry.get("path")
    return Path(cand) if isinstance(cand, str) and cand else None


def _meta(path: Path, doc: dict) -> SweepMeta:
    where = str(path / "sweep.json")
    fmt = doc.get("format")
    m = _FORMAT_RE.match(fmt) if isinstance(fmt, str) else None
    if m is None:
        raise InputError(where, f"format is {fmt!r}", f"expected {FORMAT!r}")
    if int(m.group(1)) != 1:
        raise InputError(where, f"unknown format version {fmt!r}", f"this inspect-pipe {inspect_pipe.__version__} reads {FORMAT!r}; upgrade it")
    from inspect_pipe.formats import SweepJson, validate

    validate(SweepJson, doc, where, "docs/sweep.md describes sweep.json")
    cam = doc["camera"]
    K, dist, w, h = np.asarray(cam["K"], float), cam.get("dist", []), cam["width"], cam["height"]
    calibration = cam.get("calibration") if isinstance(cam.get("calibration"), dict) else None
    if calibration is None and "calibration" not in cam and (doc.get("source") or {}).get("kind") == "sim":
        calibration = dict(SIM_CALIBRATION)  # written before sweeps recorded it: the simulated camera is exact
    camera = CameraModel(K, np.asarray(dist, float), w, h, str(cam.get("name", "camera")), calibration=calibration)
    ctb = doc.get("cam_to_body") or {}
    R, t = _mat(ctb.get("R")), _vec(ctb.get("t_m"), 3)
    pose = Pose(R if R is not None else np.eye(3), np.asarray(t if t is not None else (0.0, 0.0, 0.0)))
    sim = doc.get("simulation") if isinstance(doc.get("simulation"), dict) else None
    texture = None
    tex = (sim or {}).get("wall_texture") or (sim or {}).get("front_wall_texture")
    if isinstance(tex, dict):
        img = _resolve(path, tex.get("image"))
        origin = _vec(tex.get("origin_uv"), 2)
        mpp = _num(tex.get("m_per_px"))
        if img is not None and origin is not None and mpp:
            texture = WallTextureInfo(
                img, mpp, origin, _resolve(path, tex.get("defects_mask")), _num(tex.get("wall_width_m")), _num(tex.get("wall_height_m"))
            )
    survey = {"vessel": None, "hold": None, "wall": None, "frame_spacing_m": None, "reference_frame": None}
    if isinstance(doc.get("survey"), dict):
        survey.update(doc["survey"])
    plan = None
    if doc.get("survey_plan") is not None:
        from inspect_pipe.ship import parse_survey_plan

        plan = parse_survey_plan(doc["survey_plan"], where + " (survey_plan)")
    odo = doc.get("odometry_frame") or ("hold" if sim is not None else "takeoff")
    sim_wall = (sim or {}).get("wall", "front")
    return SweepMeta(
        format=fmt, camera=camera, cam_to_body=pose, survey=survey,
        software_version=str(doc.get("software_version", "")), source=doc.get("source") or {},
        rate_hz=_num(doc.get("rate_hz")), image_format=str(doc.get("image_format", "png")),
        created_utc=doc.get("created_utc"), time_base=str(doc.get("time_base", "host_monotonic_s")),
        simulation=sim, wall_texture=texture, raw=doc, survey_plan=plan, odometry_frame=odo, sim_wall=sim_wall,
    )


def _truth(d) -> FrameTruth | None:
    if not isinstance(d, dict):
        return None
    pos, rpy = _vec(d.get("position_m"), 3), _vec(d.get("rpy_rad"), 3)
    R, H = _mat(d.get("R_world_cam")), _mat(d.get("H_wall_m_to_frame"))
    c = _vec(d.get("cam_center_m"), 3)
    if pos is None or rpy is None or R is None or H is None or c is None:
        return None
    return FrameTruth(
        position_m=pos, rpy_rad=rpy, velocity_m_s=_vec(d.get("velocity_m_s"), 3) or (0.0, 0.0, 0.0),  # type: ignore[arg-type]
        R_world_cam=R, cam_center_m=np.asarray(c), H_wall_m_to_frame=H,
        H_wall_px_to_frame=_mat(d.get("H_wall_px_to_frame")), motion_blur_px=_num(d.get("motion_blur_px")),
    )


def _record(sweep_dir: Path, d: dict) -> FrameRecord | str:
    """A frame record, or why the line is not one (its schema: inspect_pipe.formats.FrameLine)."""
    from pydantic import ValidationError

    from inspect_pipe.formats import FrameLine, first_error

    try:
        FrameLine.model_validate(d)
    except ValidationError as err:
        return first_error(err)
    idx, img, t, exp = d["index"], d["image"], float(d["t_s"]), float(d["exposure_s"])
    s = d.get("state") if isinstance(d.get("state"), dict) else {}
    truth = _truth(d.get("truth"))
    return FrameRecord(
        index=idx, image=img, image_path=(sweep_dir / img).resolve(), t_s=t, exposure_s=exp,
        t_host_s=_num(d.get("t_host_s")), t_utc=d.get("t_utc") if isinstance(d.get("t_utc"), str) else None,
        t_device_s=_num(d.get("t_device_s")), frame_id=d.get("frame_id") if isinstance(d.get("frame_id"), int) else None,
        gain=_num(d.get("gain")),
        position_m=_vec(s.get("position_m"), 3), dist_front_m=_num(s.get("dist_front_m")), height_m=_num(s.get("height_m")),  # type: ignore[arg-type]
        velocity_m_s=_vec(s.get("velocity_m_s"), 3), est_mode=s.get("est_mode") if isinstance(s.get("est_mode"), int) else None,  # type: ignore[arg-type]
        fsm=s.get("fsm") if isinstance(s.get("fsm"), str) else None,
        inspection_mode=s.get("inspection_mode") if isinstance(s.get("inspection_mode"), bool) else None,
        position_true_m=truth.position_m if truth else None, yaw_true_rad=truth.rpy_rad[2] if truth else None,
        truth=truth, raw=d,
    )


def read_sweep(path: str | Path, *, strict: bool = False, verify: bool = False) -> Sweep:
    """Read a sweep directory.

    Raises :class:`InputError` when it is not a sweep at all (no ``sweep.json``, bad JSON, an
    unknown format version, no ``frames.jsonl``). Otherwise returns every whole, consistent frame;
    a partial last line (an interrupted capture), a bad line or a frame whose image is missing is
    skipped and described in ``Sweep.problems`` (``strict=True`` raises the first instead).

    ``complete`` is True only when the COMPLETE marker is there and agrees with the disk: the
    number of frames it lists is the number read (a sweep copied in part is not complete).
    ``verify=True`` also checks every file's sha256 against the marker: a frame whose image
    differs stays in ``frames`` and is named in ``corrupt`` with the reason (the mosaic lists it
    as unplaced); a changed ``frames.jsonl`` or ``sweep.json`` is a problem.
    """
    path = Path(path)
    if not path.is_dir():
        raise InputError(str(path), "not found" if not path.exists() else "not a directory", "give a sweep directory")
    meta_path = path / "sweep.json"
    if not meta_path.is_file():
        raise InputError(str(meta_path), "missing", "not a sweep directory (capture writes sweep.json first)")
    try:
        doc = json.loads(meta_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise InputError(str(meta_path), f"not valid JSON ({err.__class__.__name__})", "a sweep.json written by inspect-pipe") from None
    if not isinstance(doc, dict):
        raise InputError(str(meta_path), "not a JSON object")
    meta = _meta(path, doc)
    frames_path = path / "frames.jsonl"
    if not frames_path.is_file():
        raise InputError(str(frames_path), "missing", "every sweep has a frames.jsonl, even an empty one")
    raw = frames_path.read_bytes()
    problems: list[InputError] = []
    frames: list[FrameRecord] = []
    seen: set[int] = set()
    lines = raw.split(b"\n")
    tail = lines.pop()  # after the last newline: b"" unless the last line is partial
    if tail.strip():
        problems.append(InputError(str(frames_path), f"truncated at line {len(lines) + 1} (partial last line ignored)", "an interrupted capture; the frames before it are read"))
    for n, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            d = json.loads(line)
        except (json.JSONDecodeError, UnicodeDecodeError):
            problems.append(InputError(str(frames_path), f"line {n}: not valid JSON (skipped)"))
            continue
        rec = _record(path, d) if isinstance(d, dict) else "not a JSON object"
        if isinstance(rec, str):
            problems.append(InputError(str(frames_path), f"line {n}: {rec} (skipped)"))
            continue
        if rec.index in seen:
            problems.append(InputError(str(frames_path), f"line {n}: frame index {rec.index} repeated (skipped)"))
            continue
        try:
            ok = rec.image_path.stat().st_size > 0
        except OSError:
            ok = False
        if not ok:
            problems.append(InputError(str(rec.image_path), f"image of frame {rec.index} listed in frames.jsonl line {n} is missing or empty (frame skipped)"))
            continue
        seen.add(rec.index)
        frames.append(rec)
    if strict and problems:
        raise problems[0]
    complete_path = path / COMPLETE_NAME
    summary = None
    complete = complete_path.is_file()
    corrupt: dict[int, str] = {}
    c: dict = {}
    if complete:
        try:
            c = json.loads(complete_path.read_text())
            if not isinstance(c, dict):
                raise ValueError
            summary = c.get("summary") if isinstance(c.get("summary"), dict) else None
        except (json.JSONDecodeError, UnicodeDecodeError, ValueError):
            problems.append(InputError(str(complete_path), "not valid JSON (the sweep is read as incomplete)"))
            complete, c = False, {}
    listed = c.get("frames")
    if complete and isinstance(listed, int) and not isinstance(listed, bool) and listed != len(frames):
        problems.append(InputError(str(complete_path), f"lists {listed} frames but {len(frames)} are on disk (the sweep is read as incomplete)",
                                   "copy the whole sweep directory again, or use the frames there are"))
        complete = False
    if verify:
        digests = c.get("sha256") if isinstance(c.get("sha256"), dict) else None
        if digests is None:
            problems.append(InputError(str(complete_path), "no checksums to verify against" if complete_path.is_file() else "missing: no checksums to verify against",
                                       "an interrupted capture has no COMPLETE marker; run without --verify"))
        else:
            for name in ("frames.jsonl", "sweep.json"):
                if name in digests and _sha256(path / name) != digests[name]:
                    problems.append(InputError(str(path / name), "sha256 differs from the COMPLETE marker's (changed since capture)"))
                    complete = False
            for pos, rec in enumerate(frames):
                want = digests.get(rec.image)
                if want is None:
                    corrupt[pos] = "no checksum in COMPLETE (frame not written by the capture)"
                elif _sha256(rec.image_path) != want:
                    corrupt[pos] = "sha256 differs from the COMPLETE marker's (the image changed since capture)"
            if corrupt:
                complete = False
    return Sweep(path=path.resolve(), meta=meta, frames=frames, complete=complete, summary=summary, problems=tuple(problems), corrupt=corrupt)


def _sha256(p: Path) -> str | None:
    h = hashlib.sha256()
    try:
        with p.open("rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    except OSError:
        return None
    return h.hexdigest()


def verify_checksums(path: str | Path) -> list[str]:
    """Files whose sha256 differs from the COMPLETE marker's (empty list: all match)."""
    path = Path(path)
    doc = json.loads((path / COMPLETE_NAME).read_text())
    bad = []
    for rel, digest in doc.get("sha256", {}).items():
        p = path / rel
        if not p.is_file() or hashlib.sha256(p.read_bytes()).hexdigest() != digest:
            bad.append(rel)
    return bad


# =========================================================================== writing


@dataclass
class WriterStats:
    submitted: int = 0
    written: int = 0
    dropped_backpressure: int = 0
    bytes_written: int = 0
    encode_s: float = 0.0
    commit_s: float = 0.0
    max_queue: int = 0
    stored_uncompressed: int = 0  # PNGs written without compression because the queue was over half full


def _lower_priority(niceness: int = 5) -> None:
    """Writer threads yield the CPU to the grabbing thread (Linux: per-thread nice). Best effort."""
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), min(19, os.getpriority(os.PRIO_PROCESS, 0) + niceness))
    except (AttributeError, OSError):
        pass


class SweepWriter:
    """Writes a sweep without ever blocking the grabbing thread.

    ``submit`` hands a frame to a bounded pipeline (``encoders`` threads encode PNG/JPEG in
    parallel; one committer thread renames each image into place, then appends and flushes its
    line, in frame order). When ``queue_frames`` frames are already waiting, ``submit`` returns
    False: the frame is dropped and counted. A write error (disk full) stops the writer; ``error``
    then holds the one-line reason and further frames are refused.
    """

    def __init__(
        self,
        path: str | Path,
        meta: dict,
        *,
        image_format: str = "png",
        png_compression: int | None = None,
        jpeg_quality: int = 95,
        queue_frames: int = 32,
        encoders: int = 2,
        fsync_every_s: float = 1.0,
        overwrite: bool = False,
        adaptive: bool = True,
        write_bytes: Callable[[Path, bytes], None] | None = None,
    ) -> None:
        if image_format not in ("png", "jpg"):
            raise InputError(str(path), f"image format {image_format!r} not supported", "png (lossless) or jpg")
        self.path = Path(path)
        if self.path.exists() and not self.path.is_dir():
            raise InputError(str(self.path), "exists and is not a directory", "give a new sweep directory")
        if self.path.is_dir() and any(self.path.iterdir()) and not overwrite:
            raise InputError(str(self.path), "exists and is not empty", "give a new sweep directory")
        self.images = self.path / "images"
        try:
            self.images.mkdir(parents=True, exist_ok=True)
            for p in self.images.iterdir():  # overwrite: start clean
                p.unlink()
            for name in ("frames.jsonl", COMPLETE_NAME):
                (self.path / name).unlink(missing_ok=True)
            doc = {"format": FORMAT, "software_version": inspect_pipe.__version__, "image_format": image_format, **meta}
            doc["format"] = FORMAT
            atomic_write(self.path / "sweep.json", (json.dumps(doc, indent=1) + "\n").encode(), fsync=True)
            self._fh = open(self.path / "frames.jsonl", "ab", buffering=0)
        except OSError as err:
            raise InputError(str(self.path), f"cannot create the sweep ({err.strerror})", "choose a writable directory") from None
        self.image_format = image_format
        if image_format == "jpg":
            self._params = [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)]
        elif png_compression is None:
            self._params = PNG_FAST
        else:
            self._params = [cv2.IMWRITE_PNG_COMPRESSION, int(png_compression)]
        self._overload_params = PNG_STORE if (image_format == "png" and adaptive) else self._params
        self.queue_frames = int(queue_frames)
        self.fsync_every_s = fsync_every_s
        self._write_bytes = write_bytes or (lambda p, b: atomic_write(p, b, fsync=False))
        self.stats = WriterStats()
        self.error: str | None = None
        self.sha256: dict[str, str] = {}
        self._pool = cf.ThreadPoolExecutor(max_workers=max(1, encoders), thread_name_prefix="sweep-encode", initializer=_lower_priority)
        self._pending: queue.Queue = queue.Queue()
        self._lock = threading.Lock()
        self._queued = 0
        self._last_fsync = time.monotonic()
        self._closed = False
        self._committer = threading.Thread(target=self._commit_loop, name="sweep-commit", daemon=True)
        self._committer.start()

    # ------------------------------------------------------------------ producer side
    def submit(self, index: int, image: np.ndarray, record: dict, image_meta: ImageMeta | None = None) -> bool:
        """Queue frame ``index``; False when it was dropped (queue full or writer failed)."""
        self.stats.submitted += 1
        with self._lock:
            full = self._queued >= self.queue_frames
            if not full and self.error is None and not self._closed:
                self._queued += 1
                self.stats.max_queue = max(self.stats.max_queue, self._queued)
            else:
                self.stats.dropped_backpressure += 1
                return False
        name = f"images/{index:06d}.{self.image_format}"
        fut = self._pool.submit(self._encode, image, image_meta)
        self._pending.put((index, name, fut, record))
        return True

    def wait_for_room(self, timeout_s: float = 60.0) -> bool:
        """Block until a frame would be accepted (for simulated time, which can wait for the disk)."""
        t_end = time.monotonic() + timeout_s
        while self._queued >= self.queue_frames and self.error is None:
            if time.monotonic() > t_end:
                return False
            time.sleep(0.001)
        return True

    @property
    def queued(self) -> int:
        return self._queued

    def _encode(self, image: np.ndarray, image_meta: ImageMeta | None) -> bytes:
        t0 = time.perf_counter()
        params = self._params
        if params is not self._overload_params and self._queued > self.queue_frames // 2:  # falling behind: store (still lossless) rather than drop
            params = self._overload_params
            self.stats.stored_uncompressed += 1
        ok, buf = cv2.imencode("." + self.image_format, image, params)
        if not ok:
            raise OSError("image encoding failed")
        data = buf.tobytes()
        if image_meta is not None:
            data = embed(data, image_meta)
        self.stats.encode_s += time.perf_counter() - t0
        return data

    # ------------------------------------------------------------------ committer
    def _commit_loop(self) -> None:
        _lower_priority()
        while True:
            item = self._pending.get()
            if item is None:
                return
            index, name, fut, record = item
            try:
                if self.error is None:
                    data = fut.result()
                    t0 = time.perf_counter()
                    self._write_bytes(self.path / name, data)
                    line = json.dumps({"index": index, "image": name, "bytes": len(data), **record}, separators=(",", ":"))
                    self._fh.write((line + "\n").encode())
                    now = time.monotonic()
                    if self.fsync_every_s is not None and now - self._last_fsync >= self.fsync_every_s:
                        os.fsync(self._fh.fileno())
                        self._last_fsync = now
                    self.sha256[name] = hashlib.sha256(data).hexdigest()
                    self.stats.written += 1
                    self.stats.bytes_written += len(data)
                    self.stats.commit_s += time.perf_counter() - t0
            except OSError as err:
                import errno as _errno

                why = "disk full" if err.errno in (_errno.ENOSPC, _errno.EDQUOT) else (err.strerror or str(err))
                self.error = f"{self.path / name}: cannot write ({why})"
            except Exception as err:  # encoding failure: report, never kill the thread silently
                self.error = f"{self.path / name}: {err}"
            finally:
                with self._lock:
                    self._queued -= 1

    # ------------------------------------------------------------------ end
    def close(self, summary: dict | None = None, *, complete: bool = True) -> WriterStats:
        """Wait for queued frames, then write COMPLETE (unless ``complete`` is False)."""
        if self._closed:
            return self.stats
        self._closed = True
        self._pending.put(None)
        self._committer.join()
        self._pool.shutdown(wait=True)
        try:
            os.fsync(self._fh.fileno())
        except OSError:
            pass
        self._fh.close()
        if complete:
            try:
                frames_sha = hashlib.sha256((self.path / "frames.jsonl").read_bytes()).hexdigest()
                doc = {
                    "format": COMPLETE_FORMAT,
                    "frames": self.stats.written,
                    "summary": {**(summary or {}), "written": self.stats.written, "dropped_backpressure": self.stats.dropped_backpressure,
                                "stored_uncompressed": self.stats.stored_uncompressed, "bytes": self.stats.bytes_written, "writer_error": self.error},
                    "sha256": {"frames.jsonl": frames_sha, "sweep.json": hashlib.sha256((self.path / "sweep.json").read_bytes()).hexdigest(), **self.sha256},
                }
                atomic_write(self.path / COMPLETE_NAME, (json.dumps(doc, indent=1) + "\n").encode(), fsync=True)
            except OSError as err:
                self.error = self.error or f"{self.path / COMPLETE_NAME}: cannot write ({err.strerror})"
        return self.stats
