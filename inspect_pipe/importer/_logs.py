"""Flight logs as arrays: PX4 ULog (pyulog), ArduPilot DataFlash ``.bin`` and MAVLink ``.tlog``
(pymavlink's ``mavutil`` readers). No hand-written parsers.

Every reader returns a :class:`FlightTrack`: the autopilot's local position and velocity (NED,
metres, from its estimator), its attitude (quaternion, body FRD to NED), its range sensors by where
they look, its landed state when logged, and how the log's clock maps to UTC when the log says so
(GPS time, SYSTEM_TIME). Times are seconds on the log's own clock (the autopilot's boot clock).

What each format gives (the topics and messages read):

=========== ============================== ======================== =========================== ====================
format       position, velocity             attitude                 range sensors               UTC
=========== ============================== ======================== =========================== ====================
ULog         ``vehicle_local_position``     ``vehicle_attitude`` q   ``distance_sensor``         ``vehicle_gps_position``
                                                                     (orientation)               / ``sensor_gps`` time_utc_usec
DataFlash    ``XKF1`` (EKF3 core 0) or      ``ATT`` (deg)            ``RFND`` (Orient)           ``GPS`` GWk/GMS
             ``NKF1`` PN PE PD VN VE VD
tlog         ``LOCAL_POSITION_NED``         ``ATTITUDE``             ``DISTANCE_SENSOR``         ``SYSTEM_TIME``
=========== ============================== ======================== =========================== ====================

Landed state: ULog ``vehicle_land_detected``, tlog ``EXTENDED_SYS_STATE``; not read from DataFlash.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from inspect_pipe.errors import InputError

__all__ = ["FlightTrack", "read_flight_log", "LOG_SUFFIXES", "ORIENTATIONS"]

LOG_SUFFIXES = {".ulg": "ulog", ".ulog": "ulog", ".bin": "dataflash", ".tlog": "tlog"}

# MAV_SENSOR_ORIENTATION (PX4 distance_sensor.orientation and ArduPilot RFND Orient use the same numbers)
ORIENTATIONS = {0: "forward", 2: "right", 4: "backward", 6: "left", 24: "up", 25: "down"}

GPS_EPOCH_UNIX_S = 315964800  # 1980-01-06
GPS_LEAP_S = 18  # GPS - UTC since 2017


@dataclass
class FlightTrack:
    """A flight log's vehicle state, on the log's clock (seconds)."""

    path: Path
    kind: str  # ulog | dataflash | tlog
    t_pos: np.ndarray  # (N,)
    pos_ned: np.ndarray  # (N, 3) local position, m
    vel_ned: np.ndarray  # (N, 3) m/s
    t_att: np.ndarray  # (M,)
    quat: np.ndarray  # (M, 4) w x y z, body FRD -> NED, sign-continuous
    ranges: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # orientation -> (t, m; nan = no echo)
    landed: tuple[np.ndarray, list[str]] | None = None  # (t, fsm name: landed, taking_off, flying, landing)
    utc_offset_s: float | None = None  # UTC (unix s) = log time + this
    utc_source: str | None = None
    #: Garbled stretches the reader skipped (a tlog's bytes that are no MAVLink message).
    skipped: int = 0

    @property
    def start_s(self) -> float:
        return float(max(self.t_pos[0], self.t_att[0]))

    @property
    def end_s(self) -> float:
        return float(min(self.t_pos[-1], self.t_att[-1]))

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s

    def summary(self) -> dict:
        return {
            "path": str(self.path.resolve()), "kind": self.kind, "start_s": round(self.start_s, 6), "end_s": round(self.end_s, 6),
            "position_samples": int(len(self.t_pos)), "attitude_samples": int(len(self.t_att)),
            "range_sensors": {k: int(len(v[0])) for k, v in self.ranges.items()},
            "landed_state": self.landed is not None, "utc_offset_s": self.utc_offset_s, "utc_source": self.utc_source,
            **({"skipped_garbled_stretches": self.skipped} if self.skipped else {}),
        }


def quat_from_euler(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """ZYX Euler angles (rad, FRD/NED as MAVLink) -> quaternions (w, x, y, z)."""
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.stack([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy], axis=1)


def _continuous(q: np.ndarray) -> np.ndarray:
    """Flip signs so consecutive quaternions are in the same hemisphere (interpolation-safe)."""
    q = np.asarray(q, float).copy()
    if len(q) > 1:
        flips = np.cumsum(np.r_[0, (np.einsum("ij,ij->i", q[1:], q[:-1]) < 0).astype(int)]) % 2
        q[flips == 1] *= -1
    n = np.linalg.norm(q, axis=1, keepdims=True)
    return q / np.where(n > 0, n, 1.0)


def _sorted(t: np.ndarray, *arrays: np.ndarray):
    """Time-ordered, finite, strictly increasing samples (a log may repeat or reorder a stamp)."""
    t = np.asarray(t, float)
    ok = np.isfinite(t)
    if len(t) == 0:
        return (t, *arrays)
    for a in arrays:
        ok &= np.all(np.isfinite(a.reshape(len(a), -1)), axis=1)
    order = np.argsort(t[ok], kind="stable")
    t2 = t[ok][order]
    keep = np.r_[True, np.diff(t2) > 0]
    return (t2[keep], *(a[ok][order][keep] for a in arrays))


def _need(path: Path, what: str, n: int, hint: str) -> None:
    if n < 2:
        raise InputError(str(path), f"no {what} in the log" if n == 0 else f"only {n} {what} sample in the log", hint)


def _track(path: Path, kind: str, t_pos, pos, vel, t_att, quat, ranges, landed, utc_offset, utc_source, pos_name, att_name) -> FlightTrack:
    t_pos, pos, vel = _sorted(t_pos, np.asarray(pos, float), np.asarray(vel, float))
    _need(path, f"{pos_name} (position)", len(t_pos), "a log of the autopilot's local position estimate is needed")
    t_att, quat = _sorted(t_att, np.asarray(quat, float))
    _need(path, f"{att_name} (attitude)", len(t_att), "a log of the autopilot's attitude is needed")
    rng = {}
    for name, (t, r) in ranges.items():
        t, r = np.asarray(t, float), np.asarray(r, float)
        order = np.argsort(t, kind="stable")
        rng[name] = (t[order], r[order])
    tr = FlightTrack(path, kind, t_pos, pos, vel, t_att, _continuous(quat), rng, landed, utc_offset, utc_source)
    if tr.duration_s <= 0:
        raise InputError(str(path), f"{pos_name} and {att_name} do not overlap in time", "a log of one flight")
    return tr


# --------------------------------------------------------------------------- ULog


def _read_ulog(path: Path) -> FlightTrack:
    try:
        from pyulog import ULog
    except ImportError:
        raise InputError(str(path), "reading a PX4 ULog needs pyulog", "pip install 'inspect-pipe[import]'") from None
    topics = ["vehicle_local_position", "vehicle_attitude", "distance_sensor", "vehicle_gps_position", "sensor_gps", "vehicle_land_detected"]
    try:
        u = ULog(str(path), topics)
    except Exception as err:  # pyulog raises bare exceptions on damaged files
        raise InputError(str(path), f"not a readable ULog ({err.__class__.__name__}: {str(err)[:80]})", "give a .ulg file written by PX4") from None
    data = {}
    for d in u.data_list:
        if d.multi_id == 0 or d.name == "distance_sensor":
            data.setdefault(d.name, []).append(d)
    for topic in ("vehicle_local_position", "vehicle_attitude"):
        if topic not in data or len(data[topic][0].data["timestamp"]) == 0:
            raise InputError(str(path), f"no {topic} topic in the log", f"PX4 logs {topic} by default; check SDLOG_PROFILE")
    lp = data["vehicle_local_position"][0].data
    t_pos = lp["timestamp"] * 1e-6
    pos = np.stack([lp["x"], lp["y"], lp["z"]], axis=1)
    vel = np.stack([lp["vx"], lp["vy"], lp["vz"]], axis=1)
    at = data["vehicle_attitude"][0].data
    quat = np.stack([at["q[0]"], at["q[1]"], at["q[2]"], at["q[3]"]], axis=1)
    ranges: dict[str, tuple[list, list]] = {}
    for d in data.get("distance_sensor", []):
        ds = d.data
        if "current_distance" not in ds:
            continue
        orient = ds.get("orientation", np.full(len(ds["timestamp"]), 25))
        r = ds["current_distance"].astype(float)
        bad = (r < ds.get("min_distance", 0 * r)) | (r > ds.get("max_distance", r + 1))
        if "signal_quality" in ds:
            bad |= ds["signal_quality"] == 0
        r = np.where(bad, np.nan, r)
        for o in np.unique(orient):
            name = ORIENTATIONS.get(int(o))
            if name is None:
                continue
            sel = orient == o
            t_list, r_list = ranges.setdefault(name, ([], []))
            t_list.extend(ds["timestamp"][sel] * 1e-6)
            r_list.extend(r[sel])
    utc_off = utc_src = None
    for topic in ("vehicle_gps_position", "sensor_gps"):
        if topic in data and "time_utc_usec" in data[topic][0].data:
            g = data[topic][0].data
            ok = g["time_utc_usec"] > 0
            if ok.sum() >= 1:
                utc_off = float(np.median(g["time_utc_usec"][ok] * 1e-6 - g["timestamp"][ok] * 1e-6))
                utc_src = f"{topic}.time_utc_usec"
                break
    landed = None
    if "vehicle_land_detected" in data:
        ld = data["vehicle_land_detected"][0].data
        if "landed" in ld and len(ld["timestamp"]):
            landed = (ld["timestamp"] * 1e-6, ["landed" if v else "flying" for v in ld["landed"]])
    return _track(path, "ulog", t_pos, pos, vel, at["timestamp"] * 1e-6, quat,
                  {k: (np.array(v[0]), np.array(v[1])) for k, v in ranges.items()}, landed, utc_off, utc_src,
                  "vehicle_local_position", "vehicle_attitude")


# --------------------------------------------------------------------------- MAVLink tlog

_LANDED = {1: "landed", 2: "flying", 3: "taking_off", 4: "landing"}


def _mavutil(path: Path, **kw):
    try:
        from pymavlink import mavutil
    except ImportError:
        raise InputError(str(path), "reading MAVLink and DataFlash logs needs pymavlink", "pip install 'inspect-pipe[mavlink]'") from None
    try:
        return mavutil.mavlink_connection(str(path), **kw)
    except Exception as err:
        raise InputError(str(path), f"pymavlink cannot open it ({err.__class__.__name__})", "give a .tlog or .bin log") from None


def _read_tlog(path: Path) -> FlightTrack:
    conn = _mavutil(path, dialect="common", robust_parsing=True)
    t_pos, pos, vel, t_att, eul, landed_t, landed_s = [], [], [], [], [], [], []
    ranges: dict[str, tuple[list, list]] = {}
    sys_time, stamp_off = [], []
    n = bad_runs = 0
    vehicle: int | None = None  # MAVLink system id of the autopilot (a tlog also holds the GCS, a companion...)
    try:
        while True:
            m = conn.recv_match(type=["HEARTBEAT", "LOCAL_POSITION_NED", "ATTITUDE", "DISTANCE_SENSOR", "SYSTEM_TIME",
                                      "EXTENDED_SYS_STATE", "BAD_DATA"])
            if m is None:
                break
            kind = m.get_type()
            if kind == "BAD_DATA":  # bytes that are no message (a cut or damaged stretch): skipped, counted
                bad_runs += 1  # (its length is not known: pymavlink skips on to the next timestamp silently)
                continue
            n += 1
            src = m.get_srcSystem()
            if kind == "HEARTBEAT":
                if vehicle is None and getattr(m, "autopilot", 8) != 8:  # 8: MAV_AUTOPILOT_INVALID (not a vehicle)
                    vehicle = src
                continue
            if vehicle is not None and src != vehicle:
                continue
            if kind == "LOCAL_POSITION_NED":
                t = m.time_boot_ms * 1e-3
                t_pos.append(t)
                pos.append((m.x, m.y, m.z))
                vel.append((m.vx, m.vy, m.vz))
                stamp_off.append(m._timestamp - t)
            elif kind == "ATTITUDE":
                t_att.append(m.time_boot_ms * 1e-3)
                eul.append((m.roll, m.pitch, m.yaw))
            elif kind == "DISTANCE_SENSOR":
                name = ORIENTATIONS.get(int(m.orientation))
                if name is None:
                    continue
                r = m.current_distance
                ok = m.min_distance <= r <= m.max_distance
                t_list, r_list = ranges.setdefault(name, ([], []))
                t_list.append(m.time_boot_ms * 1e-3)
                r_list.append(r / 100.0 if ok else math.nan)
            elif kind == "SYSTEM_TIME":
                if m.time_unix_usec > 0 and m.time_boot_ms > 0:
                    sys_time.append(m.time_unix_usec * 1e-6 - m.time_boot_ms * 1e-3)
            elif kind == "EXTENDED_SYS_STATE":  # no time of its own: the last time-stamped message's
                landed_t.append(t_pos[-1] if t_pos else (t_att[-1] if t_att else 0.0))
                landed_s.append(_LANDED.get(int(m.landed_state)))
    except Exception as err:
        raise InputError(str(path), f"garbled MAVLink data after {n} messages ({err.__class__.__name__})", "give a .tlog as a ground station writes it") from None
    finally:
        try:
            conn.close()
        except Exception:
            pass
    if n == 0:
        raise InputError(str(path), "no MAVLink messages found (empty or not a tlog)", "give a .tlog as QGroundControl or MAVProxy writes it")
    if sys_time:
        utc_off, utc_src = float(np.median(sys_time)), "SYSTEM_TIME"
    elif stamp_off:  # the ground station's receive times: late by the link's latency
        utc_off, utc_src = float(np.median(stamp_off)), "tlog receive time"
    else:
        utc_off = utc_src = None
    landed = None
    if landed_t:
        keep = [i for i, s in enumerate(landed_s) if s is not None]
        if keep:
            landed = (np.array([landed_t[i] for i in keep]), [landed_s[i] for i in keep])  # type: ignore[misc]
    e = np.asarray(eul, float).reshape(-1, 3)
    tr = _track(path, "tlog", t_pos, np.asarray(pos, float).reshape(-1, 3), np.asarray(vel, float).reshape(-1, 3), t_att,
                quat_from_euler(e[:, 0], e[:, 1], e[:, 2]), {k: (np.array(v[0]), np.array(v[1])) for k, v in ranges.items()},
                landed, utc_off, utc_src, "LOCAL_POSITION_NED", "ATTITUDE")
    return replace(tr, skipped=bad_runs) if bad_runs else tr


# --------------------------------------------------------------------------- DataFlash


def _read_dataflash(path: Path) -> FlightTrack:
    conn = _mavutil(path)
    kf: dict[str, tuple[list, list, list]] = {"XKF1": ([], [], []), "NKF1": ([], [], [])}
    t_att, eul, gps = [], [], []
    ranges: dict[str, tuple[list, list]] = {}
    n = 0
    try:
        while True:
            m = conn.recv_match(type=["XKF1", "NKF1", "ATT", "RFND", "GPS"])
            if m is None:
                break
            n += 1
            kind = m.get_type()
            t = getattr(m, "TimeUS", None)
            if t is None:
                continue
            t *= 1e-6
            if kind in kf:
                if getattr(m, "C", 0) != 0:  # EKF core 0 only
                    continue
                kf[kind][0].append(t)
                kf[kind][1].append((m.PN, m.PE, m.PD))
                kf[kind][2].append((m.VN, m.VE, m.VD))
            elif kind == "ATT":
                t_att.append(t)
                eul.append((math.radians(m.Roll), math.radians(m.Pitch), math.radians(m.Yaw)))
            elif kind == "RFND":
                name = ORIENTATIONS.get(int(getattr(m, "Orient", 25)))
                if name is None:
                    continue
                d = float(m.Dist)
                t_list, r_list = ranges.setdefault(name, ([], []))
                t_list.append(t)
                r_list.append(d if d > 0 and getattr(m, "Stat", 4) in (4,) else math.nan)
            elif kind == "GPS" and getattr(m, "Status", 0) >= 3 and getattr(m, "GWk", 0) > 0:
                gps.append(GPS_EPOCH_UNIX_S + m.GWk * 604800 + m.GMS * 1e-3 - GPS_LEAP_S - t)
    except Exception as err:
        raise InputError(str(path), f"garbled DataFlash data after {n} messages ({err.__class__.__name__})", "give a .bin log as ArduPilot writes it") from None
    if n == 0:
        raise InputError(str(path), "no DataFlash messages found (empty or not a .bin log)", "give a .bin log as ArduPilot writes it")
    name = "XKF1" if len(kf["XKF1"][0]) >= 2 else "NKF1"
    t_pos, pos, vel = kf[name]
    e = np.asarray(eul, float).reshape(-1, 3)
    return _track(path, "dataflash", t_pos, np.asarray(pos, float).reshape(-1, 3), np.asarray(vel, float).reshape(-1, 3), t_att,
                  quat_from_euler(e[:, 0], e[:, 1], e[:, 2]), {k: (np.array(v[0]), np.array(v[1])) for k, v in ranges.items()},
                  None, float(np.median(gps)) if gps else None, "GPS week time" if gps else None,
                  "XKF1 (EKF3)" if name == "XKF1" else "XKF1/NKF1 (EKF)", "ATT")


def read_flight_log(path: str | Path) -> FlightTrack:
    """The log at ``path`` by its suffix (``.ulg``, ``.bin``, ``.tlog``); :class:`InputError` (one
    line naming the file and the problem) on anything unreadable or missing a needed topic."""
    path = Path(path)
    if not path.is_file():
        raise InputError(str(path), "not found" if not path.exists() else "not a file", "give the flight log (.ulg, .bin or .tlog)")
    kind = LOG_SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise InputError(str(path), f"unknown flight log type {path.suffix!r}", "a PX4 ULog (.ulg), an ArduPilot DataFlash log (.bin) or a MAVLink telemetry log (.tlog)")
    if path.stat().st_size == 0:
        raise InputError(str(path), "is empty", "give the flight log the autopilot or ground station wrote")
    reader = {"ulog": _read_ulog, "tlog": _read_tlog, "dataflash": _read_dataflash}[kind]
    # pymavlink's DataFlash indexer (C) prints a line per bad byte, pyulog prints warnings: a
    # reader's chatter is not the user's output (errors come back as one InputError line)
    with _silenced():
        return reader(path)


@contextlib.contextmanager
def _silenced():
    """stdout and stderr, Python's and the C library's (file descriptors 1 and 2), to /dev/null."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    saved = []
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        for fd in (1, 2):
            saved.append((fd, os.dup(fd)))
            os.dup2(null, fd)
        os.close(null)
    except OSError:  # no real descriptors (embedded interpreter): Python-level only
        pass
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            yield
    finally:
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)
