"""Real-time flight: the unchanged onboard stack ticked on the wall clock, with the operator's
input from the base station (or a scenario script) and a vehicle behind it: the embedded
simulator (:class:`SimPlant`) or an autopilot over MAVLink (``mavlink_vehicle.MavlinkPlant``)."""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable, Protocol

from inspect_pipe.flight.battery import Battery
from inspect_pipe.flight.geometry import HoldGeometry
from inspect_pipe.flight.operator_link import LinkSpec, OperatorLink
from inspect_pipe.flight.runner import FLOOR_CRASH_M_S, SimParts, stack_params_for
from inspect_pipe.flight.scenario import VEHICLE_RADIUS_M, FaultKind, Scenario
from inspect_pipe.flight.sensors import SensorSuite
from inspect_pipe.flight.vehicle_sim import QuadrotorSim
from inspect_pipe.flight_stack.flight_machine import FlightState
from inspect_pipe.flight_stack.messages import HOVER, Button, Measurements, OperatorInput, SpeedCommand
from inspect_pipe.flight_stack.onboard import OnboardStack, TickOutput
from inspect_pipe.flight_stack.params import StackParams

__all__ = ["OperatorInbox", "Plant", "RealTimeFlight", "ScriptedOperator", "SimPlant", "feedback"]


class Plant(Protocol):
    """The vehicle behind the onboard stack."""

    def now(self) -> float: ...
    def measurements(self, now: float) -> Measurements: ...
    @property
    def battery_percent(self) -> float: ...
    def apply(self, out: TickOutput, now: float) -> None: ...
    def telemetry(self) -> dict: ...
    def vehicle_ok(self) -> bool: ...


class OperatorSource(Protocol):
    def receive(self, now: float) -> OperatorInput: ...


# --------------------------------------------------------------------------- operator input


@dataclass(frozen=True, slots=True)
class StickStamp:
    """When the page produced a stick message (wall clock, s) and on which monotonic time it
    arrived, for the key-press-to-set-point latency."""

    client_wall_s: float | None
    rx_mono_s: float


class OperatorInbox:
    """Base station -> onboard: the last stick and buttons pressed since the last tick.

    Thread-safe. Onboard the link is OK while the last message is younger than ``timeout_s``
    (the stack's ``waiting_for_connectivity`` hovers otherwise), exactly as over WiFi.
    """

    def __init__(self, *, timeout_s: float = LinkSpec().timeout_s, clock: Callable[[], float] = time.monotonic) -> None:
        self.timeout_s = timeout_s
        self.clock = clock
        self._lock = threading.Lock()
        self._stick = HOVER
        self._buttons: set[Button] = set()
        self._last_rx: float | None = None
        self._stamp: StickStamp | None = None
        self.consumed: StickStamp | None = None  # the stamp the last receive() took up

    def put_stick(self, stick: SpeedCommand, client_wall_s: float | None = None) -> None:
        now = self.clock()
        with self._lock:
            self._stick = stick
            self._last_rx = now
            self._stamp = StickStamp(client_wall_s, now)

    def press(self, button: Button) -> None:
        with self._lock:
            self._buttons.add(button)
            self._last_rx = self.clock()

    def receive(self, now: float | None = None) -> OperatorInput:
        """``now`` is ignored: arrival times are on this inbox's own clock."""
        now = self.clock()
        with self._lock:
            ok = self._last_rx is not None and now - self._last_rx <= self.timeout_s
            buttons = frozenset(self._buttons) if ok else frozenset()
            self._buttons.clear()
            self.consumed, self._stamp = self._stamp, None
            return OperatorInput(stick=self._stick if ok else HOVER, buttons=buttons, link_ok=ok)


class ScriptedOperator:
    """A scenario's operator events, on the flight's clock (for ``fly --vehicle mavlink:``)."""

    def __init__(self, scenario: Scenario) -> None:
        self.link = OperatorLink(scenario.operator, scenario.faults, LinkSpec())
        self.consumed = None
        self._t0: float | None = None

    def receive(self, now: float) -> OperatorInput:
        if self._t0 is None:
            self._t0 = now
        t = now - self._t0
        self.link.advance(t)
        return self.link.receive(t)


# --------------------------------------------------------------------------- embedded simulator


class SimPlant:
    """The scenario's simulated vehicle stepped one control period per tick (real time when the
    loop is paced by the wall clock). Operator events and link-loss faults of the scenario are
    ignored: the operator is the base station."""

    def __init__(self, scenario: Scenario, *, parts: SimParts | None = None, tick_hz: float = 50.0) -> None:
        self.sc = scenario
        self.parts = parts or SimParts()
        self.substeps = max(1, round(self.parts.physics_hz / tick_hz))
        self.dt = 1.0 / tick_hz
        v = scenario.vehicle
        self.sim = QuadrotorSim(scenario.world, v.start_position_m, v.start_yaw_rad, vehicle=self.parts.vehicle,
                                firmware=self.parts.firmware, physics_hz=self.substeps * tick_hz, seed=scenario.seed)
        self.sensors = SensorSuite(self.parts.sensors, seed=scenario.seed)
        self.battery = Battery(v.battery)
        self.geometry = HoldGeometry(scenario.world)
        self.hover = StackParams().control.hover_thrust_frac
        self.t = 0.0
        self.collided = False
        self.collisions = 0
        self._prev_vz = 0.0
        self.dropouts = [f for f in scenario.faults if f.kind is FaultKind.SENSOR_DROPOUT]

    def now(self) -> float:
        """Simulated time: the clock the sensors stamp with."""
        return self.t

    def measurements(self, now: float) -> Measurements:
        return self.sensors.read(self.t, self.sim)

    @property
    def battery_percent(self) -> float:
        return self.battery.percent

    def vehicle_ok(self) -> bool:
        return True

    def apply(self, out: TickOutput, now: float) -> None:
        sim = self.sim
        sim.set_setpoint(out.setpoint)
        dropped = frozenset(f.sensor for f in self.dropouts if f.active(self.t))
        sim.step(self.substeps, lambda s: self.sensors.sample(s, dropped))  # type: ignore[arg-type]
        self.battery.drain(self.dt, sim.thrust_n / (self.hover * self.parts.vehicle.max_thrust_n))
        self.t += self.dt
        x, y, z = sim.position
        vz = sim.velocity[2]
        on_floor = z - self.parts.vehicle.leg_height_m < 0.02
        hit = self.geometry.wall_distance(x, y, z) < VEHICLE_RADIUS_M or (on_floor and self._prev_vz < -FLOOR_CRASH_M_S)
        self._prev_vz = vz
        if hit and not self.collided:
            self.collisions += 1
        self.collided = hit

    def telemetry(self) -> dict:
        x, y, z = self.sim.position
        d = self.geometry.clearances(x, y, z)
        return {
            "vehicle": "simulator", "pos_true": [round(x, 3), round(y, 3), round(z, 3)],
            "yaw_true": round(self.sim.euler()[2], 3), "dist_true_front": round(d.front, 3),
            "collided": self.collided, "collisions": self.collisions,
        }

    def pose(self) -> tuple[tuple[float, float, float], float]:
        return self.sim.position, self.sim.euler()[2]


# --------------------------------------------------------------------------- plain-language feedback


def feedback(out: TickOutput, link_ok: bool) -> list[str]:
    """What the surveyor reads under the numbers: why the vehicle does what it does."""
    msgs: list[str] = []
    e, c, b = out.estimate, out.clearance, set(out.behaviors)
    if not link_ok and out.fsm is not FlightState.LANDED:
        msgs.append("link lost: hovering (waiting_for_connectivity)")
    if e.mode < 0 and out.fsm is not FlightState.LANDED:
        msgs.append(f"alarm mode {int(e.mode)}: descending" + (" (no height reference)" if e.mode == -2 else ""))
    u, k = out.user_cmd, out.command
    for axis, user, cmd, pos_name, neg_name in (
        ("x", u.vx_m_s, k.vx_m_s, "front", None), ("y", u.vy_m_s, k.vy_m_s, "left", "right"),
    ):
        if abs(user) > 0.02 and abs(cmd) < abs(user) - 0.02 and ("attenuated_go" in b or "prevent_collision" in b or "attenuated_inspect" in b):
            side = pos_name if user > 0 else neg_name
            d = getattr(c, f"{side}_m", None) if side else None
            where = f"wall at {d:.1f} m" if d is not None else "obstacle ahead"
            msgs.append(f"speed attenuated: {where}" if abs(cmd) > 0.02 else f"stopped at the stop line: {where}")
    if "prevent_collision" in b and any(
        v is not None and v < 0.95 for v in (c.front_m, c.left_m, c.right_m)
    ):
        msgs.append("too close: backing off")
    if "limit_max_height" in b:
        msgs.append("maximum height: climbing stopped")
    if "ensure_reference_surface_detection" in b:
        msgs.append("no reference surface in range: keeping close")
    if "low_battery_land" in b:
        msgs.append("battery low: landing")
    if "go_ahead" in b or "inspect_ahead" in b:
        msgs.append(("inspect ahead" if out.inspection_mode else "go ahead") + ": holding the last speed")
    if out.fsm is FlightState.DESCENDING:
        msgs.append("descending to land")
    return msgs


def _r(v: float | None, nd: int = 3) -> float | None:
    return None if v is None or not math.isfinite(v) else round(v, nd)


def snapshot(out: TickOutput, now: float, op: OperatorInput, battery: float) -> dict:
    e, c = out.estimate, out.clearance
    cmd = lambda s: {"vx": _r(s.vx_m_s), "vy": _r(s.vy_m_s), "vz": _r(s.vz_m_s), "yaw_rate": _r(s.yaw_rate_rad_s)}  # noqa: E731
    return {
        "t": round(now, 3), "fsm": out.fsm.value, "est_mode": int(e.mode),
        "height": _r(e.height_m), "altitude": _r(e.altitude_m), "vx": _r(e.vx_m_s), "vy": _r(e.vy_m_s), "vz": _r(e.vz_m_s),
        "dist": {"front": _r(c.front_m), "left": _r(c.left_m), "right": _r(c.right_m), "down": _r(c.down_m)},
        "user_cmd": cmd(out.user_cmd), "cmd": cmd(out.command), "behaviors": list(out.behaviors),
        "inspection_mode": out.inspection_mode, "battery_percent": _r(battery, 1), "link_ok": op.link_ok,
        "feedback": feedback(out, op.link_ok),
    }


# --------------------------------------------------------------------------- the loop


class RealTimeFlight:
    """Tick the onboard stack at its rate on ``clock``; ``state`` is the latest snapshot."""

    def __init__(self, plant: Any, operator: Any, *, scenario: Scenario | None = None, params: StackParams | None = None,
                 clock: Callable[[], float] = time.monotonic, on_tick: Callable[[TickOutput, dict], None] | None = None) -> None:
        params = stack_params_for(scenario, params) if scenario is not None else (params or StackParams())
        self.stack = OnboardStack(params)
        self.plant = plant
        self.operator = operator
        self.clock = clock
        self.on_tick = on_tick
        self.tick_dt = 1.0 / self.stack.params.control.tick_hz
        self.state: dict = {}
        self.latencies_s: deque[float] = deque(maxlen=5000)
        self.tick_late_s: deque[float] = deque(maxlen=5000)
        self.ticks = 0
        self._lock = threading.Lock()

    def tick(self, now: float) -> TickOutput:
        op = self.operator.receive(now)
        stamp = getattr(self.operator, "consumed", None)
        out = self.stack.tick(now, self.plant.measurements(now), op, self.plant.battery_percent)
        self.plant.apply(out, now)  # the set-point leaves here
        if stamp is not None and stamp.client_wall_s is not None:
            self.latencies_s.append(time.time() - stamp.client_wall_s)
        snap = snapshot(out, now, op, self.plant.battery_percent)
        snap["vehicle"] = self.plant.telemetry()
        snap["vehicle_ok"] = self.plant.vehicle_ok()
        with self._lock:
            self.state = snap
        self.ticks += 1
        if self.on_tick is not None:
            self.on_tick(out, snap)
        return out

    def snapshot(self) -> dict:
        with self._lock:
            return self.state

    def run(self, stop: threading.Event, duration_s: float | None = None) -> None:
        """Until ``stop`` is set (or ``duration_s`` of flight). Ticks are paced by deadlines; a
        tick that comes late is not repeated (real time, not catch-up)."""
        t0 = self.clock()
        k = 0
        while not stop.is_set():
            if duration_s is not None and k * self.tick_dt > duration_s:
                break
            self.tick(self.plant.now())
            k += 1
            deadline = t0 + k * self.tick_dt
            late = self.clock() - deadline
            if late > 0:
                self.tick_late_s.append(late)
                if late > 0.25:  # stalled: re-anchor rather than burst
                    t0 += late
            else:
                stop.wait(-late)
