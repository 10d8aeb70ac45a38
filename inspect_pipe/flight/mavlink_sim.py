"""The simulator exposed as a MAVLink vehicle: a simulated PX4 (offboard) or ArduCopter (guided).

``inspect-pipe fly --scenario FILE --mavlink-sim udp:127.0.0.1:14540`` runs this in real time.
The MuJoCo quadrotor and its sensors are those of the scenario runner; in front of them sits what
an autopilot does for a companion computer:

* heartbeat (1 Hz), ATTITUDE, LOCAL_POSITION_NED, HIGHRES_IMU (50 Hz), every new DISTANCE_SENSOR
  and OPTICAL_FLOW_RAD reading, BATTERY_STATUS (2 Hz), EXTENDED_SYS_STATE (5 Hz). ATTITUDE is the
  autopilot's ESTIMATE (the simulated IMU's roll/pitch estimate with its error, its gyro-integrated
  heading, its gyro rates with their bias), HIGHRES_IMU the accelerometer's specific force and the
  gyro as measured: what a real autopilot streams, never the simulator's true attitude;
* COMMAND_LONG arm/disarm, take-off, land, set mode (acknowledged with COMMAND_ACK); TIMESYNC
  requests answered with the autopilot's boot clock;
* velocity set-points (SET_POSITION_TARGET_LOCAL_NED, velocity only) tracked by the autopilot's
  velocity controller in offboard/guided; older than ``setpoint_timeout_s`` the vehicle hovers
  (PX4: COM_OF_LOSS_T; ArduCopter: the guided-velocity timeout). PX4 refuses offboard unless
  set-points are already streaming.

The autopilot's velocity/height controller is the same PID design as the onboard stack's, fed the
autopilot's own state estimate (here the simulator's truth, as a well-tuned EKF would give; the
attitude it streams is its estimate, above).
A scenario ``link_loss`` fault drops every packet both ways while active.
"""

from __future__ import annotations

import json
import math
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Callable

import inspect_pipe
from inspect_pipe.flight import mavlink_codec as mc
from inspect_pipe.flight.battery import Battery
from inspect_pipe.flight.geometry import HoldGeometry
from inspect_pipe.flight.mavlink_endpoint import MavlinkEndpoint
from inspect_pipe.flight.runner import FLOOR_CRASH_M_S, ExitStatus, SimParts
from inspect_pipe.flight.scenario import VEHICLE_RADIUS_M, FaultKind, Scenario
from inspect_pipe.flight.sensors import SensorSuite
from inspect_pipe.flight.vehicle_sim import QuadrotorSim
from inspect_pipe.flight_stack.control import FlightController
from inspect_pipe.flight_stack.messages import HOVER, AttitudeSetpoint, EstimationMode, SpeedCommand, StateEstimate
from inspect_pipe.flight_stack.params import ControlParams

__all__ = ["AutopilotSpec", "SimulatedAutopilot", "SIM_LOG_FORMAT"]

SIM_LOG_FORMAT = "inspect_pipe.mavlink_sim_log/1"


@dataclass(frozen=True)
class AutopilotSpec:
    flavour: mc.Autopilot = mc.Autopilot.PX4
    system_id: int = 1
    tick_hz: float = 50.0
    setpoint_timeout_s: float = 0.25
    offboard_requires_stream_s: float = 0.5  # PX4: no offboard without set-points this recent
    land_speed_m_s: float = 0.5
    takeoff_speed_m_s: float = 0.5
    max_speed_m_s: float = 2.0


@dataclass
class AutopilotState:
    armed: bool = False
    custom_mode: int = 0
    setpoint: SpeedCommand = HOVER
    setpoint_rx_s: float | None = None
    takeoff_alt_m: float | None = None
    landing: bool = False
    touchdown_s: float | None = None
    rejected_setpoints: int = 0
    acks: list[tuple[int, int]] = field(default_factory=list)


class SimulatedAutopilot:
    """Step with :meth:`tick` (one control period) or run in real time with :meth:`run`."""

    def __init__(
        self,
        scenario: Scenario,
        url: str,
        *,
        spec: AutopilotSpec | None = None,
        parts: SimParts | None = None,
        clock: Callable[[], float] = time.monotonic,
        log: IO[str] | None = None,
    ) -> None:
        self.sc = scenario
        self.spec = spec or AutopilotSpec()
        self.parts = parts or SimParts()
        self.clock = clock
        self.log = log
        self.dt = 1.0 / self.spec.tick_hz
        self.substeps = max(1, round(self.parts.physics_hz / self.spec.tick_hz))
        v = scenario.vehicle
        self.sim = QuadrotorSim(scenario.world, v.start_position_m, v.start_yaw_rad, vehicle=self.parts.vehicle,
                                firmware=self.parts.firmware, physics_hz=self.substeps * self.spec.tick_hz, seed=scenario.seed)
        self.sensors = SensorSuite(self.parts.sensors, seed=scenario.seed)
        self.battery = Battery(v.battery)
        self.geometry = HoldGeometry(scenario.world)
        self.ctrl = FlightController(ControlParams())
        self.hover = ControlParams().hover_thrust_frac
        self.start = v.start_position_m
        self.ep = MavlinkEndpoint(url, system_id=self.spec.system_id, component_id=1,
                                  accept_heartbeat=lambda m: m.type != mc.MAV_TYPE_QUADROTOR)
        self.common = self.ep.common
        self.st = AutopilotState(custom_mode=self._initial_mode())
        self.t = 0.0  # simulated time
        self._prev_meas: dict[str, Any] = {}
        self._flow_sent: dict = {}  # per PX4Flow: its last reading's values and the frame sent for them
        self._next_hb = 0.0
        self._k = 0
        self._prev_vz = 0.0
        self.collided_at: float | None = None
        self.link_down = False
        if log is not None:
            h = scenario.world.hold
            log.write(json.dumps({
                "format": SIM_LOG_FORMAT, "scenario": scenario.name, "tick_hz": self.spec.tick_hz,
                "autopilot": self.spec.flavour.value, "url": url,
                "hold": {"length_m": h.length_m, "width_m": h.width_m, "height_m": h.height_m},
                "software_version": inspect_pipe.__version__,
            }) + "\n")

    # ------------------------------------------------------------------ modes
    def _initial_mode(self) -> int:
        if self.spec.flavour is mc.Autopilot.PX4:
            return mc.px4_custom_mode(mc.Px4Mode.POSCTL)
        return int(mc.ArduCopterMode.LOITER)

    @property
    def in_companion_mode(self) -> bool:
        """Offboard (PX4) or guided (ArduCopter): the companion's set-points are tracked."""
        if self.spec.flavour is mc.Autopilot.PX4:
            return mc.px4_main_mode(self.st.custom_mode) == mc.Px4Mode.OFFBOARD
        return self.st.custom_mode == mc.ArduCopterMode.GUIDED

    def mode_name(self) -> str:
        m = self.st.custom_mode
        if self.spec.flavour is mc.Autopilot.PX4:
            main, sub = mc.px4_main_mode(m), (m >> 24) & 0xFF
            name = mc.Px4Mode(main).name if main in mc.Px4Mode._value2member_map_ else str(main)
            return name + ({mc.PX4_AUTO_LAND: ".LAND", mc.PX4_AUTO_LOITER: ".LOITER", mc.PX4_AUTO_TAKEOFF: ".TAKEOFF"}.get(sub, "") if main == mc.Px4Mode.AUTO else "")
        return mc.ArduCopterMode(m).name if m in mc.ArduCopterMode._value2member_map_ else str(m)

    def _set_mode(self, base_mode: float, main: float, sub: float) -> int:
        if not (int(base_mode) & mc.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED):
            return mc.MAV_RESULT_UNSUPPORTED
        main_i, sub_i = int(main), int(sub)
        if self.spec.flavour is mc.Autopilot.PX4:
            if main_i not in (mc.Px4Mode.POSCTL, mc.Px4Mode.ALTCTL, mc.Px4Mode.OFFBOARD, mc.Px4Mode.AUTO):
                return mc.MAV_RESULT_UNSUPPORTED
            if main_i == mc.Px4Mode.OFFBOARD:
                rx = self.st.setpoint_rx_s
                if rx is None or self.t - rx > self.spec.offboard_requires_stream_s:
                    return mc.MAV_RESULT_TEMPORARILY_REJECTED
            self.st.custom_mode = mc.px4_custom_mode(main_i, sub_i if main_i == mc.Px4Mode.AUTO else 0)
            self.st.landing = main_i == mc.Px4Mode.AUTO and sub_i == mc.PX4_AUTO_LAND
        else:
            if main_i not in mc.ArduCopterMode._value2member_map_:
                return mc.MAV_RESULT_UNSUPPORTED
            self.st.custom_mode = main_i
            self.st.landing = main_i == mc.ArduCopterMode.LAND
        return mc.MAV_RESULT_ACCEPTED

    @property
    def on_ground(self) -> bool:
        return self.altitude_m < 0.03

    @property
    def altitude_m(self) -> float:
        return self.sim.position[2] - self.parts.vehicle.leg_height_m

    # ------------------------------------------------------------------ incoming
    def handle(self, m: Any) -> None:
        kind = m.get_type()
        sysid = self.spec.system_id
        if kind == "SET_POSITION_TARGET_LOCAL_NED":
            if m.target_system not in (0, sysid):
                return
            vals = (m.vx, m.vy, m.vz, m.yaw_rate)
            ok = (
                m.coordinate_frame == mc.MAV_FRAME_LOCAL_NED
                and (m.type_mask & 7) == 7  # position ignored: velocity control
                and not (m.type_mask & (8 | 16 | 32))
                and all(math.isfinite(v) for v in vals)
            )
            if not ok:
                self.st.rejected_setpoints += 1
                return
            lim = self.spec.max_speed_m_s
            vn, ve, vd = (max(-lim, min(lim, v)) for v in vals[:3])
            yaw_rate = 0.0 if m.type_mask & 2048 else max(-1.5, min(1.5, m.yaw_rate))
            _, _, yaw_w = self.sim.euler()
            self.st.setpoint = mc.speed_command_from_ned(vn, ve, vd, yaw_rate, -yaw_w)
            self.st.setpoint_rx_s = self.t
        elif kind == "COMMAND_LONG":
            if m.target_system not in (0, sysid):
                return
            result = self._command(m)
            self.st.acks.append((m.command, result))
            self.ep.send(self.common.MAVLink_command_ack_message(m.command, result, 0, 0, m.get_srcSystem(), m.get_srcComponent()))
        elif kind == "TIMESYNC":
            if m.tc1 == 0:  # a request: answer with the autopilot's boot clock, as PX4 and ArduPilot do
                self.ep.send(self.common.MAVLink_timesync_message(int(self.t * 1e9), m.ts1))
        elif kind == "SET_MODE":
            if m.target_system == sysid:
                self._set_mode(m.base_mode, (m.custom_mode >> 16) & 0xFF if self.spec.flavour is mc.Autopilot.PX4 else m.custom_mode,
                               (m.custom_mode >> 24) & 0xFF)

    def _command(self, m: Any) -> int:
        c, p = m.command, (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7)
        if any(isinstance(v, float) and math.isinf(v) for v in p):
            return mc.MAV_RESULT_DENIED
        st = self.st
        if c == mc.MAV_CMD_COMPONENT_ARM_DISARM:
            if p[0] >= 0.5:
                st.armed = True
                return mc.MAV_RESULT_ACCEPTED
            if self.on_ground or int(p[1]) == 21196:
                st.armed, st.landing, st.takeoff_alt_m = False, False, None
                return mc.MAV_RESULT_ACCEPTED
            return mc.MAV_RESULT_DENIED
        if c == mc.MAV_CMD_DO_SET_MODE:
            return self._set_mode(p[0], p[1], p[2])
        if c == mc.MAV_CMD_NAV_TAKEOFF:
            if not st.armed or not self.on_ground:
                return mc.MAV_RESULT_TEMPORARILY_REJECTED
            if self.spec.flavour is mc.Autopilot.ARDUPILOT and not self.in_companion_mode:
                return mc.MAV_RESULT_DENIED  # ArduCopter takes off on command only in guided
            alt = p[6] if math.isfinite(p[6]) and p[6] > 0 else 1.0
            st.takeoff_alt_m = min(alt, self.sc.max_height_m)
            if self.spec.flavour is mc.Autopilot.PX4:
                st.custom_mode = mc.px4_custom_mode(mc.Px4Mode.AUTO, mc.PX4_AUTO_TAKEOFF)
            return mc.MAV_RESULT_ACCEPTED
        if c == mc.MAV_CMD_NAV_LAND:
            if self.spec.flavour is mc.Autopilot.PX4:
                st.custom_mode = mc.px4_custom_mode(mc.Px4Mode.AUTO, mc.PX4_AUTO_LAND)
            else:
                st.custom_mode = int(mc.ArduCopterMode.LAND)
            st.landing, st.takeoff_alt_m = True, None
            return mc.MAV_RESULT_ACCEPTED
        if c in (mc.MAV_CMD_SET_MESSAGE_INTERVAL, 512):  # fixed rates here; REQUEST_MESSAGE
            return mc.MAV_RESULT_ACCEPTED
        return mc.MAV_RESULT_UNSUPPORTED

    # ------------------------------------------------------------------ one control period
    def _target(self) -> tuple[SpeedCommand, bool]:
        """The velocity the autopilot flies now, and whether the companion's set-point is fresh."""
        st = self.st
        fresh = st.setpoint_rx_s is not None and self.t - st.setpoint_rx_s <= self.spec.setpoint_timeout_s
        if st.landing:
            return SpeedCommand(0.0, 0.0, -self.spec.land_speed_m_s, 0.0), fresh
        if st.takeoff_alt_m is not None:
            if self.altitude_m >= st.takeoff_alt_m - 0.05:
                st.takeoff_alt_m = None
                if self.spec.flavour is mc.Autopilot.PX4:
                    st.custom_mode = mc.px4_custom_mode(mc.Px4Mode.AUTO, mc.PX4_AUTO_LOITER)
            else:
                # Slow down on the way to the target, as a position controller would.
                vz = min(self.spec.takeoff_speed_m_s, max(0.1, 1.2 * (st.takeoff_alt_m - self.altitude_m)))
                return SpeedCommand(0.0, 0.0, vz, 0.0), fresh
        if self.in_companion_mode and fresh:
            if self.spec.flavour is mc.Autopilot.ARDUPILOT and self.on_ground:
                return HOVER, fresh  # ArduCopter needs NAV_TAKEOFF to leave the ground in guided
            return st.setpoint, fresh
        return HOVER, fresh

    def tick(self) -> dict:
        """Advance one control period of simulated time; returns the log record."""
        sim, st, dt = self.sim, self.st, self.dt
        now = self.t
        self.link_down = any(f.kind is FaultKind.LINK_LOSS and f.active(now) for f in self.sc.faults)
        target, fresh = self._target()
        x, y, z = sim.position
        vx, vy, vz = sim.velocity
        yaw_w = sim.euler()[2]
        c, s = math.cos(yaw_w), math.sin(yaw_w)
        alt = z - self.parts.vehicle.leg_height_m
        est = StateEstimate(alt, alt, c * vx + s * vy, -s * vx + c * vy, vz, EstimationMode.BOTTOM)
        if not st.armed:
            sp = AttitudeSetpoint()
            self.ctrl.reset()
        elif self.on_ground and target.vz_m_s <= 0.0:
            if st.landing:
                st.touchdown_s = now if st.touchdown_s is None else st.touchdown_s
                if now - st.touchdown_s > 0.5 and abs(vz) < 0.1:
                    st.armed, st.landing, st.touchdown_s = False, False, None  # auto-disarm on touchdown
            sp = AttitudeSetpoint()  # idle on the ground
            self.ctrl.reset()
        else:
            sp = self.ctrl.update(target, est, dt, allow_height_hold=not st.landing and st.takeoff_alt_m is None)
        sim.set_setpoint(sp)

        meas = self.sensors.read(now, sim)
        if not self.link_down:
            self._send_telemetry(now, meas)

        dist = self.geometry.clearances(x, y, z)
        on_floor = z - self.parts.vehicle.leg_height_m < 0.02
        collided = self.geometry.wall_distance(x, y, z) < VEHICLE_RADIUS_M or (on_floor and self._prev_vz < -FLOOR_CRASH_M_S)
        self._prev_vz = vz
        if collided and self.collided_at is None:
            self.collided_at = now
        rec = {
            "t": round(now, 3), "pos_true": [round(x, 4), round(y, 4), round(z, 4)],
            "vel_true": [round(vx, 4), round(vy, 4), round(vz, 4)], "yaw_true": round(yaw_w, 4),
            "dist_true": {"front": round(dist.front, 4), "back": round(dist.back, 4), "left": round(dist.left, 4),
                          "right": round(dist.right, 4), "down": round(dist.down, 4)},
            "armed": st.armed, "mode": self.mode_name(), "landed_state": self.landed_state().name.lower(),
            "cmd": {"vx": round(target.vx_m_s, 4), "vy": round(target.vy_m_s, 4), "vz": round(target.vz_m_s, 4),
                    "yaw_rate": round(target.yaw_rate_rad_s, 4)},
            "setpoint_fresh": fresh, "link_ok": not self.link_down,
            "battery_percent": round(self.battery.percent, 2), "collided": collided,
            "bad_packets": self.ep.stats.bad_packets, "foreign_packets": self.ep.stats.foreign_packets,
            "rejected_setpoints": st.rejected_setpoints,
        }
        if self.log is not None:
            self.log.write(json.dumps(rec, separators=(",", ":")) + "\n")

        dropped = frozenset(f.sensor for f in self.sc.faults if f.kind is FaultKind.SENSOR_DROPOUT and f.active(now))
        sim.step(self.substeps, lambda q: self.sensors.sample(q, dropped))  # type: ignore[arg-type]
        self.battery.drain(dt, sim.thrust_n / (self.hover * self.parts.vehicle.max_thrust_n))
        self._k += 1
        self.t = self._k * dt
        return rec

    def landed_state(self) -> mc.LandedState:
        st = self.st
        if self.on_ground and not (st.armed and (self._target()[0].vz_m_s > 0)):
            return mc.LandedState.ON_GROUND
        if st.landing:
            return mc.LandedState.LANDING
        if st.takeoff_alt_m is not None:
            return mc.LandedState.TAKEOFF
        return mc.LandedState.IN_AIR

    def _send_telemetry(self, now: float, meas: Any) -> None:
        C, ep = self.common, self.ep
        if ep.peer is None:
            return
        ms = int(now * 1000)
        us = int(now * 1e6)
        if now >= self._next_hb:
            self._next_hb += 1.0
            st = self.st
            base = mc.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mc.MAV_MODE_FLAG_SAFETY_ARMED if st.armed else 0)
            ap = mc.MAV_AUTOPILOT_PX4 if self.spec.flavour is mc.Autopilot.PX4 else mc.MAV_AUTOPILOT_ARDUPILOTMEGA
            ep.send(C.MAVLink_heartbeat_message(mc.MAV_TYPE_QUADROTOR, ap, base, st.custom_mode,
                                                mc.MAV_STATE_ACTIVE if st.armed else mc.MAV_STATE_STANDBY, 3))
        if self._k % 10 == 0:
            ep.send(C.MAVLink_extended_sys_state_message(0, int(self.landed_state())))
        if self._k % 25 == 0:
            ep.send(C.MAVLink_battery_status_message(0, 0, 0, 32767, [3700 * 3] + [65535] * 9, -1, -1, -1,
                                                     int(round(self.battery.percent))))
        i = meas.imu  # None on the first tick only (no interval to average over yet)
        p = q = 0.0
        if i is not None:
            # The autopilot's attitude estimate and its gyro, as a real autopilot streams them:
            # body FLU (stack) -> FRD (MAVLink) negates y and z, world yaw -> NED yaw negates it.
            roll, pitch, yaw = mc.attitude_from_world(i.roll_rad, i.pitch_rad, i.yaw_rad or 0.0)
            p, q, r = i.p_rad_s, -i.q_rad_s, -i.r_rad_s
            ep.send(C.MAVLink_attitude_message(ms, roll, pitch, yaw, p, q, r))
            ep.send(C.MAVLink_highres_imu_message(us, i.fx_m_s2, -i.fy_m_s2, -i.fz_m_s2, p, q, r,
                                                  0, 0, 0, 0, 0, 0, 20.0, 0b111111))
        x, y, z = self.sim.position
        vx, vy, vz = self.sim.velocity
        x0, y0, _ = self.start
        ep.send(C.MAVLink_local_position_ned_message(ms, x - x0, -(y - y0), -self.altitude_m, vx, -vy, -vz))
        prev = self._prev_meas
        for slot, (sid, kind, orient, lo, hi) in mc.DISTANCE_SENSORS.items():
            reading = getattr(meas, slot.value)
            if reading is not None and reading is not prev.get(slot.value):
                ep.send(C.MAVLink_distance_sensor_message(ms, lo, hi, mc.range_to_cm(reading.range_m, hi), kind, sid, orient, 0))
            prev[slot.value] = reading
        for sid, name, sonar in ((0, "bottom_flow", meas.bottom_sonar), (1, "front_flow", meas.front_sonar)):
            f = getattr(meas, name)
            if f is None or f is prev.get(name):
                continue
            prev[name] = f
            a, b = (f.vx_m_s, f.vy_m_s) if sid == 0 else (f.vy_m_s, f.vz_m_s)
            rates = (f.rate_x_rad_s, f.rate_y_rad_s) if sid == 0 else (f.rate_y_rad_s, f.rate_z_rad_s)
            d = (sonar.range_m if sonar is not None and sonar.range_m else 1.0) if f.scaled else None
            # The gyro fields carry what was subtracted (the receiver takes it out again); the
            # unit's own compensation error is already in the metric flow. Without its sonar's
            # range the unit sends its angular flow with distance -1. A stuck unit repeats its
            # whole frame, gyro fields included, so a repeated reading sends the same bytes.
            key = (a, b, rates, f.quality, f.scaled, d)
            last = self._flow_sent.get(name)
            if last is not None and last[0] == key:
                fr = last[1]
            else:
                fr = mc.flow_to_rad(a, b, f.quality, d, 1.0 / self.parts.sensors.flow.rate_hz, p, q,
                                    rates if None not in rates else None)
                self._flow_sent[name] = (key, fr)
            ep.send(C.MAVLink_optical_flow_rad_message(us, sid, fr.integration_time_us, fr.integrated_x, fr.integrated_y,
                                                       fr.integrated_xgyro, fr.integrated_ygyro, 0.0, 2000, fr.quality, 0, fr.distance_m))

    # ------------------------------------------------------------------ real time
    def poll(self, timeout_s: float) -> None:
        """Receive and handle what arrives within ``timeout_s``."""
        for m in self.ep.recv(timeout_s):
            if not self.link_down:
                self.handle(m)

    def run(self, *, duration_s: float | None = None, stop: threading.Event | None = None,
            stop_on_collision: bool = True) -> ExitStatus:
        """Real time: one tick per period, listening in between. Ends after ``duration_s``."""
        duration = self.sc.duration_s if duration_s is None else duration_s
        t0 = self.clock()
        while self.t <= duration and not (stop is not None and stop.is_set()):
            self.tick()
            if self.collided_at is not None and stop_on_collision:
                break
            deadline = t0 + self.t
            while True:
                left = deadline - self.clock()
                if left <= 0:
                    break
                self.poll(min(left, 0.02))
            if self.clock() - deadline > 0.5:  # far behind (a stalled machine): don't race to catch up
                t0 = self.clock() - self.t
        return ExitStatus.COLLISION if self.collided_at is not None else ExitStatus.COMPLETED

    def close(self) -> None:
        self.ep.close()


def open_sim_log(path: Path | None) -> IO[str] | None:
    if path is None:
        return None
    path.parent.mkdir(parents=True, exist_ok=True)
    return path.open("w", buffering=1)
