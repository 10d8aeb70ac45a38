"""Baseline shields: ArduPilot's and PX4's obstacle avoidance as drop-in replacements of the
stack's behaviour arbitration (``MAVBehaviors``), on the same estimator, flight machine,
controllers, sensors and operator scripts.

Both are re-derived from the autopilots' code and documentation (read, not translated):

* **ardupilot_like** (``AC_Avoid::adjust_velocity`` with the proximity sensor, Copter defaults;
  ``AP_Proximity_RangeFinder``): each horizontal rangefinder is a face of the proximity boundary.
  The backend is healthy while ANY of its rangefinders has reported within 200 ms
  (``PROXIMITY_RANGEFIDER_TIMEOUT_MS``; an out-of-range reading counts as a report and clears its
  face); a face not refreshed within 750 ms (``PROXIMITY_BOUNDARY_3D_TIMEOUT_MS``) is dropped.
  ``AVOID_BEHAVE`` = slide: for each face, only the desired velocity's component towards it is
  limited, to ``sqrt_controller(distance - AVOID_MARGIN, PSC_POSXY_P, accel)`` with the braking
  acceleration capped at 1 m/s^2 (``AC_AVOID_ACCEL_CMSS_MAX``). Inside the margin by more than
  ``AVOID_BACKUP_DZ``, a back-away velocity ``sqrt_controller(breach, P, 0.4 accel)`` (largest
  per quadrant, summed, at most ``AVOID_BACKUP_SPD``) replaces any slower motion on each axis.
  ``AVOID_ACCEL_MAX`` (3 m/s^2) is what it means in ``limit_accel``: how fast avoidance may change
  the velocity it hands on, not a braking rate.
* **px4_like** (``CollisionPrevention::modifySetpoint`` after the acceleration-based rewrite,
  in the manual acceleration flight task): an obstacle map of 72 5-deg bins filled over each
  rangefinder's field of view, a bin stale after 500 ms; the stick's acceleration set-point
  (``MPC_ACC_HOR`` at full stick, a drag that settles the speed at stick x ``MPC_VEL_MANUAL``) is
  split along the closest obstacle: the component towards it scaled by ((d - ``CP_DIST``) /
  max(``CP_DIST``, ``MPC_VEL_MANUAL`` / ``MPC_XY_P``))^2, negative inside ``CP_DIST`` (pushed
  away), the tangential one by the same law for the bin it points at; plus, over all bins, the
  most braking ``MPC_XY_VEL_P_ACC`` x (max speed - speed towards the bin), the max speed from
  ``computeMaxSpeedFromDistance(MPC_JERK_MAX, MPC_ACC_HOR, d - CP_DIST - v (CP_DELAY + age))``.
  The direction may turn by up to ``CP_GUIDE_ANG`` towards a freer bin; a set-point into a bin
  without data is dropped (``CP_GO_NO_DATA`` = 0: no rear sensor, no flying backwards); with no
  data at all the vehicle gets no acceleration, and after 5 s it holds (``TIMEOUT_HOLD_US``).

Both get the vehicle protections ours has, so the campaign compares avoidance only: the alarm
modes' descent (the estimator fills the missing state; the stick is zeroed as ours does), the
link-loss hover of ``waiting_for_connectivity`` at once (not the autopilots' radio failsafes), and
``low_battery_land``. Neither has an inspection mode.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

from inspect_pipe.campaign._avoid_math import ardupilot_sqrt_controller, px4_cp_scale, px4_max_speed_from_distance
from inspect_pipe.flight_stack.behaviors import BehaviorsOutput, LowBatteryLand
from inspect_pipe.flight_stack.behaviors.waiting_for_connectivity import WaitingForConnectivity
from inspect_pipe.flight_stack.messages import (
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
    "ShieldedStack",
    "make_stack",
]

# The horizontal rangefinders: the sonar field and its axis in the heading frame (rad).
_SONARS: tuple[tuple[str, float], ...] = (("front_sonar", 0.0), ("left_sonar", math.pi / 2), ("right_sonar", -math.pi / 2))


@dataclass(frozen=True)
class ArduPilotLikeParams:
    avoid_margin_m: float = 1.0  # AVOID_MARGIN (default 2 m; set to our stop line)
    avoid_accel_max_m_s2: float = 3.0  # AVOID_ACCEL_MAX (default 3): rate limit of the avoidance's velocity change
    avoid_backup_spd_m_s: float = 0.75  # AVOID_BACKUP_SPD (default)
    avoid_backup_dz_m: float = 0.1  # AVOID_BACKUP_DZ (default)
    psc_posxy_p: float = 1.0  # PSC_POSXY_P (default): the sqrt_controller's gain
    brake_accel_m_s2: float = 1.0  # AC_AVOID_ACCEL_CMSS_MAX: the braking acceleration is capped at 1 m/s^2
    proximity_timeout_s: float = 0.2  # PROXIMITY_RANGEFIDER_TIMEOUT_MS
    face_timeout_s: float = 0.75  # PROXIMITY_BOUNDARY_3D_TIMEOUT_MS
    accel_timeout_s: float = 0.2  # AC_AVOID_ACCEL_TIMEOUT_MS: limit_accel restarts from the pilot's velocity after this
    min_range_m: float = 0.3  # HRLV-EZ4 RNGFND_MIN
    max_range_m: float = 5.0  # HRLV-EZ4 RNGFND_MAX


@dataclass(frozen=True)
class Px4LikeParams:
    cp_dist_m: float = 1.0  # CP_DIST (default -1: off; set to our stop line)
    cp_delay_s: float = 0.4  # CP_DELAY (default)
    cp_guide_ang_deg: float = 30.0  # CP_GUIDE_ANG (default)
    cp_go_no_data: bool = False  # CP_GO_NO_DATA (default 0)
    mpc_acc_hor_m_s2: float = 3.0  # MPC_ACC_HOR (default 3 m/s^2)
    mpc_jerk_max_m_s3: float = 8.0  # MPC_JERK_MAX (default)
    mpc_xy_vel_p_acc: float = 1.8  # MPC_XY_VEL_P_ACC (default)
    mpc_xy_p: float = 0.95  # MPC_XY_P (default)
    mpc_vel_manual_m_s: float = 1.0  # MPC_VEL_MANUAL (default 10 m/s): here the stick's full scale
    bin_deg: int = 5  # BIN_SIZE
    range_stream_timeout_s: float = 0.5  # RANGE_STREAM_TIMEOUT_US
    hold_timeout_s: float = 5.0  # TIMEOUT_HOLD_US
    sensor_h_fov_deg: float = 30.0  # DISTANCE_SENSOR.h_fov of the HRLV-EZ4 beam
    min_range_m: float = 0.3
    max_range_m: float = 5.0


class _BaselineShield:
    """What the baselines share with ours: the vehicle protections (alarm descent, link-loss
    hover, low battery), the stick limits; ``avoid`` is the autopilot's part."""

    name = "baseline"

    def __init__(self, behavior_params: BehaviorParams) -> None:
        self.bp = behavior_params
        self.inspection_mode = False  # the autopilots have no inspection mode
        self.low_battery_land = LowBatteryLand(behavior_params)
        self.link_loss = WaitingForConnectivity(behavior_params)
        self.measurements = Measurements()

    def observe(self, now_s: float, measurements: Measurements) -> None:
        self.measurements = measurements

    def _inputs(self, now_s, estimate, clearance, operator, battery_percent, flying) -> BehaviorInputs:
        return BehaviorInputs(
            now_s=now_s, estimate=estimate, clearance=clearance, stick=operator.stick, link_ok=operator.link_ok,
            inspection_mode=False, go_ahead_pressed=False, battery_percent=battery_percent, flying=flying,
        )

    def avoid(self, now_s: float, desired: SpeedCommand, estimate: StateEstimate, dt: float) -> tuple[SpeedCommand, tuple[str, ...]]:
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
        p = self.bp
        inputs = self._inputs(now_s, estimate, clearance, operator, battery_percent, flying)
        names: list[str] = []
        stick = operator.stick
        hold = self.link_loss.update(inputs, dt)
        if hold is not None:  # the same link-loss hover as ours
            stick, names = hold.to_command(), [self.link_loss.name]
        if estimate.mode < 0:  # the same alarm-mode stick as ours: the filled state brings it down
            stick = SpeedCommand(0.0, 0.0, 0.0, stick.yaw_rate_rad_s)
        stick = SpeedCommand(
            max(-p.max_speed_m_s, min(p.max_speed_m_s, stick.vx_m_s)),
            max(-p.max_speed_m_s, min(p.max_speed_m_s, stick.vy_m_s)),
            max(-p.max_vertical_speed_m_s, min(p.max_vertical_speed_m_s, stick.vz_m_s)),
            stick.yaw_rate_rad_s,
        )
        if flying:
            cmd, who = self.avoid(now_s, stick, estimate, dt)
            names.extend(who)
        else:
            cmd = stick
        viable = self.low_battery_land.viable(inputs)
        if not viable:
            names.append(self.low_battery_land.name)
        return BehaviorsOutput(cmd, tuple(names), land_request=not viable)


class ArduPilotLikeShield(_BaselineShield):
    name = "ardupilot_like"

    def __init__(self, behavior_params: BehaviorParams, params: ArduPilotLikeParams | None = None) -> None:
        super().__init__(behavior_params)
        self.p = params or ArduPilotLikeParams()
        self._stamps = {name: None for name, _ in _SONARS}
        self._faces: dict[str, tuple[float, float]] = {}  # sonar -> (distance, time of the reading)
        self._last_update_s: float | None = None
        self._prev_avoid_vel: tuple[float, float] | None = None
        self._last_limit_s = -math.inf

    def _update_proximity(self, now_s: float) -> bool:
        """``AP_Proximity_RangeFinder::update``: faces from the readings; True while Good."""
        p, m = self.p, self.measurements
        for name, _ in _SONARS:
            r: RangeReading | None = getattr(m, name)
            if r is None or r.stamp_s == self._stamps[name]:
                continue
            self._stamps[name] = r.stamp_s
            # Any reading, in range or not, is data.
            self._last_update_s = r.stamp_s if self._last_update_s is None else max(self._last_update_s, r.stamp_s)
            if r.range_m is not None and p.min_range_m <= r.range_m < p.max_range_m:
                self._faces[name] = (r.range_m, r.stamp_s)
            else:
                self._faces.pop(name, None)
        for name in [n for n, (_, t) in self._faces.items() if now_s - t > p.face_timeout_s]:
            del self._faces[name]
        return self._last_update_s is not None and now_s - self._last_update_s <= p.proximity_timeout_s

    def healthy(self, now_s: float) -> bool:
        return self._update_proximity(now_s)

    def avoid(self, now_s, desired, estimate, dt):
        p = self.p
        if not self._update_proximity(now_s):
            return desired, ()  # proximity status NoData: adjust_velocity_proximity does nothing
        vx, vy = desired.vx_m_s, desired.vy_m_s
        orig = (vx, vy)
        accel = p.brake_accel_m_s2
        quads: dict[tuple[bool, bool], list[float]] = {}
        moving = vx != 0.0 or vy != 0.0
        speed = math.hypot(vx, vy)
        for name, axis in _SONARS:
            face = self._faces.get(name)
            if face is None:
                continue
            d = face[0]
            ux, uy = math.cos(axis), math.sin(axis)
            breach = p.avoid_margin_m - d
            if breach > max(0.0, p.avoid_backup_dz_m):
                back = ardupilot_sqrt_controller(breach, p.psc_posxy_p, 0.4 * accel, dt)
                bx, by = -ux * back, -uy * back
                q = quads.setdefault((bx > 0.0, by > 0.0), [0.0, 0.0])
                q[0] = max(q[0], bx) if bx > 0.0 else min(q[0], bx)
                q[1] = max(q[1], by) if by > 0.0 else min(q[1], by)
            if not moving:
                continue
            # Slide (limit_velocity_3D, horizontal): the margin is laid along the desired velocity.
            dist = max(d - p.avoid_margin_m * math.hypot(vx, vy) / speed, 0.0)
            max_speed = ardupilot_sqrt_controller(dist, p.psc_posxy_p, accel, dt)
            toward = vx * ux + vy * uy
            if toward > max_speed:
                vx += ux * (max_speed - toward)
                vy += uy * (max_speed - toward)
        backing = False
        if quads:
            bx = sum(q[0] for q in quads.values())
            by = sum(q[1] for q in quads.values())
            n = math.hypot(bx, by)
            if n > 0.0 and p.avoid_backup_spd_m_s > 0.0:
                backing = True
                if n > p.avoid_backup_spd_m_s:
                    bx, by = bx * p.avoid_backup_spd_m_s / n, by * p.avoid_backup_spd_m_s / n
                # The pilot keeps control while backing away faster than this, per axis.
                if bx:
                    vx = max(vx, bx) if bx > 0.0 else min(vx, bx)
                if by:
                    vy = max(vy, by) if by > 0.0 else min(vy, by)
        if (vx, vy) == orig:
            return desired, ()
        vx, vy = self._limit_accel(now_s, orig, (vx, vy), dt)
        cmd = SpeedCommand(vx, vy, desired.vz_m_s, desired.yaw_rate_rad_s)
        return cmd, ("avoid_backup",) if backing else ("avoid_slide",)

    def _limit_accel(self, now_s: float, original, modified, dt: float) -> tuple[float, float]:
        """``AC_Avoid::limit_accel``: the avoidance's change of velocity at most AVOID_ACCEL_MAX."""
        p = self.p
        if p.avoid_accel_max_m_s2 <= 0.0 or dt <= 0.0:
            return modified
        if now_s - self._last_limit_s > p.accel_timeout_s or self._prev_avoid_vel is None:
            self._prev_avoid_vel = original
        self._last_limit_s = now_s
        px, py = self._prev_avoid_vel
        ax, ay = (modified[0] - px) / dt, (modified[1] - py) / dt
        a = math.hypot(ax, ay)
        if a > p.avoid_accel_max_m_s2:
            k = p.avoid_accel_max_m_s2 / a
            modified = (px + ax * k * dt, py + ay * k * dt)
        self._prev_avoid_vel = modified
        return modified


class Px4LikeShield(_BaselineShield):
    name = "px4_like"

    def __init__(self, behavior_params: BehaviorParams, params: Px4LikeParams | None = None) -> None:
        super().__init__(behavior_params)
        self.p = params or Px4LikeParams()
        n = 360 // self.p.bin_deg
        self._n = n
        self._dist = [math.inf] * n  # inf: no data (UINT16_MAX)
        self._stamp = [-math.inf] * n
        self._fov = [False] * n  # some sensor's field of view covers the bin
        self._stamps = {name: None for name, _ in _SONARS}
        self._map_stamp = -math.inf
        self._v_sp = (0.0, 0.0)  # the flight task's velocity set-point (heading frame)
        self._dirs = [(math.cos(a), math.sin(a)) for a in (math.radians(i * self.p.bin_deg) for i in range(n))]

    def _bin_dir(self, i: int) -> tuple[float, float]:
        return self._dirs[i]

    def _bin_of(self, ux: float, uy: float) -> int:
        return int(math.floor((math.degrees(math.atan2(uy, ux)) % 360.0) / self.p.bin_deg)) % self._n

    def _update_map(self, now_s: float) -> None:
        """``_updateObstacleMap`` + the stale reset of ``_updateObstacleData``."""
        p, m = self.p, self.measurements
        for name, axis in _SONARS:
            r: RangeReading | None = getattr(m, name)
            if r is None or r.stamp_s == self._stamps[name] or now_s - r.stamp_s >= p.range_stream_timeout_s:
                continue
            self._stamps[name] = r.stamp_s
            self._map_stamp = max(self._map_stamp, r.stamp_s)
            d = p.max_range_m if r.range_m is None else min(r.range_m, p.max_range_m)
            if d <= p.min_range_m:
                continue  # below the minimum range: discarded
            centre = math.degrees(axis) % 360.0
            half = p.sensor_h_fov_deg / 2.0
            lo = int(math.floor((centre - half) / p.bin_deg))
            hi = int(math.floor((centre + half) / p.bin_deg))
            for b in range(lo, hi + 1):
                i = b % self._n
                self._dist[i], self._stamp[i], self._fov[i] = d, r.stamp_s, True
        for i in range(self._n):
            if now_s - self._stamp[i] > p.range_stream_timeout_s:
                self._dist[i] = math.inf

    def _scale(self, d: float) -> float:
        p = self.p
        return px4_cp_scale(d, keep_m=p.cp_dist_m, scale_distance_m=max(p.cp_dist_m, p.mpc_vel_manual_m_s / p.mpc_xy_p))

    def _guide(self, index: int) -> int:
        """``_adaptSetpointDirection``: the bin within CP_GUIDE_ANG with the lowest cost."""
        p = self.p
        k = int(p.cp_guide_ang_deg // p.bin_deg)
        best, best_i = 9999.0, index
        for i in range(index - k, index + k + 1):
            b = i % self._n
            if math.isinf(self._dist[b]):
                continue
            mean = sum(
                (p.cp_dist_m if math.isinf(self._dist[j % self._n]) else self._dist[j % self._n]) for j in (i - 1, i, i + 1)
            ) / 3.0
            cost = p.cp_dist_m * 0.5 * abs(i - index) - mean - self._dist[b]  # in metres (PX4: centimetres)
            if cost < best:
                best, best_i = cost, b
        return best_i

    def avoid(self, now_s, desired, estimate, dt):
        p = self.p
        self._update_map(now_s)
        data = any(not math.isinf(d) for d in self._dist) and now_s - self._map_stamp < p.range_stream_timeout_s
        acc, vmax = p.mpc_acc_hor_m_s2, p.mpc_vel_manual_m_s
        # The stick's acceleration (StickAccelerationXY): full stick is MPC_ACC_HOR.
        sx, sy = desired.vx_m_s / vmax, desired.vy_m_s / vmax
        n = math.hypot(sx, sy)
        if n > 1.0:
            sx, sy = sx / n, sy / n
        ax, ay = acc * sx, acc * sy
        names: tuple[str, ...] = ()
        length = math.hypot(ax, ay)
        vx, vy = self._v_sp
        if not data:
            ax = ay = 0.0  # "No obstacle data, not moving"
            names = ("cp_no_data",)
            if now_s - self._map_stamp > p.hold_timeout_s:
                self._v_sp = (0.0, 0.0)  # the switch to Hold
                return SpeedCommand(0.0, 0.0, desired.vz_m_s, desired.yaw_rate_rad_s), ("cp_hold_no_data",)
        elif length > 0.001:
            ux, uy = ax / length, ay / length
            index = self._guide(self._bin_of(ux, uy))
            if index != self._bin_of(ux, uy):
                ux, uy = self._bin_dir(index)
            # Velocity compensation: the most braking acceleration over the bins with data.
            comp, comp_dir = math.inf, (0.0, 0.0)
            closest, closest_dir = math.inf, (0.0, 0.0)
            for i in range(self._n):
                d = self._dist[i]
                if math.isinf(d):
                    continue
                bx, by = self._bin_dir(i)
                if d < closest:
                    closest, closest_dir = d, (bx, by)
                v_par = max(0.0, vx * bx + vy * by)
                delay = v_par * p.cp_delay_s + (v_par * (now_s - self._stamp[i]) if d < p.max_range_m else 0.0)
                stop = max(0.0, d - p.cp_dist_m - delay)
                vmax_bin = px4_max_speed_from_distance(stop, accel_m_s2=acc, jerk_m_s3=p.mpc_jerk_max_m_s3)
                c = p.mpc_xy_vel_p_acc * (vmax_bin - v_par)
                if c < comp:
                    comp, comp_dir = c, (bx, by)
            feasible = not (math.isinf(self._dist[index]) and (not p.cp_go_no_data or self._fov[index]))
            cx = cy = 0.0
            if feasible:
                dot = ux * closest_dir[0] + uy * closest_dir[1]
                nx, ny = closest_dir[0] * dot, closest_dir[1] * dot
                tx, ty = ux - nx, uy - ny
                if dot > 0.0:
                    ns = self._scale(closest)
                    tn = math.hypot(tx, ty)
                    ts = self._scale(self._dist[self._bin_of(tx, ty)]) if tn > 1e-9 else 1.0
                    cx, cy = (tx * ts + nx * ns) * length, (ty * ts + ny * ns) * length
                else:
                    cx, cy = ux * length, uy * length
            # Only a braking compensation is added (a positive one is no constraint).
            comp = min(comp, 0.0) if not math.isinf(comp) else 0.0
            ax, ay = cx + comp * comp_dir[0], cy + comp * comp_dir[1]
            if (ax, ay) != (acc * sx, acc * sy):
                names = ("collision_prevention",)
        # Drag: the speed settles at stick x MPC_VEL_MANUAL, and comes to rest with the stick centred.
        drag = acc / vmax
        ax -= drag * vx
        ay -= drag * vy
        vx, vy = vx + ax * dt, vy + ay * dt
        self._v_sp = (vx, vy)
        return SpeedCommand(vx, vy, desired.vz_m_s, desired.yaw_rate_rad_s), names


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

