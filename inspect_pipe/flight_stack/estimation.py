"""State estimation: the paper's ``MAV_state_updater`` node (Table I).

:func:`select_mode` maps the valid sensor set to the mode; :data:`TABLE_I` says, per mode, which
measurement feeds which state; :class:`MAVStateUpdater` feeds them: the horizontal and vertical speeds are one
:class:`SpeedObserver` per axis (speed and accelerometer bias, the IMU as input), the height and
the front range are :class:`RangeObserver` s (the height one tells floor steps from motion), all in
``observers.py``. Optical-flow speeds are preferred over range derivatives. The alarm modes (-1,
-2) fill the missing vertical state with a positive speed, so that the speed controllers make the
vehicle descend; their horizontal speed, zero in the paper, is here the observers' speed carried
on with the IMU and corrected by the horizontal sonars' range rates where they hear a wall
(``_range_rate_speeds``).
"""
from __future__ import annotations

import dataclasses
import enum
import math
from collections import deque
from dataclasses import dataclass

from inspect_pipe.flight_stack.messages import (
    Clearance,
    EstimationMode,
    Measurements,
    RangeReading,
    StateEstimate,
)
from inspect_pipe.flight_stack.observers import HeightEstimator, RangeObserver, RangeSlope, SpeedObserver, StuckCheck
from inspect_pipe.flight_stack.obstacle_memory import ObstacleMemory, oblique_wall
from inspect_pipe.flight_stack.params import BehaviorParams, EstimationParams

# The height below which a bottom range sensor's reading is its clamp, within its noise: the HRLV
# sonar reports 0.30 m when closer (+-0.006 m), the TeraRanger One 0.20 m (+-0.02 m). Judged at
# 0.35 m, a hover the controller had just arrested at 0.33 m after a battery sag's dip was a
# touchdown (campaign seed 11 e190); so was a 0.35 m TeraRanger threshold 0.27 m above the floor.
SONAR_FLOOR_M = 0.32
TOF_FLOOR_M = 0.25

__all__ = ["TABLE_I", "Feeds", "MAVStateUpdater", "SensorStatus", "Source", "select_mode", "without_stale_imu"]


@dataclass(frozen=True, slots=True)
class SensorStatus:
    """Which sensors are valid this tick (the data columns of Table I)."""

    bottom_px: bool
    bottom_tof: bool
    front_px: bool


def select_mode(status: SensorStatus) -> EstimationMode:
    """Table I: estimation mode from the valid sensor set."""
    if status.bottom_px:
        return EstimationMode.BOTTOM_FRONT if status.front_px else EstimationMode.BOTTOM
    if status.front_px:
        return EstimationMode.TOF_FRONT if status.bottom_tof else EstimationMode.FRONT
    return EstimationMode.ALARM_TOF if status.bottom_tof else EstimationMode.ALARM_NONE


class Source(enum.Enum):
    """What measures a state: the cells of Table I (the alarm modes' horizontal sources and the
    vertical speed of mode -1 go beyond the paper, see :data:`TABLE_I`)."""

    BOTTOM_FLOW = "bottom flow"
    FRONT_FLOW = "front flow"
    FRONT_RANGE_RATE = "front sonar derivative"
    BOTTOM_SONAR = "bottom sonar (the TeraRanger below its clamp zone)"
    TERARANGER = "TeraRanger"
    HEIGHT_RATE = "height derivative"
    INTEGRATED = "integrated (front flow's vz, else +val)"
    RANGE_RATES = "the IMU, corrected by the horizontal sonars' range rates"
    HEIGHT_RATE_AND_VAL = "TeraRanger derivative + val"
    CARRIED_AND_VAL = "the IMU (relaxing to 0) + val"


@dataclass(frozen=True, slots=True)
class Feeds:
    """One row of Table I: the measurement that feeds each state."""

    height: Source
    vx: Source
    vy: Source
    vz: Source


#: Table I, mode by mode: which measurement feeds which state (docs/flight.md). The paper's alarm
#: modes (-1, -2) set vx = vy = 0; here the speed observers carry the speeds on with the IMU and the
#: horizontal sonars' range rates correct them where they hear a wall (``_range_rate_speeds``).
TABLE_I: dict[EstimationMode, Feeds] = {
    EstimationMode.BOTTOM: Feeds(Source.BOTTOM_SONAR, Source.BOTTOM_FLOW, Source.BOTTOM_FLOW, Source.HEIGHT_RATE),
    EstimationMode.BOTTOM_FRONT: Feeds(Source.BOTTOM_SONAR, Source.BOTTOM_FLOW, Source.BOTTOM_FLOW, Source.FRONT_FLOW),
    EstimationMode.TOF_FRONT: Feeds(Source.TERARANGER, Source.FRONT_RANGE_RATE, Source.FRONT_FLOW, Source.FRONT_FLOW),
    EstimationMode.FRONT: Feeds(Source.INTEGRATED, Source.FRONT_RANGE_RATE, Source.FRONT_FLOW, Source.FRONT_FLOW),
    EstimationMode.ALARM_TOF: Feeds(Source.TERARANGER, Source.RANGE_RATES, Source.RANGE_RATES, Source.HEIGHT_RATE_AND_VAL),
    EstimationMode.ALARM_NONE: Feeds(Source.INTEGRATED, Source.RANGE_RATES, Source.RANGE_RATES, Source.CARRIED_AND_VAL),
}


def _fresh_range(r: RangeReading | None, now: float, timeout: float, max_range: float) -> bool:
    return r is not None and now - r.stamp_s <= timeout and r.range_m is not None and r.range_m <= max_range


def without_stale_imu(m: Measurements, now: float, timeout_s: float) -> Measurements:
    """``m`` with its IMU reading dropped when that is older than ``timeout_s``.

    A link that stops delivering telemetry leaves its last IMU reading in place; integrated tick
    after tick, that one sample's acceleration is a speed and a position the vehicle never had
    (companion over MAVLink, 1 s telemetry loss: a vibration sample of +0.4 m/s^2 carried the
    speed estimate from 0.53 to 0.87 m/s while the autopilot braked to 0.13, and the obstacle
    memory, placed by that odometry, held the wall 0.7 m nearer than the sonar heard it after
    the link came back: the vehicle stopped 1.65 m from the wall instead of 1 m)."""
    imu = m.imu
    if imu is None or now - imu.stamp_s <= timeout_s:
        return m
    return dataclasses.replace(m, imu=None)


class MAVStateUpdater:
    """The paper's MAV_state_updater: speeds, height and obstacle distances each tick.

    ``update(now, measurements)`` returns the estimate and the clearances, both valid at ``now``.
    """

    def __init__(self, params: EstimationParams | None = None, behaviors: BehaviorParams | None = None) -> None:
        self.p = params or EstimationParams()
        p = self.p
        # The sonar beams' half-width and the obliqueness margin, declared once with the
        # behaviours that also use them.
        b = behaviors or BehaviorParams()
        self._beam_half_angle_rad = math.radians(b.covered_half_angle_deg)
        self._oblique_margin_m_s = b.oblique_margin_m_s
        pole = p.observer_pole_1_s
        k = dict(k1=3.0 * pole, k2=3.0 * pole * pole, k3=pole**3)
        self.height = HeightEstimator(
            jump_m=p.height_jump_m, settle_samples=p.height_step_settle_samples, step_min_height_m=p.sonar_clamp_zone_m, **k
        )
        self.front = RangeObserver(jump_m=p.height_jump_m, **k)
        self._slopes = {"front": RangeSlope(), "left": RangeSlope(), "right": RangeSlope()}
        #: the speed observers along x, y (heading frame) and z: speed and accelerometer bias
        self.obs = tuple(
            SpeedObserver(accel_noise=p.accel_noise_m_s2, bias_walk=p.bias_walk_m_s2, gate=p.observer_gate_sigma)
            for _ in range(3)
        )
        self._obs_yaw: float | None = None  # the heading the observers' speeds are expressed in
        self._alarm_since: float | None = None  # when the current alarm mode began
        self.memory = ObstacleMemory(
            keep_s=p.memory_keep_s, keep_travel_m=p.memory_keep_travel_m, max_angle_deg=p.memory_max_angle_deg,
            jump_m=p.height_jump_m, beam_half_rad=self._beam_half_angle_rad, body_radius_m=p.body_radius_m,
        )
        self._yaw: float | None = None  # last heading the autopilot reported
        self._stuck = {
            k: StuckCheck(p.flow_stuck_samples, p.flow_stuck_imu_dv_m_s) for k in ("bottom", "front")
        }
        # Horizontal sonars: stuck once the vehicle's own speed along the axis says the range
        # should have changed.
        self._range_stuck = {
            k: StuckCheck(p.sonar_stuck_samples, p.sonar_stuck_travel_m)
            for k in ("front", "left", "right", "bottom_sonar", "bottom_tof")
        }
        # Per downward range sensor: the vertical speed carried by the IMU alone since its reading
        # last changed (the height estimate it feeds cannot judge it: see _drop_stuck_sonars).
        self._vz_free: dict[str, float] = {"bottom_sonar": 0.0, "bottom_tof": 0.0}
        self._last_down_range: dict[str, float | None] = {"bottom_sonar": None, "bottom_tof": None}
        self._was_stuck = {"bottom": False, "front": False}
        self._newly_stuck = {"bottom": False, "front": False}
        self._last_now: float | None = None
        self._range_rates: dict[str, float | None] = {"front": None, "left": None, "right": None}
        self._v_hist: deque[tuple[float, float, float]] = deque()  # (t, observed vx, vy) over the last slope window
        self._yaw_hist: list[tuple[float, float]] = []  # (t, heading) over the last slope window
        self._reading_stamps: dict[str, float] = {}  # per use of a sensor, the stamp of its reading last used
        self._had_imu = False  # an IMU reading has come (the first tick of a simulation has none)
        self._imu_silent = False  # the IMU went silent after it had spoken (see ``update``)
        self._imu_dt = 0.0  # time since the last IMU reading integrated into the speed observers

    @property
    def imu_bias(self) -> tuple[float, float, float]:
        """The accelerometer's bias (heading frame, m/s^2): the speed observers' bias states,
        set at rest on the floor by the onboard stack and learnt in flight."""
        x, y, z = self.obs
        return x.b, y.b, z.b

    @imu_bias.setter
    def imu_bias(self, bias: tuple[float, float, float]) -> None:
        for o, b in zip(self.obs, bias):
            o.b = b

    def status(self, now: float, m: Measurements) -> SensorStatus:
        p = self.p
        b_sonar = _fresh_range(m.bottom_sonar, now, p.sonar_timeout_s, p.sonar_max_range_m)
        f_sonar = _fresh_range(m.front_sonar, now, p.sonar_timeout_s, p.sonar_max_range_m)
        bf, ff = m.bottom_flow, m.front_flow
        b_flow = bf is not None and now - bf.stamp_s <= p.flow_timeout_s and bf.quality >= p.flow_min_quality
        f_flow = ff is not None and now - ff.stamp_s <= p.flow_timeout_s and ff.quality >= p.flow_min_quality
        imu = m.imu
        ax, ay, az = (imu.ax_m_s2, imu.ay_m_s2, imu.az_m_s2) if imu is not None else (0.0, 0.0, 0.0)
        bx, by, bz = self.imu_bias
        b_stuck = b_flow and self._stuck["bottom"].check(
            bf.stamp_s, (bf.vx_m_s, bf.vy_m_s), (ax - bx, ay - by), reference=(self.obs[0].v, self.obs[1].v)  # type: ignore[union-attr]
        )
        f_stuck = f_flow and self._stuck["front"].check(
            ff.stamp_s, (ff.vy_m_s, ff.vz_m_s), (ay - by, az - bz), reference=(self.obs[1].v, None)  # type: ignore[union-attr]
        )
        self._newly_stuck = {"bottom": b_stuck and not self._was_stuck["bottom"], "front": f_stuck and not self._was_stuck["front"]}
        self._was_stuck = {"bottom": b_stuck, "front": f_stuck}
        b_flow, f_flow = b_flow and not b_stuck, f_flow and not f_stuck
        return SensorStatus(
            bottom_px=b_flow and b_sonar,
            bottom_tof=_fresh_range(m.bottom_tof, now, p.tof_timeout_s, p.tof_max_range_m),
            front_px=f_flow and f_sonar,
        )

    def update(self, now: float, m: Measurements) -> tuple[StateEstimate, Clearance]:
        p = self.p
        m = without_stale_imu(m, now, p.imu_timeout_s)
        dt = 0.0 if self._last_now is None else max(now - self._last_now, 0.0)
        self._last_now = now
        ax, ay, az = m.imu.heading_accel() if m.imu is not None else (0.0, 0.0, 0.0)
        m = self._drop_stuck_sonars(m, az, dt)
        if m.imu is None:
            # Nothing measures the vehicle's motion: the odometry cannot place what the sonars
            # heard before, so the memory forgets it (the sonars refill it within a reading)...
            self.memory.reset()
            self._imu_silent = self._had_imu
        elif self._imu_silent:
            # ...and the speeds carried through the silence are unknown by whatever the vehicle
            # did meanwhile: restarted with the initial variance, the first flow or range rate is
            # taken in full, not gated out against a confident stale speed.
            for o in self.obs:
                o.restart(o.v)
            self._imu_silent = False
            self._imu_dt = 0.0  # the silence is not integrated with the first reading after it
        else:
            self._had_imu = True
        self._feed_slopes(now, m)
        if m.imu is not None and m.imu.yaw_rad is not None:
            self._yaw = m.imu.yaw_rad
            hist = self._yaw_hist
            hist.append((now, self._yaw))
            while now - hist[0][0] > self._slopes["front"].window_s:
                hist.pop(0)
        status = self.status(now, m)
        mode = select_mode(status)
        feeds = TABLE_I[mode]
        imu = m.imu
        bflow = m.bottom_flow if feeds.vx is Source.BOTTOM_FLOW else None
        fflow = m.front_flow if Source.FRONT_FLOW in (feeds.vy, feeds.vz) else None
        if imu is not None and (bflow is not None or fflow is not None):
            bflow, fflow = self._flow_to_heading(imu.roll_rad, imu.pitch_rad, bflow, fflow)
        # Each IMU reading is integrated once, over the time since the last one integrated: a
        # link that delivers readings out of step with the ticks (or stops) repeats the last one,
        # and that sample's acceleration is no longer what the vehicle does.
        self._imu_dt += dt
        if imu is not None and self._new_reading("imu", imu.stamp_s):
            self._predict(ax, ay, az, min(self._imu_dt, p.imu_timeout_s))
            self._imu_dt = 0.0
        self._restart_after_stuck_flow()

        # Front range (vx in modes 2 and 3, front clearance always). Flow speed, when there is
        # one, drives the range between samples; otherwise the IMU does.
        self.front.propagate(now, -ax, -bflow.vx_m_s if bflow is not None else None)
        fs = m.front_sonar
        if fs is not None and fs.range_m is not None and self._new_reading("front_range", fs.stamp_s):
            self.front.correct(fs.range_m, fs.stamp_s - p.sonar_latency_s)
        # One accelerometer bias along x: the x observer's (learnt from the bottom flow) while there is one;
        # without it the front range observer's own bias state, which the sonar corrects (modes
        # 2 and 3). Not shared, the speed loop pushed with a bias only one of them knew, and the
        # Fig. 5 hover in mode 2 drifted 0.30 m.
        if bflow is not None:
            self.front.bias = -self.obs[0].b
        elif _fresh_range(fs, now, p.sonar_timeout_s, p.sonar_max_range_m):
            self.obs[0].b = -self.front.bias

        # Horizontal speeds (Table I): the bottom flow's (modes 0 and 1), else the front range's rate
        # and the front flow's vy (modes 2 and 3); each is a measurement of its axis's observer
        # (``SpeedObserver``), and the loops get the observer's speed. Taken as it came, the
        # PX4Flow's output holds the body rotation its own gyro's scale error leaves in (scale x
        # rate x distance), and the speed PID closed a loop through it and the attitude that
        # diverged with height (a 4 % scale error rolling at 6 Hz reads 0.3 m/s at 2 m); the
        # observer, carried by the IMU between readings, passes a fraction of that. In the alarm
        # modes nothing in Table I measures them: the paper fills in zero, which leaves a moving
        # vehicle coasting on (its speed loop sees no error to brake on); the observers carry the
        # last speed on with the IMU instead, so the loop brakes, and the horizontal sonars' range
        # rates correct them where they hear a wall (``_range_rate_speeds``).
        ox, oy, oz = self.obs
        noise = p.speed_noise_m_s
        if feeds.vx is Source.BOTTOM_FLOW:
            assert bflow is not None
            # The PX4Flow scales its angular flow by its own sonar's range; below the sonar's
            # clamp (0.30 m) that range is too long and the speed too high by the ratio (3x at
            # 0.10 m). Taken as it came during take-off, it carried a speed the vehicle did not
            # have into the bias state, and the position estimate gained 2-3 cm along the wall in
            # the first climb, which every mosaic placed by odometry kept (issue 20, wall 53;
            # the IMU alone for that second did worse, 4 cm). In the clamp zone the TeraRanger's
            # range, which reaches down to 0.20 m, rescales the speed, and the reading corrects
            # the speed but not the accelerometer's bias.
            bs, tof = m.bottom_sonar, m.bottom_tof
            clamped = bs is not None and bs.range_m is not None and bs.range_m < p.sonar_clamp_zone_m
            if self._new_reading("bottom_flow", bflow.stamp_s):
                scale = min(1.0, tof.range_m / bs.range_m) if clamped and status.bottom_tof else 1.0  # type: ignore[union-attr,operator]
                ox.correct(bflow.vx_m_s * scale, noise, learn_bias=not clamped)
                oy.correct(bflow.vy_m_s * scale, noise, learn_bias=not clamped)
        elif feeds.vx is Source.FRONT_RANGE_RATE:
            assert fflow is not None
            # Modes 2 and 3: vx is the front range's rate, which is the speed only while the
            # heading holds: turning, the range to a wall at an angle changes without any
            # translation (pushed while yawing, the rate said 0.2 m/s while the vehicle sped up to
            # 0.77 m/s). While turning, vx is carried on with the IMU alone.
            if self._yaw is None or not self._turning(now):
                ox.correct(-self.front.rate, noise)
            if self._new_reading("front_flow", fflow.stamp_s):
                oy.correct(fflow.vy_m_s, noise)
        else:
            self._range_rate_speeds(now)
        vx, vy = ox.v, oy.v
        if self._yaw is not None:
            self.memory.advance(now, vx, vy, self._yaw, altitude_m=self.height.altitude_m, measured=mode >= 0)

        # Height: bottom PX4Flow sonar, else TeraRanger, else integration (mode 3: front flow;
        # mode -2: the alarm value, Table I "i"). Vertical speed: front flow, else derivative.
        vz_flow = fflow.vz_m_s if feeds.vz is Source.FRONT_FLOW and fflow is not None else None
        # Each range sensor within its range: below the bottom sonar's clamp zone the TeraRanger,
        # which reads down to 0.20 m, measures the height (the sonar reads 0.30 m there whether
        # the vehicle hovers 0.3 m up or stands on the floor, and a landing that hopped after a
        # battery sag took the hop's top, 0.21 m above the floor, for the touchdown and fell from
        # it at 0.95 m/s: campaign seed 113 e1766). ``height_floor`` is the height below which the
        # measuring sensor's reading is its clamp within its noise (the flight machine's "down").
        source, latency, height_floor = None, 0.0, None
        if feeds.height is Source.BOTTOM_SONAR:
            source, latency, height_floor = m.bottom_sonar, p.sonar_latency_s, SONAR_FLOOR_M
            if status.bottom_tof and source.range_m < p.sonar_clamp_zone_m:  # type: ignore[union-attr,operator]
                source, latency, height_floor = m.bottom_tof, p.tof_latency_s, TOF_FLOOR_M
        elif feeds.height is Source.TERARANGER:
            source, latency, height_floor = m.bottom_tof, p.tof_latency_s, TOF_FLOOR_M
        # "+val." (Table I), filled in once the alarm mode has lasted ``alarm_descent_delay_s``:
        # a brief loss of every range sensor is not yet a lost reference. Descending at once, a
        # vehicle that came to rest blind beside a box edge brought its rotors onto that edge
        # within the 2.9 s the sensors were silent (safety campaign, seed 5 e1805).
        if mode >= 0:
            self._alarm_since = None
        elif self._alarm_since is None:
            self._alarm_since = now
        alarm_s = 0.0 if self._alarm_since is None else now - self._alarm_since
        climb = p.alarm_climb_m_s if mode < 0 and alarm_s >= p.alarm_descent_delay_s else 0.0
        if source is None and vz_flow is None:
            self.height.propagate(now, rate=climb)
        else:
            self.height.propagate(now, az, vz_flow)
        if source is not None and self._new_reading("height", source.stamp_s):
            self.height.update(source.range_m, source.stamp_s - latency)  # type: ignore[arg-type]

        # "+val." (Table I): the alarm modes report a climb so that the speed loop descends. Filled
        # in alone, a constant +val is an error the loop never removes: it descended faster and
        # faster (every range sensor lost, 0.4-0.8 m/s into a coaming below). The val is added to
        # the vertical observer's speed instead (carried on with the IMU), so the loop settles at
        # a steady descent of val. Mode -1 still has the TeraRanger's rate.
        # The front flow's vz is a measurement of the vertical observer; without it, the height
        # observer's rate (Table I's derivative) is, but one that corrects the speed and not the
        # bias: that rate is itself the IMU's integral corrected by a 10 Hz range, with the IMU's
        # errors in it (taken as a bias measurement, it walked the bias to -0.2 m/s^2 over a
        # climb, and the carried alarm descent sped up to 0.67 m/s). In mode -2 the speed is
        # carried on with the IMU and relaxes towards zero at ``alarm_vz_leak_m_s2``: the
        # vertical bias a short floor calibration leaves (~0.02 m/s^2) is unobservable without a
        # vertical flow, and the loop, holding the carried speed at -val, turned it into a
        # descent that slowed from 0.2 to 0.09 m/s within 7 s (alarm_none_descent).
        if vz_flow is not None:
            oz.correct(vz_flow, noise)
        elif feeds.vz in (Source.HEIGHT_RATE, Source.HEIGHT_RATE_AND_VAL):
            oz.correct(self.height.rate_m_s, noise, learn_bias=False)
        if feeds.vz is Source.HEIGHT_RATE_AND_VAL:
            vz = self.height.rate_m_s + climb
        elif feeds.vz is Source.CARRIED_AND_VAL:
            oz.v -= math.copysign(min(abs(oz.v), p.alarm_vz_leak_m_s2 * dt), oz.v)
            vz = oz.v + climb
        else:
            vz = vz_flow if vz_flow is not None else self.height.rate_m_s

        hist = self._v_hist
        hist.append((now, vx, vy))
        while now - hist[0][0] > self._slopes["front"].window_s + p.sonar_latency_s + 0.5:
            hist.popleft()
        est = StateEstimate(
            height_m=self.height.height_m,
            height_floor_m=height_floor,
            altitude_m=self.height.altitude_m,
            vx_m_s=vx,
            vy_m_s=vy,
            vz_m_s=vz,
            mode=mode,
            odometry=None if self._yaw is None else (self.memory.x, self.memory.y, self._yaw),
        )
        return est, self._clearance(now, m, est)

    def _clearance(self, now: float, m: Measurements, est: StateEstimate) -> Clearance:
        """Obstacle distances brought to ``now``: a 10 Hz sonar reading is up to 0.15 s old."""
        p = self.p

        def at_now(r: RangeReading | None, closing_m_s: float) -> float | None:
            if not _fresh_range(r, now, p.sonar_timeout_s, p.sonar_max_range_m):
                return None
            age = now - r.stamp_s + p.sonar_latency_s  # type: ignore[union-attr]
            return r.range_m - closing_m_s * age  # type: ignore[union-attr,operator]

        def stale(r: RangeReading | None) -> bool:
            return r is None or now - r.stamp_s > p.sonar_timeout_s

        closing = {name: None if rate is None else -rate for name, rate in self._range_rates.items()}

        front = self.front.value if _fresh_range(m.front_sonar, now, p.sonar_timeout_s, p.sonar_max_range_m) else None
        left, right = at_now(m.left_sonar, est.vy_m_s), at_now(m.right_sonar, -est.vy_m_s)
        if self._yaw is not None and p.memory_keep_s > 0.0:
            self._oblique_walls(m, est, closing, front, left, right)
            front, left, right = (
                self._remembered(now, name, axis, r, d)
                for name, axis, r, d in (
                    ("front", 0.0, m.front_sonar, front),
                    ("left", _HALF_PI, m.left_sonar, left),
                    ("right", -_HALF_PI, m.right_sonar, right),
                )
            )
        return Clearance(
            front_m=front,
            left_m=left,
            right_m=right,
            down_m=est.height_m if est.mode != EstimationMode.ALARM_NONE else None,
            front_stale=stale(m.front_sonar),
            left_stale=stale(m.left_sonar),
            right_stale=stale(m.right_sonar),
            front_closing_m_s=closing["front"],
            left_closing_m_s=closing["left"],
            right_closing_m_s=closing["right"],
        )

    def _flow_to_heading(self, roll: float, pitch: float, bflow, fflow):
        """The PX4Flow units measure in the body frame; the estimate is in the heading frame.
        Turned by the autopilot's ESTIMATED roll and pitch (small angles: v_h = R_y R_x v_b), the
        component a unit does not see taken from the last estimate. Left in the body frame, a
        0.05 rad pitch at 0.4 m/s reads as a 0.02 m/s climb."""
        vx_prev = self.obs[0].v
        vz_prev = self.obs[2].v
        if bflow is not None:
            bflow = dataclasses.replace(
                bflow, vx_m_s=bflow.vx_m_s + pitch * vz_prev, vy_m_s=bflow.vy_m_s - roll * vz_prev
            )
        if fflow is not None:
            vx = bflow.vx_m_s if bflow is not None else vx_prev
            fflow = dataclasses.replace(
                fflow, vy_m_s=fflow.vy_m_s - roll * vz_prev, vz_m_s=fflow.vz_m_s - pitch * vx + roll * fflow.vy_m_s
            )
        return bflow, fflow

    def _restart_after_stuck_flow(self) -> None:
        """A flow found stuck has fed its repeated value into the estimate since it stuck (the
        check needs the IMU to disagree by ``flow_stuck_imu_dv_m_s`` first); the observers that
        take over restart from what it would read now instead (``StuckCheck.likely_value``).
        Continuing from the stuck value, the front range observer of mode 2 needed a second to
        find the real speed, and the vehicle flew 0.15 m past the stop line meanwhile."""
        ox, oy, oz = self.obs
        if self._newly_stuck["bottom"]:
            vx, vy = self._stuck["bottom"].likely_value()
            self.front.rate = -vx
            ox.restart(vx)
            oy.restart(vy)
        if self._newly_stuck["front"]:
            vy, vz = self._stuck["front"].likely_value()
            oy.restart(vy)
            oz.restart(vz)

    def _predict(self, ax: float, ay: float, az: float, dt: float) -> None:
        """The observers one tick on with the IMU's acceleration (heading frame), the horizontal
        speeds first turned by the heading's change since the last tick: a speed fixed in the hold
        turns the other way in a turning frame (the operator may keep yawing in the alarm modes,
        0.27 rad/s while braking). The biases are the sensor's and stay in the heading frame."""
        ox, oy, oz = self.obs
        yaw, prev = self._yaw, self._obs_yaw
        self._obs_yaw = yaw
        if yaw is not None and prev is not None:
            d = math.remainder(yaw - prev, math.tau)
            c, sn = math.cos(d), math.sin(d)
            ox.v, oy.v = c * ox.v + sn * oy.v, -sn * ox.v + c * oy.v
        ox.predict(ax, dt)
        oy.predict(ay, dt)
        oz.predict(az, dt)

    def _new_reading(self, name: str, stamp_s: float) -> bool:
        """Whether ``stamp_s`` is a reading not yet used for ``name`` (one use of one sensor: a
        measurement counts once), and from now on a used one."""
        if self._reading_stamps.get(name) == stamp_s:
            return False
        self._reading_stamps[name] = stamp_s
        return True

    def _range_rate_speeds(self, now: float) -> None:
        """Alarm modes: no flow measures the horizontal speed, and the IMU-carried one drifts with
        whatever accelerometer bias is left, so a station-keeping loop lets the vehicle creep away
        (bottom flow quality 0 during a link loss: 0.55 m in 4 s beside walls the side sonars heard
        2.6-3.9 m away). Beyond Table I, the horizontal sonars' range rates measure the speed along
        their axes (a wall ahead closing at 1 m/s: vx = +1) and correct the observers.

        A range rate is the slope of the last ``window_s`` of samples: the speed at their mean
        stamp less the sonar's latency, not now; its innovation is taken against the estimate of
        that moment and applied now (compared with the speed now, a vehicle braking as every range
        sensor went silent took the lagging rate for its speed and coasted at 0.14 m/s for 2.5 s).
        A new surface entering the beam fails the observer's gate; the left and right sonars
        disagreeing by more than the gate's width (one of them hears a box sliding into its beam)
        say nothing. Not used while turning: the range to a wall then changes without any
        translation."""
        p = self.p
        if self._turning(now):
            return
        noise = p.speed_noise_m_s
        for axis, sensors in ((0, (("front", -1.0),)), (1, (("left", -1.0), ("right", 1.0)))):
            obs, found = self.obs[axis], []
            for name, sign in sensors:
                rate, t_mid = self._range_rates[name], self._slopes[name].t_mid
                if rate is None or t_mid is None or not self._new_reading(f"{name}_slope", t_mid):
                    continue
                then = self._speed_at(t_mid - p.sonar_latency_s)
                found.append((sign * rate, None if then is None else then[axis]))
            # One slope's own noise is half of speed_noise_m_s (doubled there for the overlap
            # of consecutive slopes); the difference of two sensors' has sqrt(2) times that.
            if len(found) == 2 and abs(found[0][0] - found[1][0]) > p.observer_gate_sigma * noise / math.sqrt(2.0):
                continue
            for z, then in found:
                obs.correct(z, noise, then=then)
    def _feed_slopes(self, now: float, m: Measurements) -> None:
        """Each horizontal sonar's range rate (least-squares slope of its last samples), or None."""
        p = self.p
        rates: dict[str, float | None] = {}
        for name, r in (("front", m.front_sonar), ("left", m.left_sonar), ("right", m.right_sonar)):
            slope = self._slopes[name]
            if r is not None and self._new_reading(f"{name}_samples", r.stamp_s):
                valid = r.range_m is not None and r.range_m <= p.sonar_max_range_m
                slope.add(r.stamp_s, r.range_m if valid else None)
            fresh = r is not None and now - r.stamp_s <= p.sonar_timeout_s
            rates[name] = slope.rate(now) if fresh else None
        self._range_rates = rates

    def _speed_at(self, t: float) -> tuple[float, float] | None:
        """The carried horizontal speed at time ``t`` (linear between ticks), from the history."""
        hist = self._v_hist
        if not hist or t < hist[0][0]:
            return None
        prev = hist[0]
        for h in hist:
            if h[0] >= t:
                if h[0] == prev[0]:
                    return h[1], h[2]
                w = (t - prev[0]) / (h[0] - prev[0])
                return prev[1] + w * (h[1] - prev[1]), prev[2] + w * (h[2] - prev[2])
            prev = h
        return prev[1], prev[2]

    def _turning(self, now: float) -> bool:
        """The heading turned more than ``alarm_slope_max_turn_rad`` over the last slope window
        (or no heading is known, or none recently)."""
        hist = self._yaw_hist
        if self._yaw is None or not hist or now - hist[-1][0] > self.p.sonar_timeout_s:
            return True
        return abs(math.remainder(hist[-1][1] - hist[0][1], math.tau)) > self.p.alarm_slope_max_turn_rad

    def _drop_stuck_sonars(self, m: Measurements, az: float, dt: float) -> Measurements:
        """A range sensor repeating its range bit for bit while the vehicle has moved along its
        axis by more than ``sonar_stuck_travel_m`` is stuck: its readings count as missing until
        they change. Horizontal sonars: a silent sector, no user motion into it (safety campaign:
        a left sonar stuck at 1.65 m while the operator pushed at 0.77 m/s towards the wall; the
        stop came when it recovered, 0.15 m inside the line).

        The downward ones (bottom sonar, TeraRanger) are judged by the vertical speed the IMU
        alone carries from the moment their reading last changed: the height estimate they feed
        follows a stuck reading, and so does its rate. In mode -1 a TeraRanger stuck at 2.45 m
        pinned the height, the estimate's vertical speed stayed at the alarm descent's "+val."
        while the vehicle fell, the speed loop kept lowering the thrust, and the vehicle hit the
        floor at 1.47 m/s (found by hand, 2026-11-28; the campaign draws one stuck sensor at a
        time, and with a flow alive the TeraRanger does not measure the height). Dropped, the
        TeraRanger leaves mode -2 and its alarm descent. A reading at the sensor's clamp (the
        sonar's 0.30 m, the TeraRanger's 0.20 m: on the floor, in a take-off) repeats by design."""
        vx, vy = self.obs[0].v, self.obs[1].v
        drop = {}
        for name, r, speed in (("front", m.front_sonar, vx), ("left", m.left_sonar, vy), ("right", m.right_sonar, -vy)):
            if r is not None and r.range_m is not None and self._range_stuck[name].check(r.stamp_s, (r.range_m,), (speed,)):
                drop[f"{name}_sonar"] = None
        az -= self.obs[2].b  # ``az``: the IMU's vertical acceleration this tick (heading frame)
        for name, r, clamp_m in (("bottom_sonar", m.bottom_sonar, SONAR_FLOOR_M), ("bottom_tof", m.bottom_tof, TOF_FLOOR_M)):
            if r is None or r.range_m is None or r.range_m <= clamp_m:
                self._last_down_range[name] = None
                continue
            if r.range_m != self._last_down_range[name]:
                self._vz_free[name] = self.obs[2].v  # the estimate while the reading still moved
                self._last_down_range[name] = r.range_m
            else:
                self._vz_free[name] += az * dt
            if self._range_stuck[name].check(r.stamp_s, (r.range_m,), (self._vz_free[name],)):
                drop[name] = None
        return dataclasses.replace(m, **drop) if drop else m

    def _oblique_walls(
        self, m: Measurements, est: StateEstimate, closing: dict[str, float | None],
        front: float | None, left: float | None, right: float | None,
    ) -> None:
        """Store the wall that the front sonar and a side sonar hear together at an angle
        (:func:`oblique_wall`), when either has a fresh echo: pushed while yawing, the vehicle
        otherwise stops on readings that overstate the perpendicular distance (safety campaign).

        Two readings alone cannot tell such a wall from an inside corner, and a wall across a
        corner blocked the escape along one of its walls (safety campaign). The wall is taken
        only with evidence of obliquity: one of the two ranges closes faster than the speed along
        its own sensor's axis explains (a corner's walls close at exactly those speeds), and it is
        kept only ``oblique_keep_s`` unless the evidence renews it (a pillar's end face heard
        obliquely on the way into a corner is such evidence once, and the wall fitted across
        that corner must not outlive it)."""
        if front is None or m.front_sonar is None:
            return
        h = self._beam_half_angle_rad
        margin = self._oblique_margin_m_s

        def oblique(name: str, axis_speed: float) -> bool:
            c = closing.get(name)
            return c is not None and c > max(axis_speed, 0.0) + margin

        front_oblique = oblique("front", est.vx_m_s)
        for name, side, r, sign in (("left", left, m.left_sonar, 1.0), ("right", right, m.right_sonar, -1.0)):
            if side is None or r is None:
                continue
            if not (front_oblique or oblique(name, sign * est.vy_m_s)):
                continue
            stamp = max(m.front_sonar.stamp_s, r.stamp_s)
            if not self._new_reading(f"{name}_wall", stamp):
                continue
            wall = oblique_wall(front, side, h)
            if wall is not None:
                phi, d = wall
                self.memory.add(stamp, sign * phi, d, self._yaw, keep_s=self.p.oblique_keep_s)  # type: ignore[arg-type]

    def _remembered(self, now: float, name: str, axis_rad: float, r: RangeReading | None, d: float | None) -> float | None:
        """The sector's clearance ``d`` (from its sonar, brought to now), after storing a fresh
        echo in the obstacle memory, lowered to the nearest remembered surface facing it."""
        yaw = self._yaw
        if d is not None and r is not None and self._new_reading(f"{name}_memory", r.stamp_s):
            self.memory.add(r.stamp_s, axis_rad, d, yaw)  # type: ignore[arg-type]
        mem = self.memory.clearance(now, axis_rad, yaw)  # type: ignore[arg-type]
        if mem is None:
            return d
        return mem if d is None else min(d, mem)


_HALF_PI = 1.5707963267948966
