"""Fuzz targets: every file the product reads, and the MAVLink packets of the live link, driven by
hypothesis. Shared by the test suite (tests/reliability/test_fuzz.py: a few hundred cases) and
the bench (bench/bench_fuzz.py: 10,000).

Each target has a seed input (a valid file of its format) and a hypothesis strategy of inputs
derived from it: the bytes truncated, bit-flipped, overwritten or spliced; for the structured
formats also the parsed document with one value replaced by another JSON value (a wrong type,
a huge or non-finite number, a missing key). ``outcome`` runs the product's reader on one input
under a per-case timeout and classifies what happened:

    ok      a result (a sweep's skipped lines each reported in one line naming the file)
    error   one-line InputError that names the file (or the device/link)
    crash   anything else: another exception (a traceback for the user), a multi-line error, an
            InputError that names neither the file nor the link, or lines printed by the reader
    hang    the case ran past its timeout
"""

from __future__ import annotations

import contextlib
import copy
import io
import json
import math
import os
import signal
import struct
import tempfile
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import yaml
from hypothesis import HealthCheck, Phase, given, seed as hseed, settings, strategies as st

from inspect_pipe.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
CASE_TIMEOUT_S = 10.0


class Hang(Exception):
    pass


@dataclass
class Outcome:
    kind: str  # ok | error | crash | hang
    detail: str = ""


def outcome(fn: Callable[[], Any], names: tuple[str, ...], timeout_s: float = CASE_TIMEOUT_S) -> Outcome:
    """Run ``fn`` under a timeout (SIGALRM; main thread): ok, a one-line error naming one of
    ``names``, or a crash/hang with its reason."""

    def alarm(signum, frame):
        raise Hang()

    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout_s)
    chatter = _Chatter()
    try:
        with chatter:
            fn()
        if chatter.text:  # a reader printing its own lines is not one line either
            return Outcome("crash", f"printed {chatter.text[:200]!r}")
        return Outcome("ok")
    except Hang:
        return Outcome("hang", f"ran past {timeout_s:g} s")
    except InputError as err:
        msg = str(err)
        if "\n" in msg or not msg.strip():
            return Outcome("crash", f"multi-line or empty error: {msg!r}")
        if not any(n in msg for n in names):
            return Outcome("crash", f"error names neither of {names}: {msg!r}")
        if chatter.text:
            return Outcome("crash", f"printed {chatter.text[:200]!r} before its error")
        return Outcome("error", msg)
    except Exception as err:  # noqa: BLE001 - that is the finding
        tb = traceback.extract_tb(err.__traceback__)
        at = f"{Path(tb[-1].filename).name}:{tb[-1].lineno}" if tb else "?"
        return Outcome("crash", f"{err.__class__.__name__} at {at}: {str(err)[:200]}")
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


class _Chatter:
    """What a case prints, Python's and C libraries' (file descriptors 1 and 2 to a file)."""

    def __enter__(self):
        import sys

        for s in (sys.stdout, sys.stderr):
            s.flush()
        self.file = tempfile.TemporaryFile()
        self.saved = [(fd, os.dup(fd)) for fd in (1, 2)]
        for fd in (1, 2):
            os.dup2(self.file.fileno(), fd)
        self.py = io.StringIO()
        self.redirects = [contextlib.redirect_stdout(self.py), contextlib.redirect_stderr(self.py)]
        for r in self.redirects:
            r.__enter__()
        self.text = ""
        return self

    def __exit__(self, *exc):
        import sys

        for r in reversed(self.redirects):
            r.__exit__(None, None, None)
        for s in (sys.stdout, sys.stderr):
            s.flush()
        for fd, saved in self.saved:
            os.dup2(saved, fd)
            os.close(saved)
        self.file.seek(0)
        self.text = (self.py.getvalue() + self.file.read().decode("utf-8", "replace")).strip()
        self.file.close()
        return False


# =============================================================================== mutations


def _json_values(depth: int = 2) -> st.SearchStrategy:
    leaf = st.one_of(
        st.none(), st.booleans(), st.integers(min_value=-2**70, max_value=2**70),
        st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
        st.sampled_from([0, -1, 1e308, -0.0, "", "nan", "../../etc/passwd", "/abs/path.png", "images/000000.png"]),
    )
    if depth <= 0:
        return leaf
    inner = _json_values(depth - 1)
    return st.one_of(leaf, st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=6), inner, max_size=3),
                     st.lists(st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=0, max_size=4), max_size=4))


def _paths(doc: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:6]):
            out += _paths(v, prefix + (i,))
    return out


def _set(doc: Any, path: tuple, value: Any, delete: bool) -> Any:
    if not path:
        return value
    doc = copy.deepcopy(doc)
    node = doc
    for p in path[:-1]:
        node = node[p]
    if delete:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return doc


@st.composite
def doc_mutation(draw, doc: Any) -> Any:
    """``doc`` with one value replaced (or a key deleted, or a key added)."""
    paths = _paths(doc)
    path = draw(st.sampled_from(paths))
    how = draw(st.sampled_from(["replace", "replace", "delete", "add"]))
    if how == "delete" and path:
        return _set(doc, path, None, True)
    if how == "add":
        target = path if path and isinstance(_get(doc, path), dict) else ()
        if isinstance(_get(doc, target), dict):
            return _set(doc, target + (draw(st.text(min_size=1, max_size=8)),), draw(_json_values(1)), False)
    return _set(doc, path, draw(_json_values()), False)


def _get(doc, path):
    for p in path:
        doc = doc[p]
    return doc


@st.composite
def byte_mutation(draw, data: bytes, focus: int | None = None) -> bytes:
    """``data`` truncated, bit-flipped, overwritten, spliced or emptied. ``focus``: mutate mostly
    in the first ``focus`` bytes (a file's header)."""
    n = len(data)
    hi = min(n, focus) if focus else n
    how = draw(st.sampled_from(["truncate", "flip", "flip", "overwrite", "insert", "delete", "empty", "random"]))
    b = bytearray(data)
    if how == "truncate":
        return bytes(b[: draw(st.integers(0, max(0, n - 1)))])
    if how == "flip":
        for _ in range(draw(st.integers(1, 8))):
            i = draw(st.integers(0, max(0, hi - 1)))
            b[i] ^= 1 << draw(st.integers(0, 7))
        return bytes(b)
    if how == "overwrite":
        i = draw(st.integers(0, max(0, hi - 1)))
        chunk = draw(st.binary(min_size=1, max_size=16))
        b[i:i + len(chunk)] = chunk
        return bytes(b)
    if how == "insert":
        i = draw(st.integers(0, hi))
        return bytes(b[:i]) + draw(st.binary(min_size=1, max_size=32)) + bytes(b[i:])
    if how == "delete":
        i = draw(st.integers(0, max(0, hi - 1)))
        return bytes(b[:i]) + bytes(b[i + draw(st.integers(1, 64)):])
    if how == "empty":
        return b""
    return draw(st.binary(max_size=256))


def text_or_doc(seed_doc: Any, dump: Callable[[Any], bytes]) -> st.SearchStrategy:
    """Bytes of a structured file: its document mutated, or its text mutated."""
    return st.one_of(doc_mutation(seed_doc).map(_safe(dump)), byte_mutation(dump(seed_doc)))


def _safe(dump):
    def f(doc):
        try:
            return dump(doc)
        except (ValueError, TypeError, OverflowError, yaml.YAMLError):
            return json.dumps(str(doc)).encode()
    return f


def dump_json(doc) -> bytes:
    return json.dumps(doc).encode()  # NaN/Infinity as Python writes them: a reader must cope


def dump_yaml(doc) -> bytes:
    return yaml.safe_dump(doc, sort_keys=False).encode()


# =============================================================================== targets


@dataclass
class Target:
    name: str
    strategy: Callable[[], st.SearchStrategy]
    run: Callable[[Any, Path], Any]  # (input, scratch dir) -> result; raises InputError
    names: Callable[[Path], tuple[str, ...]] = lambda d: (str(d),)
    notes: str = ""
    setup: Callable[[Path], None] = field(default=lambda d: None)


K = [[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]]
SWEEP_DOC = {
    "format": "inspect_pipe.sweep/1",
    "camera": {"K": K, "dist": [0.01, -0.02, 0.0, 0.0, 0.0], "width": 320, "height": 240, "name": "cam",
               "calibration": {"source": "simulator", "sha256": None, "rms_px": 0.0}},
    "cam_to_body": {"R": [[0, 0, 1], [-1, 0, 0], [0, -1, 0]], "t_m": [0.1, 0.0, 0.0]},
    "survey": {"vessel": "MV Test", "hold": "No. 1", "wall": "front", "frame_spacing_m": 0.8, "reference_frame": 112},
    "software_version": "0.1.0", "source": {"kind": "sim", "description": "fuzz"}, "rate_hz": 10.0,
    "image_format": "png", "created_utc": "2026-11-25T00:00:00Z", "time_base": "simulation_s", "odometry_frame": "hold",
    "simulation": {"scenario": "s", "hold": {"length_m": 12, "width_m": 10, "height_m": 16}, "wall": "front",
                   "wall_texture": {"image": {"path": "/nonexistent/wall.png", "relative": "wall.png"}, "m_per_px": 0.004,
                                    "origin_uv": [3.8, 2.0], "wall_width_m": 10.0}},
}
FRAME = {"index": 0, "image": "images/000000.png", "t_s": 0.0, "exposure_s": 0.002, "t_host_s": 1.0, "frame_id": 1,
         "state": {"position_m": [10.0, 0.0, 1.0], "dist_front_m": 2.0, "height_m": 1.0, "velocity_m_s": [0, 0, 0],
                   "est_mode": 0, "fsm": "inspection", "inspection_mode": True},
         "truth": {"position_m": [10.0, 0.0, 1.0], "rpy_rad": [0, 0, 0], "R_world_cam": np.eye(3).tolist(),
                   "cam_center_m": [10.0, 0.0, 1.0], "H_wall_m_to_frame": np.eye(3).tolist()}}


def _frames_bytes(n: int = 3) -> bytes:
    return b"".join(json.dumps(dict(FRAME, index=i, image=f"images/{i:06d}.png", t_s=0.1 * i)).encode() + b"\n" for i in range(n))


def _write_sweep(d: Path, meta: bytes, frames: bytes) -> Path:
    s = d / "sweep"
    (s / "images").mkdir(parents=True, exist_ok=True)
    for i in range(3):
        p = s / "images" / f"{i:06d}.png"
        if not p.exists():
            p.write_bytes(b"\x89PNG fuzz")
    (s / "sweep.json").write_bytes(meta)
    (s / "frames.jsonl").write_bytes(frames)
    return s


def _read_sweep_fully(s: Path):
    from inspect_pipe.capture import read_sweep

    sw = read_sweep(s)
    for p in sw.problems:  # skipped lines are reported, each in one line naming its file
        if "\n" in str(p) or not str(p).startswith(str(s)):
            raise AssertionError(f"sweep problem not one line naming its file: {str(p)!r}")
    sw.meta.hold_dims()
    sw.meta.wall_frame()
    sw.meta.wall_frame_note()
    for f in sw.frames:
        sw.meta.to_hold(f.position_m or (0.0, 0.0, 0.0))
    return sw


def run_sweep_json(data: bytes, d: Path):
    return _read_sweep_fully(_write_sweep(d, data, _frames_bytes()))


def run_frames(data: bytes, d: Path):
    return _read_sweep_fully(_write_sweep(d, dump_json(SWEEP_DOC), data))


def plan_doc() -> dict:
    from inspect_pipe.pipeline._demo import DEMO_PLAN

    return dict(copy.deepcopy(DEMO_PLAN), takeoff={"position_m": [10.5, 0.5, 0.0], "heading_deg": 0.0},
                control_points=[{"image": "images/000000.png", "pixel": [10.0, 20.0], "wall_m": [1.0, 2.0]}])


def run_plan(data: bytes, d: Path):
    from inspect_pipe.ship import load_survey_plan

    p = d / "plan.yaml"
    p.write_bytes(data)
    plan = load_survey_plan(p)
    plan.warnings
    plan.to_json()
    return plan


SCENARIO_DOC = {
    "format": "inspect_pipe.scenario/1", "name": "fuzz", "duration_s": 8.0, "seed": 3,
    "world": {"hold": {"length_m": 12, "width_m": 10, "height_m": 16}},
    "vehicle": {"start": {"position": [10.5, 0.0, 0], "yaw": 0}},
    "camera": {"fps": 10, "width": 320, "height": 240, "hfov_deg": 60},
    "operator": [{"t": 0.5, "button": "takeoff"}, {"t": 4.0, "stick": {"vx": 0, "vy": -0.2, "vz": 0, "yaw_rate": 0}}],
}


def run_scenario(data: bytes, d: Path):
    from inspect_pipe.flight import load_scenario

    p = d / "scenario.yaml"
    p.write_bytes(data)
    return load_scenario(p)


MOSAIC_DOC = {
    "format": "inspect_pipe.mosaic/1", "mosaic": "mosaic.png",
    "frames": [{"index": i, "file": f"{i:06d}.png", "H": [[1, 0, 40.0 * i], [0, 1, 0], [0, 0, 1]], "group": 0, "image": "mosaic.png",
                "model": "pose"} for i in range(3)],
    "unplaced": [], "groups": [{"id": 0, "image": "mosaic.png", "size_wh": [400, 240], "n_frames": 3}], "frame_size_wh": [320, 240],
    "wall_from_mosaic": [[0.002, 0, 3.0], [0, -0.002, 6.0], [0, 0, 1]], "m_per_px": 0.002, "wall_fit": {"rms_m": 0.01, "max_m": 0.02},
}


def run_mosaic(data: bytes, d: Path):
    from inspect_pipe.pipeline._store import RunStore
    from inspect_pipe.report._geo import WallMap
    from inspect_pipe.report._report import frame_views

    store = RunStore(d / "run")
    store.mosaic_dir.mkdir(parents=True, exist_ok=True)
    (store.mosaic_dir / "mosaic.json").write_bytes(data)
    doc = store.load_mosaic_json()
    where = str(store.mosaic_dir / "mosaic.json")
    views = frame_views(doc, where)
    wall = WallMap.from_mosaic_json(doc, where, m_per_px_override=None if doc.get("wall_from_mosaic") is not None else 0.002,
                                    mosaic_hw=(240, 400))
    wall.to_wall(np.array([[0.0, 0.0], [10.0, 10.0]]))
    return views


DETECT_DOC = {
    "format": "inspect_pipe.defects/1", "model": {"engine": "saliency", "file": "defects_v1.npz"}, "kinds": ["corrosion", "crack"],
    "images": [{"image": "mosaic", "width": 400, "height": 240, "prob": "mosaic.prob.png", "mask": "mosaic.mask.png"}],
    "regions": [{"id": 1, "image": "mosaic", "class": "corrosion", "polygon_px": [[0, 0], [10, 0], [10, 10]], "area_px": 50,
                 "confidence": 0.7, "bbox_xywh": [0, 0, 10, 10]}],
    "errors": [], "keyframes": [0, 2], "keyframe_spacing": 2,
}


def run_detections(data: bytes, d: Path):
    from inspect_pipe.pipeline._store import RunStore

    store = RunStore(d / "run")
    store.detect_dir.mkdir(parents=True, exist_ok=True)
    (store.detect_dir / "defects.json").write_bytes(data)
    det = store.load_detections()
    [k for k in det["kinds"] if isinstance(k, str)]
    list(det.get("keyframes") or [])
    return det


def register_doc() -> dict:
    return {"format": "inspect_pipe.defect_register/1", "statuses": ["suggested", "confirmed", "rejected"], "defects": [
        {"id": "D001", "class": "corrosion", "status": "confirmed", "note": "pitting", "polygon_wall_m": [[1, 1], [1.1, 1], [1.1, 1.1]],
         "centroid_wall_m": [1.05, 1.05], "bbox_wall_m": [1, 1, 1.1, 1.1], "area_m2": 0.005, "length_m": None, "confidence": 0.8,
         "frames": [0, 1], "keyframes_detected": [0], "keyframes_seen": [0, 2], "frame_range": "112-113",
         "height_above_tank_top_m": 1.2, "polygon_mosaic_px": [[0, 0], [10, 0], [10, 10]], "bbox_mosaic_xywh": [0, 0, 10, 10],
         "area_px": 50, "redetected": True, "crop": "assets/D001.jpg", "context": None, "crop_frame": 1, "location": None,
         "detected_class": None, "severity": {"state": "poor", "fractions": {"fair": 0.2, "poor": 0.8, "severe": 0.0}}},
    ]}


def run_register(data: bytes, d: Path):
    from inspect_pipe.report import read_register

    p = d / "defects.json"
    p.write_bytes(data)
    return read_register(p)


CAMERA_OPENCV = b"""%YAML:1.0
---
camera_name: fuzzcam
image_width: 640
image_height: 480
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 519.0, 0., 315.5, 0., 519.2, 249.6, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -0.29, 0.10, 0.001, -0.0002, 0.0 ]
avg_reprojection_error: 0.144
"""
CAMERA_ROS = {
    "image_width": 640, "image_height": 480, "camera_name": "narrow_stereo",
    "camera_matrix": {"rows": 3, "cols": 3, "data": [612.5, 0, 321.2, 0, 611.9, 239.4, 0, 0, 1]},
    "distortion_model": "plumb_bob",
    "distortion_coefficients": {"rows": 1, "cols": 5, "data": [-0.41, 0.19, 0.001, -0.002, 0]},
}


def run_camera(data: bytes, d: Path):
    from inspect_pipe.capture._calibration import load_camera

    p = d / "camera.yaml"
    p.write_bytes(data)
    return load_camera(p)


MODELS = ROOT / "inspect_pipe" / "saliency_defects" / "models"


def _model_runner(engine: str, name: str, suffix: str):
    def run(data: bytes, d: Path):
        from inspect_pipe.saliency_defects import load_engine

        p = d / f"model{suffix}"
        p.write_bytes(data)
        return load_engine(engine, p)
    return run


def run_log(suffix: str):
    def run(data: bytes, d: Path):
        from inspect_pipe.importer._logs import read_flight_log

        p = d / f"flight{suffix}"
        p.write_bytes(data)
        return read_flight_log(p)
    return run


_ULOG_SEED: bytes | None = None


def ulog_seed() -> bytes:
    """The head of the shared PX4 sample log (tests/fixtures/import): its header, definitions and
    the first data messages."""
    global _ULOG_SEED
    if _ULOG_SEED is None:
        _ULOG_SEED = (ROOT / "tests" / "fixtures" / "import" / "sample_appended_multiple.ulg").read_bytes()[:100000]
    return _ULOG_SEED


def tlog_seed(seconds: float = 2.0) -> bytes:
    """A small .tlog as a ground station writes it: each packed message after its 8-byte UTC."""
    from pymavlink.dialects.v20 import common as C

    mav = C.MAVLink(io.BytesIO(), srcSystem=1, srcComponent=1)
    out = bytearray()
    t0 = 1_760_000_000.0
    for k in range(int(seconds * 10)):
        t = k * 0.1
        msgs = [C.MAVLink_attitude_message(int(t * 1e3), 0.01, -0.02, 0.1 * t, 0, 0, 0),
                C.MAVLink_local_position_ned_message(int(t * 1e3), 0.1 * t, 0.0, -1.0, 0.1, 0, 0),
                C.MAVLink_distance_sensor_message(int(t * 1e3), 10, 600, 200, 0, 1, 0, 0)]
        if k % 10 == 0:
            msgs += [C.MAVLink_heartbeat_message(2, 12, 128, 0, 4, 3), C.MAVLink_system_time_message(int((t0 + t) * 1e6), int(t * 1e3)),
                     C.MAVLink_extended_sys_state_message(0, 2)]
        for m in msgs:
            out += struct.pack(">Q", int((t0 + t) * 1e6)) + m.pack(mav)
    return bytes(out)


# -------------------------------------------------------------------------- MAVLink live link

_LINK = None


def _link():
    """One MavlinkLink and one state tracker (not connected: their handlers are driven here)."""
    global _LINK
    if _LINK is None:
        from inspect_pipe.capture._vehicle_feed import AutopilotStateTracker, MavlinkStateFeed
        from inspect_pipe.flight.mavlink_vehicle import MavlinkLink

        link = MavlinkLink("udp:127.0.0.1:0")
        _LINK = (link, AutopilotStateTracker(mode_names=MavlinkStateFeed._mode_name))
    return _LINK


# what each receive loop catches and counts as a bad packet (anything else would end the loop)
LINK_COUNTED = (ValueError, TypeError, OverflowError)
FEED_COUNTED = (ValueError, TypeError, OverflowError, AttributeError)


def feed_bytes(data: bytes) -> int:
    """``data`` as one datagram from the vehicle through the endpoint's parser into both receive
    handlers, as their loops call them. Returns the messages handled."""
    link, tracker = _link()
    out: list = []
    link.ep._parse(data, ("127.0.0.1", 14550), out)
    for m in out:
        try:
            link._handle(m, 100.0)
        except LINK_COUNTED:
            link.ep.stats.bad_packets += 1
        try:
            tracker.on_message(m, 100.0)
        except FEED_COUNTED:
            pass
    tracker.state_at(100.0)
    link.measurements()
    link.status()
    return len(out)


_MAV_TYPES = ["HEARTBEAT", "EXTENDED_SYS_STATE", "TIMESYNC", "LOCAL_POSITION_NED", "ATTITUDE", "DISTANCE_SENSOR", "SYSTEM_TIME",
              "COMMAND_ACK", "OPTICAL_FLOW_RAD", "HIGHRES_IMU", "SCALED_IMU", "BATTERY_STATUS"]
_INT_RANGES = {"int8_t": (-2**7, 2**7 - 1), "uint8_t": (0, 2**8 - 1), "int16_t": (-2**15, 2**15 - 1), "uint16_t": (0, 2**16 - 1),
               "int32_t": (-2**31, 2**31 - 1), "uint32_t": (0, 2**32 - 1), "int64_t": (-2**63, 2**63 - 1), "uint64_t": (0, 2**64 - 1)}


def _field_value(ftype: str, n: int) -> st.SearchStrategy:
    base = ftype.split("[")[0]
    if base in ("float", "double"):
        one = st.one_of(st.floats(width=32 if base == "float" else 64, allow_nan=True, allow_infinity=True),
                        st.sampled_from([0.0, -1.0, 1e30, float("nan"), float("inf")]))
    elif base == "char":
        return st.binary(max_size=n or 1).map(lambda b: b.decode("latin-1"))
    else:
        lo, hi = _INT_RANGES[base]
        one = st.one_of(st.integers(lo, hi), st.sampled_from([lo, hi, 0]))
    return st.lists(one, min_size=n, max_size=n) if n else one


@st.composite
def mavlink_message(draw) -> bytes:
    """A well-formed MAVLink 2 frame of a message the link reads, from the vehicle's system id,
    with arbitrary (nonsense) field values."""
    from pymavlink.dialects.v20 import common as C

    kind = draw(st.sampled_from(_MAV_TYPES))
    cls = C.mavlink_map[getattr(C, f"MAVLINK_MSG_ID_{kind}")]
    alen = dict(zip(cls.ordered_fieldnames, cls.array_lengths))
    vals = [draw(_field_value(t, alen.get(f, 0))) for f, t in zip(cls.fieldnames, cls.fieldtypes)]
    msg = cls(*vals)
    mav = C.MAVLink(io.BytesIO(), srcSystem=1, srcComponent=draw(st.sampled_from([1, 158, 200])))
    try:
        return bytes(msg.pack(mav))
    except (struct.error, OverflowError, ValueError, TypeError):
        return b""


def _heartbeat_bytes() -> bytes:
    from pymavlink.dialects.v20 import common as C

    mav = C.MAVLink(io.BytesIO(), srcSystem=1, srcComponent=1)
    return bytes(C.MAVLink_heartbeat_message(2, 12, 128, 0, 4, 3).pack(mav))


def run_mavlink(data: bytes, d: Path):
    _link()
    feed_bytes(_heartbeat_bytes())  # the vehicle is the peer
    return feed_bytes(data)


def mavlink_bytes() -> st.SearchStrategy:
    return st.one_of(
        st.binary(max_size=300),
        mavlink_message().flatmap(lambda b: byte_mutation(b) if b else st.just(b)),
        st.lists(mavlink_message(), min_size=1, max_size=4).map(b"".join),
    )


TARGETS: dict[str, Target] = {}


def _add(t: Target) -> None:
    TARGETS[t.name] = t


_add(Target("scenario", lambda: text_or_doc(SCENARIO_DOC, dump_yaml), run_scenario, lambda d: (str(d / "scenario.yaml"),)))
_add(Target("survey_plan", lambda: text_or_doc(plan_doc(), dump_yaml), run_plan, lambda d: (str(d / "plan.yaml"),)))
_add(Target("sweep.json", lambda: text_or_doc(SWEEP_DOC, dump_json), run_sweep_json, lambda d: (str(d / "sweep"),)))
_add(Target("frames.jsonl", lambda: st.one_of(
    st.lists(doc_mutation(FRAME), min_size=1, max_size=3).map(lambda ds: b"".join(_safe(dump_json)(x) + b"\n" for x in ds)),
    byte_mutation(_frames_bytes())), run_frames, lambda d: (str(d / "sweep"),)))
_add(Target("mosaic.json", lambda: text_or_doc(MOSAIC_DOC, dump_json), run_mosaic, lambda d: (str(d / "run" / "mosaic" / "mosaic.json"),)))
_add(Target("defects.json (detect)", lambda: text_or_doc(DETECT_DOC, dump_json), run_detections,
            lambda d: (str(d / "run" / "detect" / "defects.json"),)))
_add(Target("defects.json (register)", lambda: text_or_doc(register_doc(), dump_json), run_register, lambda d: (str(d / "defects.json"),)))
_add(Target("camera.yaml", lambda: st.one_of(byte_mutation(CAMERA_OPENCV), text_or_doc(CAMERA_ROS, dump_yaml)), run_camera,
            lambda d: (str(d / "camera.yaml"),)))
_add(Target("model .npz", lambda: byte_mutation((MODELS / "defects_v1.npz").read_bytes()),
            _model_runner("saliency", "defects_v1.npz", ".npz"), lambda d: (str(d / "model.npz"),)))
_add(Target("model .onnx", lambda: byte_mutation((MODELS / "defects_unet_v1.onnx").read_bytes(), focus=4096),
            _model_runner("onnx", "defects_unet_v1.onnx", ".onnx"), lambda d: (str(d / "model.onnx"),)))
_add(Target("ULog", lambda: byte_mutation(ulog_seed(), focus=2048), run_log(".ulg"), lambda d: (str(d / "flight.ulg"),)))
_add(Target("tlog", lambda: byte_mutation(tlog_seed(), focus=512), run_log(".tlog"), lambda d: (str(d / "flight.tlog"),)))
_add(Target("MAVLink packets", mavlink_bytes, run_mavlink, lambda d: ("udp:",)))


# =============================================================================== driver


@dataclass
class Tally:
    cases: int = 0
    ok: int = 0
    error: int = 0
    crash: int = 0
    hang: int = 0
    findings: list[tuple[str, bytes, str]] = field(default_factory=list)  # (kind, input, detail)
    seconds: float = 0.0


def drive(name: str, n: int, *, seed: int | None = None, timeout_s: float = CASE_TIMEOUT_S) -> Tally:
    """``n`` hypothesis-generated inputs of target ``name`` through its reader; every outcome tallied
    (no shrinking, no example database: a finding is kept with its input)."""
    import time

    t = TARGETS[name]
    tally = Tally()
    with tempfile.TemporaryDirectory(prefix="fuzz-") as tmp:
        scratch = Path(tmp)
        names = t.names(scratch)

        @settings(max_examples=n, database=None, deadline=None, phases=[Phase.generate], derandomize=seed is None,
                  suppress_health_check=list(HealthCheck))
        @given(t.strategy())
        def one(data):
            o = outcome(lambda: t.run(data, scratch), names, timeout_s)
            tally.cases += 1
            setattr(tally, o.kind, getattr(tally, o.kind) + 1)
            if o.kind in ("crash", "hang"):
                tally.findings.append((o.kind, data, o.detail))

        if seed is not None:
            one = hseed(seed)(one)
        t0 = time.perf_counter()
        one()
        tally.seconds = time.perf_counter() - t0
    return tally
