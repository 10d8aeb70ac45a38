"""Baseline shields: PX4- and ArduPilot-style avoidance as drop-in replacements of the stack's
behaviour arbitration (``MAVBehaviors``), on the same estimator, flight machine, controllers,
sensors and operator scripts.

Both are re-derived from their public documentation, not translated from code:

* **px4_like** (PX4 user guide, *Collision Prevention*; parameters ``CP_DIST``, ``CP_DELAY``,
  ``CP_GUIDE_ANG``, ``CP_GO_NO_DATA``, ``MPC_XY_CRUISE``, ``MPC_ACC_HOR``, ``MPC_JERK_MAX``,
  ``COM_RC_LOSS_T``): the setpoint's speed towards each sensed sector is limited by a
  quadratic scaling towards the keep distance ``CP_DIST`` and by the jerk/acceleration-limited
  speed that can still stop before it, after removing the distance travelled during the sensor
  and tracking delay ``CP_DELAY``. The whole setpoint vector is shortened (no sliding), and its
  direction may turn by up to ``CP_GUIDE_ANG`` towards a freer one. A sector without data
  younger than 0.5 s blocks motion into it (``CP_GO_NO_DATA`` = 0, the default: with no rear
  sensor the vehicle cannot fly backwards); after 5 s without any range data the vehicle holds.
* **ardupilot_like** (ArduPilot Copter wiki, *Simple Object Avoidance*; ``AVOID_BEHAVE`` = slide,
  ``AVOID_MARGIN``, ``AVOID_ACCEL_MAX``, ``AVOID_BACKUP_SPD``, ``AVOID_BACKUP_DZ``,
  ``AVOID_DIST_MAX``, ``RC_FS_TIMEOUT``): only the velocity component towards an obstacle is
  limited, by a square-root braking law at 1 m/s^2 to stop at the margin (the vehicle slides
  along walls); inside the margin by more than the 0.1 m dead zone it backs away at up to
  0.75 m/s; while the proximity sensor is unhealthy (a rangefinder silent for 0.5 s) avoidance
  does nothing at all.

Both keep the stack's viability behaviour (``low_battery_land``) and have no inspection mode.
On link loss each keeps the last stick until its radio-failsafe time-out, then PX4 holds and
ArduPilot lands (its RTL needs a position it does not have in a hold).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

from inspect_pipe.campaign._avoid_math import jerk_limited_max_speed_m_s, quadratic_scale, sqrt_brake_speed_m_s
from inspect_pipe.flight_stack.behaviors import BehaviorsOutput, LowBatteryLand
from inspect_pipe.flight_stack.messages import (
    HOVER,
    BehaviorInputs,
    Clearance,
    Measurements,
    OperatorInput,
    RangeReading,
    SpeedCommand,
    StateEstimate,
)
from inspect_pipe.flight_stack.onboard import OnboardStack
from inspect_pipe.flight_stack.params import BehaviorParams, StackParams

__all__ = [
    "ArduPilotLikeParams",
    "ArduPilotLikeShield",
    "Px4LikeParams",
    "Px4LikeShield",
    "SHIELDS",
    "SectorReading",
    "ShieldedStack",
    "make_stack",
]

# Sectors in the heading frame: unit direction (x, y) and the sonar that sees it (None: no sensor).
_SECTORS: tuple[tuple[str, tuple[float, float], str | None], ...] = (
    ("front", (1.0, 0.0), "front_sonar"),
    ("left", (0.0, 1.0), "left_sonar"),
    ("right", (0.0, -1.0), "right_sonar"),
    ("back", (-1.0, 0.0), None),
)


@dataclass(frozen=True, slots=True)
class SectorReading:
    """What one sector's range sensor says at ``now``: ``distance_m`` (inf: no echo within
    range), the reading's age (inf: never delivered)."""

    distance_m: float
    age_s: float


def _sector(r: RangeReading | None, now: float, max_range_m: float) -> SectorReading:
    if r is None:
        return SectorReading(math.inf, math.inf)
    d = math.inf if r.range_m is None or r.range_m >= max_range_m else r.range_m
    return SectorReading(d, now - r.stamp_s)


@dataclass(frozen=True)
class Px4LikeParams:
    cp_dist_m: float = 1.0  # CP_DIST: keep distance (same stop line as ours)
    cp_delay_s: float = 0.4  # CP_DELAY: sensor + tracking delay (default 0.4 s)
    cp_guide_ang_deg: float = 30.0  # CP_GUIDE_ANG (default 30 deg)
    xy_cruise_m_s: float = 1.0  # MPC_XY_CRUISE, here the stick's full scale
    acc_hor_m_s2: float = 1.2  # MPC_ACC_HOR: braking acceleration (our airframe's braking)
    jerk_max_m_s3: float = 8.0  # MPC_JERK_MAX
    scale_band_m: float = 2.0  # quadratic scaling starts this far beyond CP_DIST
    data_timeout_s: float = 0.5  # older sector data counts as no data
    hold_timeout_s: float = 5.0  # no range data at all for this long: hold
    sensor_range_m: float = 5.0  # HRLV-EZ4 maximum range
    rc_loss_timeout_s: float = 0.5  # COM_RC_LOSS_T


@dataclass(frozen=True)
class ArduPilotLikeParams:
    margin_m: float = 1.0  # AVOID_MARGIN (same stop line as ours)
    accel_max_m_s2: float = 1.0  # AVOID_ACCEL_MAX
    backup_speed_m_s: float = 0.75  # AVOID_BACKUP_SPD
    backup_deadzone_m: float = 0.1  # AVOID_BACKUP_DZ
    backup_gain_1_s: float = 1.5  # back-away speed per metre of breach beyond the dead zone
    dist_max_m: float = 5.0  # AVOID_DIST_MAX: farther objects are ignored
    unhealthy_after_s: float = 0.5  # a rangefinder silent this long makes the proximity unhealthy
    rc_failsafe_timeout_s: float = 1.0  # RC_FS_TIMEOUT


class _BaselineShield:
    """What the baselines share: the link-loss failsafe, low battery, sector readings."""

    name = "baseline"

    def __init__(self, behavior_params: BehaviorParams, rc_timeout_s: float) -> None:
        self.bp = behavior_params
        self.inspection_mode = False  # the autopilots have no inspection mode
        self.low_battery_land = LowBatteryLand(behavior_params)
        self.rc_timeout_s = rc_timeout_s
        self.measurements = Measurements()
        self._last_stick = HOVER
        self._last_link_ok_s: float | None = None

    def observe(self, now_s: float, measurements: Measurements) -> None:
        self.measurements = measurements

    def sectors(self, now_s: float, max_range_m: float) -> dict[str, SectorReading | None]:
        m = self.measurements
        return {
            name: (None if sensor is None else _sector(getattr(m, sensor), now_s, max_range_m))
            for name, _, sensor in _SECTORS
        }

    def _stick(self, now_s: float, operator: OperatorInput) -> tuple[SpeedCommand, bool]:
        """The stick the autopilot acts on, and whether its radio failsafe has triggered.

        The link layer reports loss 0.25 s after the last message; until the autopilot's own
        time-out the last stick is kept."""
        if operator.link_ok:
            self._last_stick, self._last_link_ok_s = operator.stick, now_s
            return operator.stick, False
        if self._last_link_ok_s is None:
            return HOVER, False
        lost_for = now_s - self._last_link_ok_s + 0.25
        if lost_for < self.rc_timeout_s:
            return self._last_stick, False
        return HOVER, True

    def _inputs(self, now_s, estimate, clearance, operator, battery_percent, flying) -> BehaviorInputs:
        return BehaviorInputs(
            now_s=now_s, estimate=estimate, clearance=clearance, stick=operator.stick, link_ok=operator.link_ok,
            inspection_mode=False, go_ahead_pressed=False, battery_percent=battery_percent, flying=flying,
        )

    def limit(self, now_s: float, stick: SpeedCommand, estimate: StateEstimate, dt: float) -> tuple[SpeedCommand, tuple[str, ...]]:
        raise NotImplementedError

    def update(
        self,
        now_s: float,
        estimate: StateEstimate,
        clearance: Clearance,
        operator: OperatorInput,
        *,
        battery_percent: float,
        flying: bool,
        dt: float,
    ) -> BehaviorsOutput:
        stick, failsafe = self._stick(now_s, operator)
        names: list[str] = []
        p = self.bp
        stick = SpeedCommand(
            max(-p.max_speed_m_s, min(p.max_speed_m_s, stick.vx_m_s)),
            max(-p.max_speed_m_s, min(p.max_speed_m_s, stick.vy_m_s)),
            max(-p.max_vertical_speed_m_s, min(p.max_vertical_speed_m_s, stick.vz_m_s)),
            stick.yaw_rate_rad_s,
        )
        land = False
        if failsafe:
            names.append(self.failsafe_name)
            land = self.failsafe_lands
            cmd = HOVER
        elif flying:
            cmd, who = self.limit(now_s, stick, estimate, dt)
            names.extend(who)
        else:
            cmd = stick
        viable = self.low_battery_land.viable(self._inputs(now_s, estimate, clearance, operator, battery_percent, flying))
        if not viable:
            names.append(self.low_battery_land.name)
        return BehaviorsOutput(cmd, tuple(names), land_request=land or not viable)

    failsafe_name = "rc_failsafe"
    failsafe_lands = False


class Px4LikeShield(_BaselineShield):
    name = "px4_like"
    failsafe_name = "rc_loss_hold"

    def __init__(self, behavior_params: BehaviorParams, params: Px4LikeParams | None = None) -> None:
        self.p = params or Px4LikeParams()
        super().__init__(behavior_params, self.p.rc_loss_timeout_s)
        self._last_data_s = 0.0

    def _bin_limit(self, reading: SectorReading | None, closing_m_s: float) -> float:
        """Largest allowed setpoint component into a sector (m/s)."""
        p = self.p
        if reading is None or reading.age_s > p.data_timeout_s:
            return 0.0  # no data: no motion into it (CP_GO_NO_DATA = 0)
        if math.isinf(reading.distance_m):
            d = p.sensor_range_m  # nothing within range: free up to the range
        else:
            d = reading.distance_m
        d_delay = d - max(closing_m_s, 0.0) * p.cp_delay_s
        brake = jerk_limited_max_speed_m_s(d_delay - p.cp_dist_m, accel_m_s2=p.acc_hor_m_s2, jerk_m_s3=p.jerk_max_m_s3)
        scaled = p.xy_cruise_m_s * quadratic_scale(d, keep_m=p.cp_dist_m, band_m=p.scale_band_m)
        return min(brake, scaled)

    def _allowed_length(self, ux: float, uy: float, limits: dict[str, float]) -> float:
        """Longest setpoint along unit (ux, uy) whose component into each sector is allowed."""
        length = math.inf
        for name, (sx, sy), _ in _SECTORS:
            c = ux * sx + uy * sy
            if c > 1e-6:
                length = min(length, limits[name] / c)
        return length

    def limit(self, now_s, stick, estimate, dt):
        p = self.p
        sectors = self.sectors(now_s, p.sensor_range_m)
        if any(r is not None and r.age_s <= p.data_timeout_s for r in sectors.values()):
            self._last_data_s = now_s
        if now_s - self._last_data_s > p.hold_timeout_s:
            return SpeedCommand(0.0, 0.0, stick.vz_m_s, stick.yaw_rate_rad_s), ("cp_hold_no_data",)
        vx, vy = estimate.vx_m_s, estimate.vy_m_s
        limits = {}
        for name, (sx, sy), _ in _SECTORS:
            limits[name] = self._bin_limit(sectors[name], vx * sx + vy * sy)
        speed = math.hypot(stick.vx_m_s, stick.vy_m_s)
        if speed < 1e-6:
            return stick, ()
        ux, uy = stick.vx_m_s / speed, stick.vy_m_s / speed
        allowed = min(speed, self._allowed_length(ux, uy, limits))
        best = (allowed, ux, uy)
        if allowed < speed:
            # Guidance: a direction within CP_GUIDE_ANG that lets the setpoint keep more length.
            base = math.atan2(uy, ux)
            for k in range(1, 7):
                for sign in (-1.0, 1.0):
                    a = base + sign * math.radians(p.cp_guide_ang_deg) * k / 6
                    cx, cy = math.cos(a), math.sin(a)
                    cand = min(speed, self._allowed_length(cx, cy, limits))
                    if cand > best[0] + 1e-3:
                        best = (cand, cx, cy)
        length, ux, uy = best
        if length >= speed - 1e-9:
            return stick, ()
        return SpeedCommand(length * ux, length * uy, stick.vz_m_s, stick.yaw_rate_rad_s), ("collision_prevention",)


class ArduPilotLikeShield(_BaselineShield):
    name = "ardupilot_like"
    failsafe_name = "radio_failsafe_land"
    failsafe_lands = True

    def __init__(self, behavior_params: BehaviorParams, params: ArduPilotLikeParams | None = None) -> None:
        self.p = params or ArduPilotLikeParams()
        super().__init__(behavior_params, self.p.rc_failsafe_timeout_s)

    def healthy(self, sectors: dict[str, SectorReading | None]) -> bool:
        return all(r is None or r.age_s <= self.p.unhealthy_after_s for r in sectors.values())

    def limit(self, now_s, stick, estimate, dt):
        p = self.p
        sectors = self.sectors(now_s, p.dist_max_m)
        if not self.healthy(sectors):
            return stick, ()  # proximity unhealthy: avoidance takes no action at all
        vx, vy = stick.vx_m_s, stick.vy_m_s
        acted = False
        for name, (sx, sy), _ in _SECTORS:
            r = sectors[name]
            if r is None or math.isinf(r.distance_m) or r.distance_m > p.dist_max_m:
                continue
            toward = vx * sx + vy * sy
            breach = p.margin_m - r.distance_m
            if breach > p.backup_deadzone_m:
                back = min(p.backup_speed_m_s, p.backup_gain_1_s * (breach - p.backup_deadzone_m))
                target = -back  # back away (replaces any motion towards it)
            else:
                target = min(toward, sqrt_brake_speed_m_s(r.distance_m, margin_m=p.margin_m, accel_m_s2=p.accel_max_m_s2))
            if target < toward - 1e-9:
                # Slide: only the component towards the obstacle changes.
                vx += (target - toward) * sx
                vy += (target - toward) * sy
                acted = True
        cmd = SpeedCommand(vx, vy, stick.vz_m_s, stick.yaw_rate_rad_s)
        return cmd, (("simple_avoidance",) if acted else ())


class ShieldedStack(OnboardStack):
    """The onboard stack with its behaviour arbitration replaced by ``shield``; the shield also
    sees the raw measurements (stamps, for data age) before each tick."""

    def __init__(self, params: StackParams | None, shield_factory: Callable[[BehaviorParams], _BaselineShield]) -> None:
        super().__init__(params)
        self.shield = shield_factory(self.params.behaviors)
        self.behaviors = self.shield  # type: ignore[assignment]

    def tick(self, now_s, measurements, operator, battery_percent):
        self.shield.observe(now_s, measurements)
        return super().tick(now_s, measurements, operator, battery_percent)


SHIELDS: tuple[str, ...] = ("ours", "px4_like", "ardupilot_like")


def make_stack(shield: str) -> Callable[[StackParams], OnboardStack]:
    """Stack factory for ``run_scenario(make_stack=...)``."""
    if shield == "ours":
        return OnboardStack
    if shield == "px4_like":
        return lambda params: ShieldedStack(params, Px4LikeShield)
    if shield == "ardupilot_like":
        return lambda params: ShieldedStack(params, ArduPilotLikeShield)
    raise ValueError(f"unknown shield {shield!r}; have {', '.join(SHIELDS)}")

