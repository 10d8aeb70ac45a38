"""Flight log writer (``inspect_pipe.flight_log/1``): JSONL, a header line, then one line per
control tick with the fields SPEC.md fixes."""

from __future__ import annotations

import json
from pathlib import Path
from typing import IO

import inspect_pipe
from inspect_pipe.flight.runner import TickRecord
from inspect_pipe.flight.scenario import Scenario

__all__ = ["FORMAT", "FlightLogWriter", "record_to_json"]

FORMAT = "inspect_pipe.flight_log/1"


def _r(x: float | None, nd: int = 4) -> float | None:
    return None if x is None else round(x, nd)


def _cmd(c) -> dict:
    return {"vx": _r(c.vx_m_s), "vy": _r(c.vy_m_s), "vz": _r(c.vz_m_s), "yaw_rate": _r(c.yaw_rate_rad_s)}


def record_to_json(rec: TickRecord) -> dict:
    o, e, d, c, i = rec.out, rec.out.estimate, rec.dist_true, rec.out.clearance, rec.imu
    return {
        "t": _r(rec.t, 3),
        "pos_true": [_r(v) for v in rec.pos_true],
        "vel_true": [_r(v) for v in rec.vel_true],
        "yaw_true": _r(rec.yaw_true),
        "est": {"height": _r(e.height_m), "altitude": _r(e.altitude_m), "vx": _r(e.vx_m_s), "vy": _r(e.vy_m_s), "vz": _r(e.vz_m_s)},
        "est_mode": int(e.mode),
        "fsm": o.fsm.value,
        "user_cmd": _cmd(o.user_cmd),
        "cmd": _cmd(o.command),
        "behaviors": list(o.behaviors),
        "inspection_mode": o.inspection_mode,
        "dist_est": {"front": _r(c.front_m), "left": _r(c.left_m), "right": _r(c.right_m), "down": _r(c.down_m)},
        "dist_true": {"front": _r(d.front), "back": _r(d.back), "left": _r(d.left), "right": _r(d.right), "down": _r(d.down)},
        "attitude_sp": {"roll": _r(o.setpoint.roll_rad), "pitch": _r(o.setpoint.pitch_rad), "thrust": _r(o.setpoint.thrust_frac)},
        "imu": None if i is None else {"ax": _r(i.fx_m_s2), "ay": _r(i.fy_m_s2), "az": _r(i.fz_m_s2)},
        "att_est": None if i is None else {"roll": _r(i.roll_rad, 5), "pitch": _r(i.pitch_rad, 5)},
        "att_true": {"roll": _r(rec.rpy_true[0], 5), "pitch": _r(rec.rpy_true[1], 5)},
        "battery_percent": _r(rec.battery_percent, 2),
        "link_ok": rec.link_ok,
        "collided": rec.collided,
    }


class FlightLogWriter:
    """Context manager; call it with each :class:`TickRecord`. Lines are flushed as written, so
    an interrupted flight leaves a readable log up to its last whole tick."""

    def __init__(self, path: str | Path, scenario: Scenario, tick_hz: float) -> None:
        self.path = Path(path)
        self.scenario = scenario
        self.tick_hz = tick_hz
        self._fh: IO[str] | None = None

    def __enter__(self) -> "FlightLogWriter":
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = self.path.open("w", buffering=1 << 16)
        h = self.scenario.world.hold
        header = {
            "format": FORMAT,
            "scenario": self.scenario.name,
            "tick_hz": self.tick_hz,
            "duration_s": self.scenario.duration_s,
            "seed": self.scenario.seed,
            "hold": {"length_m": h.length_m, "width_m": h.width_m, "height_m": h.height_m},
            "software_version": inspect_pipe.__version__,
        }
        self._fh.write(json.dumps(header) + "\n")
        return self

    def __call__(self, rec: TickRecord) -> None:
        assert self._fh is not None, "use FlightLogWriter as a context manager"
        self._fh.write(json.dumps(record_to_json(rec), separators=(",", ":")) + "\n")

    def __exit__(self, *exc) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None
