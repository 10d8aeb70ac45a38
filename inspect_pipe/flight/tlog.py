"""``fly --tlog FILE``: the MAVLink telemetry a real autopilot streams, as a ground station records it.

A ``.tlog`` is what QGroundControl and MAVProxy write: every message as sent on the link, each
preceded by the 8-byte big-endian UTC time (microseconds) at which it arrived. pymavlink's
``mavutil.mavlink_connection(FILE)`` reads it back, so a simulated flight can be imported
(``inspect-pipe import``) exactly like a real one and compared with its ground truth.

Streamed per control tick of the flight (50 Hz): ATTITUDE (the attitude, as the autopilot's
estimator reports it) and LOCAL_POSITION_NED (the onboard stack's position estimate: x from the
front-wall distance when the wall is in range, else integrated speed; the height estimate; the
speed estimate turned into NED). The local frame's origin is the take-off point and its north is
the hold's forward axis (``mavlink_codec``'s convention). DISTANCE_SENSOR, one per range sensor
(front, left, right sonars and the bottom time-of-flight sensor, ids and orientations as
``mavlink_codec.DISTANCE_SENSORS``) at 10 Hz; HEARTBEAT (armed flag), SYSTEM_TIME and
EXTENDED_SYS_STATE (landed state) at 1 Hz / 1 Hz / 5 Hz.

UTC of simulation time ``t`` is ``epoch_s + t``: by default the same epoch as the simulated
camera's clock (``ManualClock``), so the sweep written by ``fly --sweep`` and the tlog share one
clock, as a camera with a perfect clock and its autopilot would.
"""

from __future__ import annotations

import math
import os
import struct
from pathlib import Path

from inspect_pipe.capture._clock import ManualClock
from inspect_pipe.errors import InputError
from inspect_pipe.flight import mavlink_codec as mc
from inspect_pipe.flight.mavlink_endpoint import require_pymavlink

__all__ = ["SIM_EPOCH_S", "TlogWriter"]

SIM_EPOCH_S: float = ManualClock()._epoch  # UTC (s) of simulation time 0, shared with the simulated camera

_FSM_LANDED = {
    "landed": mc.LandedState.ON_GROUND,
    "taking_off": mc.LandedState.TAKEOFF,
    "flying": mc.LandedState.IN_AIR,
    "descending": mc.LandedState.IN_AIR,
    "landing": mc.LandedState.LANDING,
}


class TlogWriter:
    """``on_tick`` callback of the flight runner that writes a ``.tlog``.

    Written to ``FILE.part`` and renamed on :meth:`close`, so an interrupted flight leaves no
    half-written tlog under the final name.
    """

    def __init__(self, path: str | Path, scenario, *, epoch_s: float = SIM_EPOCH_S, system_id: int = 1,
                 distance_hz: float = 10.0) -> None:
        from inspect_pipe.capture.sources.sim import _DeadReckoner, faced_wall  # the same estimate as fly --sweep records

        self.common = require_pymavlink("--tlog")
        self.path = Path(path)
        if self.path.is_dir():
            raise InputError(str(self.path), "is a directory", "give a file path for the tlog")
        self._part = self.path.with_name(self.path.name + ".part")
        try:
            self._fh = open(self._part, "wb")
        except OSError as err:
            raise InputError(str(self.path), f"cannot write the tlog ({err.strerror})", "choose a writable path") from None
        self.mav = self.common.MAVLink(None, srcSystem=system_id, srcComponent=1)
        v = scenario.vehicle
        self.start = v.start_position_m
        self._dr = _DeadReckoner(v.start_position_m, v.start_yaw_rad, faced_wall(scenario))
        self.epoch_s = float(epoch_s)
        self._next_hb = 0.0
        self._next_ext = 0.0
        self._dist_period = 1.0 / distance_hz
        self._next_dist = 0.0
        self.messages = 0

    def _send(self, t: float, msg) -> None:
        buf = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        self._fh.write(struct.pack(">Q", int(round((self.epoch_s + t) * 1e6))) + buf)
        self.messages += 1

    def __call__(self, rec) -> None:
        C, t = self.common, rec.t
        ms = int(round(t * 1000))
        out = rec.out
        fsm = out.fsm.value
        if t >= self._next_hb - 1e-9:
            self._next_hb += 1.0
            armed = fsm != "landed"
            base = mc.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mc.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
            self._send(t, C.MAVLink_heartbeat_message(mc.MAV_TYPE_QUADROTOR, mc.MAV_AUTOPILOT_PX4, base,
                                                      mc.px4_custom_mode(mc.Px4Mode.POSCTL),
                                                      mc.MAV_STATE_ACTIVE if armed else mc.MAV_STATE_STANDBY, 3))
            self._send(t, C.MAVLink_system_time_message(int(round((self.epoch_s + t) * 1e6)), ms))
        if t >= self._next_ext - 1e-9:
            self._next_ext += 0.2
            self._send(t, C.MAVLink_extended_sys_state_message(0, int(_FSM_LANDED.get(fsm, mc.LandedState.UNDEFINED))))
        roll_w, pitch_w, yaw_w = rec.rpy_true
        roll, pitch, yaw = mc.attitude_from_world(roll_w, pitch_w, yaw_w)
        self._send(t, C.MAVLink_attitude_message(ms, roll, pitch, yaw, 0.0, 0.0, 0.0))
        e, c = out.estimate, out.clearance
        x, y = self._dr.update(t, e.vx_m_s, e.vy_m_s, c.front_m)
        cy, sy = math.cos(yaw_w), math.sin(yaw_w)
        vxw, vyw = cy * e.vx_m_s - sy * e.vy_m_s, sy * e.vx_m_s + cy * e.vy_m_s
        x0, y0, _ = self.start
        self._send(t, C.MAVLink_local_position_ned_message(ms, x - x0, -(y - y0), -e.altitude_m, vxw, -vyw, -e.vz_m_s))
        if t >= self._next_dist - 1e-9:
            self._next_dist += self._dist_period
            for slot, reading in ((mc.DistanceSlot.FRONT_SONAR, c.front_m), (mc.DistanceSlot.LEFT_SONAR, c.left_m),
                                  (mc.DistanceSlot.RIGHT_SONAR, c.right_m), (mc.DistanceSlot.BOTTOM_TOF, e.height_m)):
                sid, kind, orient, lo, hi = mc.DISTANCE_SENSORS[slot]
                self._send(t, C.MAVLink_distance_sensor_message(ms, lo, hi, mc.range_to_cm(reading, hi), kind, sid, orient, 0))

    def close(self, *, keep: bool = True) -> None:
        """Finish the file: renamed into place when ``keep``, removed otherwise."""
        if self._fh.closed:
            return
        try:
            self._fh.flush()
            os.fsync(self._fh.fileno())
        finally:
            self._fh.close()
        if keep:
            os.replace(self._part, self.path)
        else:
            self._part.unlink(missing_ok=True)
