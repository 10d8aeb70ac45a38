"""The companion computer's link to a real autopilot (PX4 offboard, ArduCopter guided).

:class:`MavlinkLink` speaks MAVLink: heartbeats both ways, commands with their acknowledgements,
velocity set-points, and the sensor messages turned into the stack's :class:`Measurements`.
:class:`MavlinkPlant` puts it behind the unchanged :class:`OnboardStack`: each tick the stack's
speed command (``TickOutput.command``, heading frame) leaves as SET_POSITION_TARGET_LOCAL_NED
(velocity only) and its flight-machine transitions become autopilot commands:

* ``landed -> taking_off``: mode offboard (PX4; set-points already streaming, as PX4 requires)
  or guided (ArduCopter), arm, and for ArduCopter NAV_TAKEOFF to the hover height;
* ``-> landing`` (below 0.5 m): NAV_LAND; the autopilot touches down and disarms.

The stack's attitude set-point is not sent: with an autopilot the velocity loops run there.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable

from inspect_pipe.errors import InputError
from inspect_pipe.flight import mavlink_codec as mc
from inspect_pipe.flight.mavlink_endpoint import MavlinkEndpoint
from inspect_pipe.flight_stack.flight_machine import FlightState
from inspect_pipe.flight_stack.messages import (
    BottomFlow,
    Clearance,
    FrontFlow,
    ImuReading,
    Measurements,
    RangeReading,
    SpeedCommand,
)
from inspect_pipe.flight_stack.onboard import TickOutput

__all__ = ["CommandFailed", "LinkStatus", "MavlinkLink", "MavlinkPlant", "parse_vehicle_url"]



class CommandFailed(RuntimeError):
    pass


def parse_vehicle_url(spec: str) -> str:
    """``mavlink:udpout:127.0.0.1:14540`` -> ``udpout:127.0.0.1:14540`` (one-line error otherwise)."""
    if not spec.startswith("mavlink:") or len(spec) <= len("mavlink:"):
        raise InputError(spec, "unknown vehicle", "mavlink:udpout:HOST:PORT, mavlink:udp:HOST:PORT (listen) or mavlink:tcp:HOST:PORT")
    return spec[len("mavlink:"):]


@dataclass
class LinkStatus:
    """What the page shows about the vehicle link."""

    autopilot: str = "?"
    armed: bool = False
    mode: int = 0
    landed_state: str = "undefined"
    heartbeat_age_s: float | None = None
    messages_per_s: float = 0.0
    bad_packets: int = 0
    foreign_packets: int = 0
    acks: list[str] = field(default_factory=list)


class MavlinkLink:
    """Thread-safe; a receive thread keeps the latest reading of every sensor."""

    def __init__(self, url: str, *, clock: Callable[[], float] = time.monotonic, system_id: int = 1,
                 heartbeat_timeout_s: float = 5.0, link_timeout_s: float = 1.5) -> None:
        self.url = url
        self.clock = clock
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.link_timeout_s = link_timeout_s
        self.ep = MavlinkEndpoint(
            url, system_id=system_id, component_id=mc.MAV_COMP_ID_ONBOARD_COMPUTER,
            accept_heartbeat=lambda m: m.type not in (mc.MAV_TYPE_GCS, mc.MAV_TYPE_ONBOARD_CONTROLLER)
            and m.autopilot != mc.MAV_AUTOPILOT_INVALID,
        )
        self.C = self.ep.common
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._hb = threading.Event()
        self._acks: dict[int, tuple[threading.Event, list[int]]] = {}
        self.flavour: mc.Autopilot | None = None
        self.vehicle_component = 1
        self.last_heartbeat_s: float | None = None
        self.armed = False
        self.custom_mode = 0
        self.landed_state = mc.LandedState.UNDEFINED
        self.attitude = (0.0, 0.0, 0.0)  # NED roll, pitch, yaw
        self.have_attitude = False  # an ATTITUDE message has arrived (the heading is known)
        self.local_position: tuple[float, ...] | None = None  # x y z vx vy vz (NED)
        self.battery_percent: float | None = None
        self._ranges: dict[mc.DistanceSlot, RangeReading] = {}
        self._bottom_flow: BottomFlow | None = None
        self._front_flow: FrontFlow | None = None
        self._imu: ImuReading | None = None
        self._rx_times: deque[float] = deque(maxlen=400)
        self.ack_log: deque[str] = deque(maxlen=8)
        self._threads: list[threading.Thread] = []

    # ------------------------------------------------------------------ lifecycle
    def connect(self) -> "MavlinkLink":
        """Start heartbeats and the receive thread; wait for the vehicle's heartbeat."""
        for fn in (self._rx_loop, self._heartbeat_loop):
            t = threading.Thread(target=fn, daemon=True, name=f"mavlink-{fn.__name__}")
            t.start()
            self._threads.append(t)
        if not self._hb.wait(self.heartbeat_timeout_s):
            self.close()
            raise InputError(self.url, f"no heartbeat from a vehicle within {self.heartbeat_timeout_s:.0f} s",
                             "check the URL, that the autopilot is powered and streams MAVLink to this port")
        return self

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=1.0)
        self.ep.close()

    def _heartbeat_loop(self) -> None:
        while not self._stop.is_set():
            self.ep.send(self.C.MAVLink_heartbeat_message(mc.MAV_TYPE_ONBOARD_CONTROLLER, mc.MAV_AUTOPILOT_INVALID, 0, 0,
                                                          mc.MAV_STATE_ACTIVE, 3))
            self._stop.wait(1.0 if self._hb.is_set() else 0.2)

    def _rx_loop(self) -> None:
        while not self._stop.is_set():
            for m in self.ep.recv(0.05):
                try:
                    self._handle(m, self.clock())
                except (ValueError, TypeError, OverflowError):
                    self.ep.stats.bad_packets += 1  # well-formed frame, nonsense values

    # ------------------------------------------------------------------ incoming
    def _handle(self, m: Any, now: float) -> None:
        kind = m.get_type()
        self._rx_times.append(now)
        if kind == "HEARTBEAT":
            if m.type in (mc.MAV_TYPE_GCS, mc.MAV_TYPE_ONBOARD_CONTROLLER):
                return
            self.vehicle_component = m.get_srcComponent()
            self.flavour = mc.Autopilot.PX4 if m.autopilot == mc.MAV_AUTOPILOT_PX4 else mc.Autopilot.ARDUPILOT
            self.armed = bool(m.base_mode & mc.MAV_MODE_FLAG_SAFETY_ARMED)
            self.custom_mode = m.custom_mode
            self.last_heartbeat_s = now
            self._hb.set()
        elif kind == "COMMAND_ACK":
            waiter = self._acks.get(m.command)
            if waiter is not None:
                waiter[1].append(m.result)
                waiter[0].set()
        elif kind == "DISTANCE_SENSOR":
            slot = mc.distance_slot(m.type, m.orientation)
            if slot is not None:
                with self._lock:
                    self._ranges[slot] = RangeReading(now, mc.range_from_cm(m.current_distance, m.min_distance, m.max_distance))
        elif kind == "OPTICAL_FLOW_RAD":
            f = mc.flow_from_rad(m.integrated_x, m.integrated_y, m.integrated_xgyro, m.integrated_ygyro,
                                 m.integration_time_us, m.distance, m.quality)
            with self._lock:
                if m.sensor_id == 0:
                    self._bottom_flow = BottomFlow(now, f.a_m_s, f.b_m_s, f.quality, f.rate_a_rad_s, f.rate_b_rad_s, f.scaled)
                elif m.sensor_id == 1:
                    self._front_flow = FrontFlow(now, f.a_m_s, f.b_m_s, f.quality, f.rate_a_rad_s, f.rate_b_rad_s, f.scaled)
        elif kind == "ATTITUDE":
            if all(math.isfinite(v) for v in (m.roll, m.pitch, m.yaw)):
                self.attitude = (m.roll, m.pitch, m.yaw)
                self.have_attitude = True
        elif kind == "HIGHRES_IMU" or kind == "SCALED_IMU":
            scale = 1.0 if kind == "HIGHRES_IMU" else 9.81e-3  # SCALED_IMU is in milli-g
            f = (m.xacc * scale, m.yacc * scale, m.zacc * scale)
            if all(math.isfinite(v) for v in f):
                roll, pitch, yaw_ned = self.attitude
                with self._lock:
                    # World yaw (x forward, y left) is the NED yaw negated (see mavlink_codec);
                    # FRD specific force -> the stack's body axes (x forward, y left, z up), with
                    # the autopilot's attitude estimate (pitch negated likewise).
                    yaw = -float(yaw_ned) if self.have_attitude else None
                    self._imu = ImuReading(now, f[0], -f[1], -f[2], yaw, float(roll), -float(pitch))
        elif kind == "LOCAL_POSITION_NED":
            self.local_position = (m.x, m.y, m.z, m.vx, m.vy, m.vz)
        elif kind == "BATTERY_STATUS":
            if 0 <= m.battery_remaining <= 100:
                self.battery_percent = float(m.battery_remaining)
        elif kind == "EXTENDED_SYS_STATE":
            if m.landed_state in mc.LandedState._value2member_map_:
                self.landed_state = mc.LandedState(m.landed_state)

    # ------------------------------------------------------------------ reading
    def measurements(self) -> Measurements:
        with self._lock:
            r = self._ranges
            return Measurements(
                bottom_flow=self._bottom_flow, bottom_sonar=r.get(mc.DistanceSlot.BOTTOM_SONAR),
                bottom_tof=r.get(mc.DistanceSlot.BOTTOM_TOF), front_flow=self._front_flow,
                front_sonar=r.get(mc.DistanceSlot.FRONT_SONAR), left_sonar=r.get(mc.DistanceSlot.LEFT_SONAR),
                right_sonar=r.get(mc.DistanceSlot.RIGHT_SONAR), imu=self._imu,
            )

    def link_ok(self, now: float | None = None) -> bool:
        now = self.clock() if now is None else now
        return self.last_heartbeat_s is not None and now - self.last_heartbeat_s <= self.link_timeout_s

    def status(self) -> LinkStatus:
        now = self.clock()
        recent = [t for t in self._rx_times if now - t <= 1.0]
        return LinkStatus(
            autopilot=self.flavour.value if self.flavour else "?", armed=self.armed, mode=self.custom_mode,
            landed_state=self.landed_state.name.lower(),
            heartbeat_age_s=None if self.last_heartbeat_s is None else now - self.last_heartbeat_s,
            messages_per_s=float(len(recent)), bad_packets=self.ep.stats.bad_packets,
            foreign_packets=self.ep.stats.foreign_packets, acks=list(self.ack_log),
        )

    # ------------------------------------------------------------------ sending
    def send_velocity(self, cmd: SpeedCommand) -> None:
        vn, ve, vd, yaw_rate = mc.velocity_setpoint_ned(cmd, self.attitude[2])
        ms = int(self.clock() * 1000) & 0xFFFFFFFF
        self.ep.send(self.C.MAVLink_set_position_target_local_ned_message(
            ms, self.ep.peer_system or 1, self.vehicle_component, mc.MAV_FRAME_LOCAL_NED, mc.VELOCITY_ONLY_MASK,
            0, 0, 0, vn, ve, vd, 0, 0, 0, 0, yaw_rate))

    def send_obstacle_distance(self, clearance: Clearance) -> None:
        """The stack's ranges as OBSTACLE_DISTANCE (body FRD, 5-degree bins: front, right, left),
        so the autopilot's own collision prevention is a second layer."""
        dist = [65535] * 72
        for ang, d in ((0, clearance.front_m), (90, clearance.right_m), (270, clearance.left_m)):
            dist[ang // 5] = 501 if d is None else max(30, min(500, int(d * 100)))
        self.ep.send(self.C.MAVLink_obstacle_distance_message(int(self.clock() * 1e6), mc.MAV_DISTANCE_SENSOR_ULTRASOUND,
                                                              dist, 5, 30, 500, 5.0, 0.0, mc.MAV_FRAME_BODY_FRD))

    def command(self, command: int, *params: float, timeout_s: float = 1.5, retries: int = 2) -> int:
        """COMMAND_LONG and wait for its COMMAND_ACK; returns MAV_RESULT, raises on silence."""
        p = list(params) + [0.0] * (7 - len(params))
        ev, results = threading.Event(), []
        self._acks[command] = (ev, results)
        try:
            for attempt in range(retries + 1):
                self.ep.send(self.C.MAVLink_command_long_message(self.ep.peer_system or 1, self.vehicle_component,
                                                                 command, attempt, *p))
                if ev.wait(timeout_s):
                    self.ack_log.append(f"command {command}: result {results[0]}")
                    return results[0]
            self.ack_log.append(f"command {command}: no acknowledgement")
            raise CommandFailed(f"command {command}: no COMMAND_ACK after {retries + 1} tries")
        finally:
            self._acks.pop(command, None)

    def set_companion_mode(self) -> int:
        if self.flavour is mc.Autopilot.PX4:
            return self.command(mc.MAV_CMD_DO_SET_MODE, mc.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mc.Px4Mode.OFFBOARD, 0)
        return self.command(mc.MAV_CMD_DO_SET_MODE, mc.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mc.ArduCopterMode.GUIDED)

    def arm(self, arm: bool = True) -> int:
        return self.command(mc.MAV_CMD_COMPONENT_ARM_DISARM, 1.0 if arm else 0.0)

    def takeoff(self, altitude_m: float) -> int:
        return self.command(mc.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, altitude_m)

    def land(self) -> int:
        return self.command(mc.MAV_CMD_NAV_LAND, 0, 0, 0, math.nan, math.nan, math.nan, 0)


class MavlinkPlant:
    """The vehicle side of a real-time flight: measurements in, the stack's command out."""

    def __init__(self, link: MavlinkLink, *, hover_height_m: float = 1.0, obstacle_distance: bool = True) -> None:
        self.link = link
        self.hover_height_m = hover_height_m
        self.obstacle_distance = obstacle_distance
        self._prev_fsm = FlightState.LANDED
        self._busy = threading.Lock()
        self.events: deque[str] = deque(maxlen=10)
        self._k = 0

    def now(self) -> float:
        """The link's clock: readings are stamped with it on arrival."""
        return self.link.clock()

    def measurements(self, now: float) -> Measurements:
        return self.link.measurements()

    @property
    def battery_percent(self) -> float:
        b = self.link.battery_percent
        return 100.0 if b is None else b

    def vehicle_ok(self) -> bool:
        return self.link.link_ok()

    def apply(self, out: TickOutput, now: float) -> None:
        if out.fsm is not self._prev_fsm:
            self._on_transition(self._prev_fsm, out.fsm)
            self._prev_fsm = out.fsm
        # Set-points stream at the tick rate in every state: PX4 enters offboard only on a live stream.
        self.link.send_velocity(out.command)
        self._k += 1
        if self.obstacle_distance and self._k % 5 == 0:
            self.link.send_obstacle_distance(out.clearance)

    def _on_transition(self, before: FlightState, after: FlightState) -> None:
        if before is FlightState.LANDED and after is FlightState.TAKING_OFF:
            self._async(self._takeoff)
        elif after is FlightState.LANDING:
            self._async(lambda: self._report("land", self.link.land()))

    def _async(self, fn: Callable[[], None]) -> None:
        def run() -> None:
            with self._busy:
                try:
                    fn()
                except CommandFailed as err:
                    self.events.append(str(err))
        threading.Thread(target=run, daemon=True).start()

    def _report(self, what: str, result: int) -> bool:
        ok = result == mc.MAV_RESULT_ACCEPTED
        self.events.append(f"{what}: {'accepted' if ok else f'refused (MAV_RESULT {result})'}")
        return ok

    def _takeoff(self) -> None:
        link = self.link
        time.sleep(0.1)  # a few set-points on the wire before asking for offboard
        if not self._report("mode " + ("offboard" if link.flavour is mc.Autopilot.PX4 else "guided"), link.set_companion_mode()):
            return
        if not self._report("arm", link.arm(True)):
            return
        if link.flavour is mc.Autopilot.ARDUPILOT:
            self._report("takeoff", link.takeoff(self.hover_height_m))

    def telemetry(self) -> dict:
        s = self.link.status()
        return {
            "autopilot": s.autopilot, "armed": s.armed, "landed_state": s.landed_state,
            "heartbeat_age_s": None if s.heartbeat_age_s is None else round(s.heartbeat_age_s, 2),
            "messages_per_s": s.messages_per_s, "bad_packets": s.bad_packets, "foreign_packets": s.foreign_packets,
            "events": list(self.events),
        }

    def close(self) -> None:
        self.link.close()
