"""Vehicle state for capture (``capture --vehicle mavlink:URL | sim:SCENARIO``): each frame is
stamped with the vehicle's state at mid-exposure, interpolated between telemetry samples, with the
autopilot's clock mapped onto the host's.

:class:`AutopilotStateTracker` is the pure core: it takes MAVLink messages (any object with
``get_type()`` and the message's fields, as pymavlink decodes them) and the host time they
arrived, and answers ``state_at(t_host)``. :class:`MavlinkStateFeed` is the adapter that receives
them from a link. Frames:

- ``LOCAL_POSITION_NED`` (x north, y east, z down, from the autopilot's local origin, where its
  estimator started: the take-off point) is turned into the flight's *take-off frame*: same
  origin, x along the heading of the first ATTITUDE received, y to its left, z up
  (``odometry_frame: takeoff`` in sweep.json; the survey plan's ``takeoff`` ties it to the hold).
  Start the capture before take-off, so that the first heading is the take-off heading.
- ``DISTANCE_SENSOR`` by orientation: forward (``MAV_SENSOR_ROTATION_NONE``) gives the distance to
  the wall ahead, downward (``MAV_SENSOR_ROTATION_PITCH_270``) the height.
- Clock: ``TIMESYNC`` round trips (the reply with the smallest round-trip time wins: its offset is
  good to half of it); until one arrives, the lower envelope of (arrival - ``time_boot_ms``) over
  every stamped message (the least-delayed message bounds the offset).
"""

from __future__ import annotations

import bisect
import math
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable

from inspect_pipe.capture._state import TrajectoryFeed, VehicleState
from inspect_pipe.errors import InputError

__all__ = ["AutopilotStateTracker", "ClockMap", "MavlinkStateFeed", "SimStateFeed", "open_vehicle_feed"]

# MAV_LANDED_STATE_<NAME> -> the sweep's fsm words
LANDED = {"ON_GROUND": "landed", "IN_AIR": "flying", "TAKEOFF": "taking_off", "LANDING": "landing"}


@dataclass
class ClockMap:
    """host_s = autopilot_boot_s + offset_s."""

    offset_s: float | None = None
    method: str = "none"
    uncertainty_s: float = math.inf  # half the best round trip (TIMESYNC) or the envelope's spread

    def observe_arrival(self, boot_s: float, host_s: float) -> None:
        """A stamped message arrived: it cannot have arrived before it was stamped."""
        if self.method == "timesync":
            return
        off = host_s - boot_s
        if self.offset_s is None or off < self.offset_s:
            self.offset_s, self.method = off, "lower envelope of message arrival"

    def observe_timesync(self, autopilot_ns: int, sent_host_s: float, now_host_s: float) -> None:
        rtt = now_host_s - sent_host_s
        if rtt < 0 or rtt > 1.0:
            return
        off = (sent_host_s + now_host_s) / 2 - autopilot_ns * 1e-9
        if rtt / 2 < self.uncertainty_s:
            self.offset_s, self.method, self.uncertainty_s = off, "TIMESYNC", rtt / 2

    def to_host(self, boot_s: float) -> float | None:
        return None if self.offset_s is None else boot_s + self.offset_s

    def to_json(self) -> dict:
        return {"method": self.method, "offset_s": None if self.offset_s is None else round(self.offset_s, 6),
                "uncertainty_s": None if not math.isfinite(self.uncertainty_s) else round(self.uncertainty_s, 6)}


class _Series:
    """Time-ordered samples (host time, value tuple) with interpolation."""

    def __init__(self, keep: int = 20000) -> None:
        self.t: list[float] = []
        self.v: list[tuple[float, ...]] = []
        self.keep = keep

    def add(self, t: float, v: tuple[float, ...]) -> None:
        if self.t and t <= self.t[-1]:
            if t == self.t[-1]:
                self.v[-1] = v
            return  # out of order (a re-sent or delayed packet): the series keeps its order
        self.t.append(t)
        self.v.append(v)
        if len(self.t) > self.keep:
            del self.t[: self.keep // 2], self.v[: self.keep // 2]

    def at(self, t: float, max_gap_s: float, max_extrapolate_s: float = 0.0) -> tuple[tuple[float, ...], bool] | None:
        """(value at t, extrapolated?) by linear interpolation between the samples around t; past
        the last sample by at most ``max_extrapolate_s`` (value held). None where not covered."""
        if not self.t or t < self.t[0]:
            return None
        i = bisect.bisect_right(self.t, t)
        if self.t[i - 1] == t:
            return self.v[i - 1], False
        if i >= len(self.t):
            if t - self.t[-1] <= max_extrapolate_s:
                return self.v[-1], True
            return None
        t0, t1 = self.t[i - 1], self.t[i]
        if t1 - t0 > max_gap_s:
            return None
        w = (t - t0) / (t1 - t0) if t1 > t0 else 0.0
        return tuple(a + w * (b - a) for a, b in zip(self.v[i - 1], self.v[i])), False


class AutopilotStateTracker:
    """Pure: MAVLink messages in (with their host arrival time), vehicle state at any host time out."""

    def __init__(self, *, max_gap_s: float = 0.5, max_extrapolate_s: float = 0.1, mode_names: Callable[[Any], str] | None = None) -> None:
        self.clock = ClockMap()
        self.max_gap_s = max_gap_s
        self.max_extrapolate_s = max_extrapolate_s
        self.mode_names = mode_names
        self.pos = _Series()  # host t -> (x, y, z, vx, vy, vz) in the take-off frame (x fwd, y left, z up)
        self.yaw = _Series()  # host t -> (yaw in the take-off frame,)
        self.front = _Series()
        self.down = _Series()
        self.yaw0: float | None = None  # NED yaw of the first ATTITUDE: the take-off heading
        self.landed_state: str | None = None
        self.mode: str | None = None
        self.messages = 0
        self.last_rx_host_s: float | None = None
        self._pending: list[tuple[float, Any]] = []  # stamped messages waiting for a clock

    # -------------------------------------------------------------- input
    def on_message(self, m: Any, host_s: float) -> None:
        kind = m.get_type()
        self.messages += 1
        self.last_rx_host_s = host_s
        from pymavlink.dialects.v20 import common  # the messages come from it: it is installed

        if kind == "HEARTBEAT":
            if getattr(m, "autopilot", common.MAV_AUTOPILOT_INVALID) == common.MAV_AUTOPILOT_INVALID:  # a GCS or companion, not the vehicle
                return
            if self.mode_names is not None:
                self.mode = self.mode_names(m)
            return
        if kind == "EXTENDED_SYS_STATE":
            entry = common.enums["MAV_LANDED_STATE"].get(int(m.landed_state))
            self.landed_state = LANDED.get(entry.name[len("MAV_LANDED_STATE_"):]) if entry is not None else None
            return
        if kind == "TIMESYNC":
            return  # answered by the feed, which knows when it sent the request
        boot_ms = getattr(m, "time_boot_ms", None)
        if boot_ms is None or kind not in ("LOCAL_POSITION_NED", "ATTITUDE", "DISTANCE_SENSOR", "SYSTEM_TIME"):
            return
        boot_s = float(boot_ms) * 1e-3
        self.clock.observe_arrival(boot_s, host_s)
        t = self.clock.to_host(boot_s)
        if t is None:
            return
        if kind == "ATTITUDE":
            if math.isfinite(m.yaw):
                if self.yaw0 is None:
                    self.yaw0 = float(m.yaw)
                self.yaw.add(t, (-(float(m.yaw) - self.yaw0),))
        elif kind == "LOCAL_POSITION_NED":
            vals = (m.x, m.y, m.z, m.vx, m.vy, m.vz)
            if not all(math.isfinite(v) for v in vals):
                return
            if self.yaw0 is None:
                return  # the take-off frame needs the heading: wait for ATTITUDE
            self.pos.add(t, self._to_takeoff(vals))
        elif kind == "DISTANCE_SENSOR":
            if not (m.min_distance <= m.current_distance <= m.max_distance) or m.current_distance <= 0:
                return  # out of range: no reading
            r = float(m.current_distance) / 100.0
            if m.orientation == common.MAV_SENSOR_ROTATION_NONE:
                self.front.add(t, (r,))
            elif m.orientation == common.MAV_SENSOR_ROTATION_PITCH_270:
                self.down.add(t, (r,))

    def _to_takeoff(self, ned: tuple[float, ...]) -> tuple[float, ...]:
        c, s = math.cos(self.yaw0), math.sin(self.yaw0)  # type: ignore[arg-type]
        # NED -> take-off heading frame (forward, right), then right -> left and down -> up
        fwd, right = c * ned[0] + s * ned[1], -s * ned[0] + c * ned[1]
        vf, vr = c * ned[3] + s * ned[4], -s * ned[3] + c * ned[4]
        return (fwd, -right, -ned[2], vf, -vr, -ned[5])

    # -------------------------------------------------------------- output
    def state_at(self, t_host: float) -> VehicleState | None:
        p = self.pos.at(t_host, self.max_gap_s, self.max_extrapolate_s)
        if p is None:
            return None
        (x, y, z, vx, vy, vz), extrapolated = p
        if extrapolated:  # the newest fix is a little older than the exposure: carry it with its velocity
            dt = t_host - self.pos.t[-1]
            x, y, z = x + vx * dt, y + vy * dt, z + vz * dt
        f = self.front.at(t_host, self.max_gap_s, self.max_extrapolate_s)
        d = self.down.at(t_host, self.max_gap_s, self.max_extrapolate_s)
        yaw = self.yaw.at(t_host, self.max_gap_s, self.max_extrapolate_s)
        # body-frame velocity (the sweep's velocity is the vehicle's, as the flight stack's estimate)
        if yaw is not None:
            c, s = math.cos(yaw[0][0]), math.sin(yaw[0][0])
            vx, vy = c * vx + s * vy, -s * vx + c * vy
        return VehicleState(
            t_s=t_host, position_m=(x, y, z), dist_front_m=None if f is None else f[0][0],
            height_m=d[0][0] if d is not None else z, velocity_m_s=(vx, vy, vz), est_mode=None,
            fsm=self.landed_state, inspection_mode=None,
        )

    def summary(self) -> dict:
        return {"clock": self.clock.to_json(), "messages": self.messages, "mode": self.mode}


class MavlinkStateFeed:
    """Adapter: a MAVLink link's telemetry into an :class:`AutopilotStateTracker` (receive thread;
    TIMESYNC requests at 1 Hz). ``state_at`` is the capture's :class:`StateFeed`."""

    def __init__(self, url: str, *, clock: Callable[[], float] = time.monotonic, heartbeat_timeout_s: float = 5.0,
                 link_timeout_s: float = 1.5) -> None:
        from inspect_pipe.flight import mavlink_codec as mc
        from inspect_pipe.flight.mavlink_endpoint import MavlinkEndpoint

        self.url, self.clock, self.link_timeout_s = url, clock, link_timeout_s
        self.ep = MavlinkEndpoint(url, system_id=255, component_id=mc.MAV_COMP_ID_ONBOARD_COMPUTER,
                                  accept_heartbeat=lambda m: m.autopilot != mc.MAV_AUTOPILOT_INVALID)
        self.C = self.ep.common
        self.tracker = AutopilotStateTracker(mode_names=self._mode_name)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._hb = threading.Event()
        self._flavour: str | None = None
        self._thread = threading.Thread(target=self._rx_loop, daemon=True, name="mavlink-state")
        self._thread.start()
        if not self._hb.wait(heartbeat_timeout_s):
            self.close()
            raise InputError(url, f"no heartbeat from an autopilot within {heartbeat_timeout_s:.0f} s",
                             "check the URL and that the autopilot streams MAVLink to this port")

    @staticmethod
    def _mode_name(heartbeat: Any) -> str:
        from pymavlink import mavutil

        return mavutil.mode_string_v10(heartbeat)  # PX4 and ArduPilot mode tables, as pymavlink keeps them

    def _rx_loop(self) -> None:
        next_sync = 0.0
        while not self._stop.is_set():
            now = self.clock()
            if now >= next_sync:
                self.ep.send(self.C.MAVLink_timesync_message(0, int(now * 1e9)))
                next_sync = now + 1.0
            for m in self.ep.recv(0.05):
                t = self.clock()
                try:
                    if m.get_type() == "HEARTBEAT" and m.autopilot != 8:
                        self._flavour = "px4" if m.autopilot == 12 else "ardupilot"
                        self._hb.set()
                    with self._lock:
                        if m.get_type() == "TIMESYNC" and m.tc1 != 0:
                            self.tracker.clock.observe_timesync(int(m.tc1), m.ts1 * 1e-9, t)
                        else:
                            self.tracker.on_message(m, t)
                except (ValueError, TypeError, OverflowError, AttributeError):
                    self.ep.stats.bad_packets += 1  # a well-formed frame with nonsense values: dropped, counted

    def link_ok(self) -> bool:
        last = self.tracker.last_rx_host_s
        return last is not None and self.clock() - last <= self.link_timeout_s

    def state_at(self, t_s: float) -> VehicleState | None:
        with self._lock:
            return self.tracker.state_at(t_s)

    def describe(self) -> dict:
        with self._lock:
            return {"kind": "mavlink", "url": self.url, "autopilot": self._flavour, **self.tracker.summary(),
                    "bad_packets": self.ep.stats.bad_packets}

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout=1.0)
        self.ep.close()


class SimStateFeed:
    """``--vehicle sim:SCENARIO``: the scenario flown by the embedded simulator (faster than real
    time, before the capture starts), its timeline laid on the host clock from the first call."""

    def __init__(self, scenario, *, clock: Callable[[], float] = time.monotonic) -> None:
        from inspect_pipe.capture.sources.sim import TrajectoryRecorder
        from inspect_pipe.flight.runner import run_scenario

        rec = TrajectoryRecorder(scenario)
        run_scenario(scenario, on_tick=rec)
        self.feed: TrajectoryFeed = rec.feed
        self.scenario = scenario
        self.clock = clock
        self.t0: float | None = None

    def state_at(self, t_s: float) -> VehicleState | None:
        if self.t0 is None:
            self.t0 = t_s
        s = self.feed.state_at(t_s - self.t0)
        if s is None:
            return None
        return VehicleState(t_s, s.position_m, s.dist_front_m, s.height_m, s.velocity_m_s, s.est_mode, s.fsm, s.inspection_mode)

    def link_ok(self) -> bool:
        return True

    def describe(self) -> dict:
        return {"kind": "sim", "scenario": self.scenario.name}

    def close(self) -> None:
        pass


def open_vehicle_feed(spec: str, *, clock: Callable[[], float] = time.monotonic):
    """``mavlink:URL`` or ``sim:SCENARIO`` -> (feed, odometry frame of its positions)."""
    if spec.startswith("mavlink:"):
        from inspect_pipe.flight.mavlink_endpoint import require_pymavlink
        from inspect_pipe.flight.mavlink_vehicle import parse_vehicle_url

        require_pymavlink("--vehicle mavlink:")
        return MavlinkStateFeed(parse_vehicle_url(spec), clock=clock), "takeoff"
    if spec.startswith("sim:"):
        from inspect_pipe.flight import load_scenario

        return SimStateFeed(load_scenario(spec[4:]), clock=clock), "hold"
    raise InputError(f"--vehicle {spec}", "unknown vehicle", "mavlink:udp:HOST:PORT (or udpout:, tcp:) or sim:SCENARIO.yaml")
