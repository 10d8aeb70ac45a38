"""A tlog re-written as an ArduPilot DataFlash ``.bin`` (for the reader tests; pymavlink has no
DataFlash writer). The file is what ArduPilot writes: FMT messages defining each message type,
then ``0xA3 0x95 id`` + packed fields. Only the messages the import reads: XKF1 (EKF3 core 0),
ATT (degrees), RFND (metres, status, orientation) and GPS (week and ms of week)."""

from __future__ import annotations

import math
import struct
from pathlib import Path

FORMATS = {"XKF1": (200, "QBffffff", "TimeUS,C,PN,PE,PD,VN,VE,VD"), "ATT": (201, "Qfff", "TimeUS,Roll,Pitch,Yaw"),
           "RFND": (202, "QBfBB", "TimeUS,Instance,Dist,Stat,Orient"), "GPS": (203, "QBIH", "TimeUS,Status,GMS,GWk")}


def _fmt(type_id: int, name: str, fmt: str, cols: str) -> bytes:
    length = 3 + struct.calcsize("<" + fmt)
    return struct.pack("<BBBBB4s16s64s", 0xA3, 0x95, 128, type_id, length, name.encode(), fmt.encode(), cols.encode())


def _msg(name: str, *vals) -> bytes:
    tid, fmt, _ = FORMATS[name]
    return struct.pack("<BBB", 0xA3, 0x95, tid) + struct.pack("<" + fmt, *vals)


def tlog_to_dataflash(tlog: Path, out: Path, *, gps: bool = True) -> None:
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(tlog), dialect="common")
    buf = bytearray(b"".join(_fmt(t, n, f, c) for n, (t, f, c) in FORMATS.items()))
    while (m := conn.recv_match(type=["LOCAL_POSITION_NED", "ATTITUDE", "DISTANCE_SENSOR", "SYSTEM_TIME"])) is not None:
        kind, us = m.get_type(), m.time_boot_ms * 1000
        if kind == "SYSTEM_TIME":
            if not gps:
                continue
            gps_s = m.time_unix_usec * 1e-6 - 315964800 + 18  # GPS time runs 18 s ahead of UTC
            week = int(gps_s // 604800)
            buf += _msg("GPS", us, 3, int(round((gps_s - week * 604800) * 1000)), week)
        elif kind == "LOCAL_POSITION_NED":
            buf += _msg("XKF1", us, 0, m.x, m.y, m.z, m.vx, m.vy, m.vz)
        elif kind == "ATTITUDE":
            buf += _msg("ATT", us, math.degrees(m.roll), math.degrees(m.pitch), math.degrees(m.yaw))
        else:
            ok = m.min_distance <= m.current_distance <= m.max_distance
            buf += _msg("RFND", us, m.id, m.current_distance / 100.0, 4 if ok else 1, m.orientation)
    out.write_bytes(bytes(buf))
