"""Scenario runner: the simulated vehicle, its sensors, battery and operator link around the
onboard stack, stepped together on one simulated clock, faster than real time."""

from __future__ import annotations

import dataclasses
import enum
import time
from dataclasses import dataclass
from typing import Callable

from inspect_pipe.flight.battery import Battery
from inspect_pipe.flight.geometry import Clearances, HoldGeometry
from inspect_pipe.flight.operator_link import LinkSpec, OperatorLink
from inspect_pipe.flight.scenario import VEHICLE_RADIUS_M, FaultKind, Scenario
from inspect_pipe.flight.sensors import NO_FAULTS, SensorFaults, SensorSpecs, SensorSuite
from inspect_pipe.flight.vehicle_sim import AttitudeFirmware, QuadrotorSim, VehicleModel
from inspect_pipe.flight_stack.flight_machine import FlightState
from inspect_pipe.flight_stack.messages import ImuReading, message
from inspect_pipe.flight_stack.onboard import OnboardStack, TickOutput
from inspect_pipe.flight_stack.params import StackParams

__all__ = ["ExitStatus", "FlightResult", "SimParts", "TickRecord", "run_scenario"]


FLOOR_CRASH_M_S = 1.0  # touching the floor faster than this is a collision, not a landing
VIBRATION_FULL_M_S2 = 3.0  # a vibration fault of rate 1 (std of the IMU's 50 Hz mean; PX4 flags raw vibration above 30 m/s^2)


class ExitStatus(str, enum.Enum):
    COMPLETED = "completed"  # the scenario's duration elapsed without a collision
    COLLISION = "collision"


@message
class TickRecord:
    """One control tick: ground truth and what the onboard stack saw and did."""

    t: float
    pos_true: tuple[float, float, float]
    vel_true: tuple[float, float, float]
    yaw_true: float
    out: TickOutput
    dist_true: Clearances
    battery_percent: float
    link_ok: bool
    collided: bool
    rpy_true: tuple[float, float, float] = (0.0, 0.0, 0.0)  # roll, pitch, yaw (ZYX); the camera's attitude
    side_true: float | None = None  # distance to the nearest wall or box side (HoldGeometry.side_distance)
    imu: ImuReading | None = None  # what the autopilot's IMU and attitude estimate gave the stack this tick


@dataclass(frozen=True)
class FlightResult:
    status: ExitStatus
    final_fsm: FlightState
    sim_time_s: float
    wall_time_s: float
    ticks: int
    tick_seconds: tuple[float, ...]  # onboard stack compute time per tick
    collided_at_s: float | None = None

    @property
    def speed_x_real_time(self) -> float:
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else float("inf")


@dataclass(frozen=True)
class SimParts:
    """What the simulator is made of; defaults are the embedded simulator."""

    vehicle: VehicleModel = VehicleModel()
    firmware: AttitudeFirmware = AttitudeFirmware()
    sensors: SensorSpecs = SensorSpecs()
    link: LinkSpec = LinkSpec()
    physics_hz: float = 200.0


def stack_params_for(scenario: Scenario, params: StackParams | None = None) -> StackParams:
    params = params or StackParams()
    return params.replace(behaviors=dataclasses.replace(params.behaviors, max_height_m=scenario.max_height_m))


def _sensor_faults(active: list) -> SensorFaults:
    """The sensor faults among the scenario's ``active`` faults."""
    if not active:
        return NO_FAULTS
    K = FaultKind
    return SensorFaults(
        packet_loss={f.sensor: f.rate for f in active if f.kind is K.PACKET_LOSS},
        stuck=frozenset(f.sensor for f in active if f.kind is K.STUCK_READING),
        spurious_max_range={f.sensor: f.rate for f in active if f.kind is K.SPURIOUS_MAX_RANGE},
        range_loss=any(f.kind is K.RANGE_LOSS for f in active),
        flow_quality_zero=frozenset(f.sensor for f in active if f.kind is K.FLOW_QUALITY_ZERO),
        low_texture={f.sensor: f.rate for f in active if f.kind is K.LOW_TEXTURE},
        vibration_m_s2=VIBRATION_FULL_M_S2 * sum(f.rate for f in active if f.kind is K.VIBRATION),
    )


def run_scenario(
    scenario: Scenario,
    *,
    params: StackParams | None = None,
    parts: SimParts | None = None,
    on_tick: Callable[[TickRecord], None] | None = None,
    stop_on_collision: bool = True,
    make_stack: Callable[[StackParams], OnboardStack] = OnboardStack,
) -> FlightResult:
    """Fly ``scenario``; ``on_tick`` receives every :class:`TickRecord` (e.g. a log writer).

    ``make_stack`` builds the onboard stack from its parameters (the safety campaign passes
    stacks whose behaviour arbitration is replaced by a baseline shield)."""
    parts = parts or SimParts()
    v = scenario.vehicle
    if v.mass_scale != 1.0 or v.thrust_scale != 1.0:  # model error: the stack keeps its nominal hover thrust
        veh = parts.vehicle
        parts = dataclasses.replace(parts, vehicle=dataclasses.replace(
            veh, mass_kg=veh.mass_kg * v.mass_scale,
            thrust_to_weight=veh.thrust_to_weight * v.thrust_scale / v.mass_scale,
        ))
    stack = make_stack(stack_params_for(scenario, params))
    tick_hz = stack.params.control.tick_hz
    substeps = max(1, round(parts.physics_hz / tick_hz))
    physics_hz = substeps * tick_hz
    sim = QuadrotorSim(
        scenario.world, v.start_position_m, v.start_yaw_rad, vehicle=parts.vehicle, firmware=parts.firmware,
        physics_hz=physics_hz, seed=scenario.seed,
    )
    sensors = SensorSuite(parts.sensors, seed=scenario.seed)
    link = OperatorLink(scenario.operator, scenario.faults, parts.link)
    battery = Battery(v.battery)
    geometry = HoldGeometry(scenario.world)
    dropouts = [f for f in scenario.faults if f.kind is FaultKind.SENSOR_DROPOUT]
    sensor_faults = [f for f in scenario.faults if f.kind not in (FaultKind.SENSOR_DROPOUT, FaultKind.LINK_LOSS)]
    sags = [f for f in scenario.faults if f.kind is FaultKind.BATTERY_SAG]
    weak = [f for f in scenario.faults if f.kind is FaultKind.WEAK_MOTOR]
    gusts = [f for f in scenario.faults if f.kind is FaultKind.GUST]
    hover_thrust_n = stack.params.control.hover_thrust_frac * parts.vehicle.max_thrust_n
    leg_height = parts.vehicle.leg_height_m
    no_dropouts: frozenset = frozenset()
    active_faults: list | None = None
    sampler = faults = None

    n_ticks = int(round(scenario.duration_s * tick_hz))
    tick_dt = 1.0 / tick_hz
    tick_seconds: list[float] = []
    status, collided_at = ExitStatus.COMPLETED, None
    wall0 = time.perf_counter()
    k = 0
    prev_vz = 0.0
    for k in range(n_ticks + 1):
        now = k * tick_dt
        link.advance(now)
        operator = link.receive(now)
        meas = sensors.read(now, sim)
        sag = sum(f.rate for f in sags if f.active(now)) if sags else 0  # type: ignore[misc]
        battery_reading = max(0.0, battery.percent - 100.0 * sag)  # voltage sag reads as charge lost
        c0 = time.perf_counter()
        out = stack.tick(now, meas, operator, battery_reading)
        tick_seconds.append(time.perf_counter() - c0)
        sim.set_setpoint(out.setpoint)

        x, y, z = sim.position
        dist = geometry.clearances(x, y, z)
        # A wall or a box's side inside the 0.35 m sphere is a collision; the floor, or the top of a
        # box straight below, only when hit hard (a touchdown faster than a landing gear takes),
        # since landing is touching them.
        vel = sim.velocity
        vz_true = vel[2]
        on_floor = dist.down - leg_height < 0.02
        side = geometry.side_distance(x, y, z)
        collided = side < VEHICLE_RADIUS_M or (on_floor and prev_vz < -FLOOR_CRASH_M_S)
        prev_vz = vz_true
        if on_tick is not None:
            rpy = sim.euler()
            on_tick(
                TickRecord(
                    t=now, pos_true=(x, y, z), vel_true=vel, yaw_true=rpy[2], out=out,
                    dist_true=dist, battery_percent=battery.percent, link_ok=operator.link_ok, collided=collided,
                    rpy_true=rpy, side_true=side, imu=meas.imu,
                )
            )
        if collided and collided_at is None:
            status, collided_at = ExitStatus.COLLISION, now
            if stop_on_collision:
                break
        if k == n_ticks:
            break
        dropped = frozenset(f.sensor for f in dropouts if f.active(now)) if dropouts else no_dropouts  # type: ignore[misc]
        if sensor_faults:
            sim.thrust_available = max(0.0, 1.0 - sag)
            if weak:
                sim.motor_health[0] = max(0.0, 1.0 - sum(f.rate for f in weak if f.active(now)))  # type: ignore[misc]
            wind = [0.0, 0.0, 0.0]
            for f in gusts:
                if f.active(now):
                    wind = [w + g for w, g in zip(wind, f.wind_m_s)]  # type: ignore[arg-type]
            sim.wind_m_s = tuple(wind)  # type: ignore[assignment]
            active = [f for f in scenario.faults if f.active(now)]
            if active != active_faults:  # the faults of the last tick still hold otherwise
                active_faults, faults = active, _sensor_faults(active)
        else:
            faults = NO_FAULTS
        if sampler is None or sampler.dropped != dropped or sampler.faults is not faults:
            sampler = sensors.sampler(dropped, faults)
        sim.step(substeps, sampler)
        battery.drain(tick_dt, sim.thrust_n / hover_thrust_n)
    return FlightResult(
        status=status,
        final_fsm=stack.fsm,
        sim_time_s=k * tick_dt,
        wall_time_s=time.perf_counter() - wall0,
        ticks=k + 1,
        tick_seconds=tuple(tick_seconds),
        collided_at_s=collided_at,
    )


