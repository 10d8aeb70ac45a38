"""State estimation: the paper's ``MAV_state_updater`` node (Table I).

:func:`select_mode` maps the valid sensor set to the mode; :data:`TABLE_I` says, per mode, which
measurement feeds which state; :class:`MAVStateUpdater` feeds them: the horizontal and vertical speeds are one
:class:`SpeedObserver` per axis (speed and accelerometer bias, the IMU as input; the flows and the
sonars' range rates are its measurements), the height is a :class:`HeightEstimator` (it tells floor
steps from motion) and the front range a :class:`RangeObserver` carried by the x speed, all in
``observers.py``. Optical-flow speeds are preferred over range derivatives. The alarm modes (-1,
-2) fill the missing vertical state with a positive speed, so that the speed controllers make the
vehicle descend; their speeds, zero in the paper, are here the observers' speeds carried on with
the IMU and corrected by what still measures them: the PX4Flows' angular flow at the distance
carried (a unit without its sonar has no metric flow but still measures rad/s) and the horizontal
sonars' range rates where they hear a wall (``range_rates.SonarRangeRates.correct``).
"""
from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass

from inspect_pipe.flight_stack.clearance import Clearances
from inspect_pipe.flight_stack.messages import (
    BottomFlow,
    Clearance,
    EstimationMode,
    FrontFlow,
    Measurements,
    StateEstimate,
)
from inspect_pipe.flight_stack.observers import HeightEstimator, RangeObserver, SpeedObserver
from inspect_pipe.flight_stack.obstacle_memory import ObstacleMemory
from inspect_pipe.flight_stack.params import BehaviorParams, EstimationParams
from inspect_pipe.flight_stack.range_rates import SonarRangeRates
from inspect_pipe.flight_stack.sensor_health import (
    SONAR_FLOOR_M,
    SONAR_LATENCY_S,
    TOF_FLOOR_M,
    TOF_LATENCY_S,
    ReadingLedger,
    SensorHealth,
    SensorStatus,
)

__all__ = ["SONAR_FLOOR_M", "TABLE_I", "TOF_FLOOR_M", "Feeds", "MAVStateUpdater", "SensorStatus", "Source", "select_mode", "without_stale_imu"]


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
    BOTH_FLOWS = "bottom flow and front flow"
    FRONT_RANGE_RATE = "front sonar derivative"
    BOTTOM_SONAR = "bottom sonar (the TeraRanger below its clamp zone)"
    TERARANGER = "TeraRanger"
    HEIGHT_RATE = "height derivative"
    INTEGRATED = "integrated (front flow's vz, else +val)"
    RANGE_RATES = ("the IMU, corrected by the bottom flow's angular rate at the height carried (vy: and the front flow's "
                   "at the front range carried) and the horizontal sonars' range rates")
    HEIGHT_RATE_AND_VAL = "TeraRanger derivative + val"
    CARRIED_AND_VAL = "the IMU, corrected by the front flow's angular rate at the front range carried (relaxing to 0), + val"


@dataclass(frozen=True, slots=True)
class Feeds:
    """One row of Table I: the measurement that feeds each state."""

    height: Source
    vx: Source
    vy: Source
    vz: Source


#: Table I, mode by mode: which measurement feeds which state (docs/flight.md). The paper's alarm
#: modes (-1, -2) set vx = vy = 0; here the speed observers carry the speeds on with the IMU, and the
#: PX4Flows' angular flow at the distance carried (``_angular_bottom_flow``, ``_angular_front_flow``) and
#: the horizontal sonars' range rates where they hear a wall (``range_rates.SonarRangeRates.correct``)
#: correct them.
#: In mode 1 both PX4Flows see the lateral speed, and both readings are measurements of it (the
#: paper takes the bottom one's): each unit's gyro bias leaves bias x range in its speed, and the
#: front one, a metre from the inspected wall, half as much as the bottom one two metres up.
TABLE_I: dict[EstimationMode, Feeds] = {
    EstimationMode.BOTTOM: Feeds(Source.BOTTOM_SONAR, Source.BOTTOM_FLOW, Source.BOTTOM_FLOW, Source.HEIGHT_RATE),
    EstimationMode.BOTTOM_FRONT: Feeds(Source.BOTTOM_SONAR, Source.BOTTOM_FLOW, Source.BOTH_FLOWS, Source.FRONT_FLOW),
    EstimationMode.TOF_FRONT: Feeds(Source.TERARANGER, Source.FRONT_RANGE_RATE, Source.FRONT_FLOW, Source.FRONT_FLOW),
    EstimationMode.FRONT: Feeds(Source.INTEGRATED, Source.FRONT_RANGE_RATE, Source.FRONT_FLOW, Source.FRONT_FLOW),
    EstimationMode.ALARM_TOF: Feeds(Source.TERARANGER, Source.RANGE_RATES, Source.RANGE_RATES, Source.HEIGHT_RATE_AND_VAL),
    EstimationMode.ALARM_NONE: Feeds(Source.INTEGRATED, Source.RANGE_RATES, Source.RANGE_RATES, Source.CARRIED_AND_VAL),
}


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
        pole = p.observer_pole_1_s
        k = dict(k1=3.0 * pole, k2=3.0 * pole * pole, k3=pole**3)
        self.height = HeightEstimator(
            jump_m=p.height_jump_m, settle_samples=p.height_step_settle_samples, step_min_height_m=p.sonar_clamp_zone_m, **k
        )
        # the front range: carried by the x observer's speed (it has no rate or bias of its own)
        self.front = RangeObserver(jump_m=p.height_jump_m, k1=k["k1"], k2=0.0)
        #: the speed observers along x, y (heading frame) and z: speed and accelerometer bias
        self.obs = tuple(
            SpeedObserver(accel_noise=p.accel_noise_m_s2, bias_walk=p.bias_walk_m_s2, gate=p.observer_gate_sigma)
            for _ in range(3)
        )
        self._obs_yaw: float | None = None  # the heading the observers' speeds are expressed in
        self._alarm_since: float | None = None  # when the current alarm mode began
        # The last floor step the downward sensors heard (a box's edge): the odometry's travel and
        # blind time then, and how far from the vehicle's centre the edge can be (see _alarm_climb).
        self._edge: tuple[float, float, float] | None = None
        # Where the odometry had the vehicle when the current alarm mode began, and how far it may
        # move from there before its rotors are over floor the downward beam did not cover (_alarm_climb).
        self._seen: tuple[float, float, float] | None = None
        self.memory = ObstacleMemory(
            keep_s=p.memory_keep_s, keep_travel_m=p.memory_keep_travel_m, max_angle_deg=p.memory_max_angle_deg,
            jump_m=p.height_jump_m, beam_half_rad=self._beam_half_angle_rad, body_radius_m=p.body_radius_m,
        )
        self._yaw: float | None = None  # last heading the autopilot reported
        self._ledger = ReadingLedger()  # per use of a sensor, the reading last used
        self.health = SensorHealth(p)  # Table I's data columns: which readings count
        self.rates = SonarRangeRates(p, self._ledger)  # the horizontal sonars' range rates
        self.clearances = Clearances(p, self.memory, self._ledger, beam_half_rad=self._beam_half_angle_rad,
                                     oblique_margin_m_s=b.oblique_margin_m_s)
        self._last_now: float | None = None
        self._had_imu = False  # an IMU reading has come (the first tick of a simulation has none)
        self._imu_silent = False  # the IMU went silent after it had spoken (see ``update``)
        self._imu_dt = 0.0  # time since the last IMU reading integrated into the speed observers
        # The distance the bottom PX4Flow's camera sees: the height estimate (measured, or in mode 3
        # integrated from the front flow's vz), carried on by the vertical speed in mode -2
        # (see _angular_bottom_flow).
        self._below_m: float | None = None
        self._last_flow_rates: dict[str, tuple[float, float]] = {}  # per PX4Flow, its last angular reading

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
        """The valid sensor set (Table I's data columns) this tick."""
        return self.health.status(now, m, self.obs)

    def update(self, now: float, m: Measurements) -> tuple[StateEstimate, Clearance]:
        """One tick: the valid sensors give the mode (Table I), the mode says which measurement
        feeds each state, and the observers, carried by the IMU, take them."""
        p = self.p
        m = without_stale_imu(m, now, p.imu_timeout_s)
        dt = 0.0 if self._last_now is None else max(now - self._last_now, 0.0)
        self._last_now = now
        ax, ay, az = m.imu.heading_accel() if m.imu is not None else (0.0, 0.0, 0.0)
        m = self.health.without_stuck_ranges(m, az, dt, self.obs)
        self._imu_silence(m)
        self.rates.feed(now, m)
        if m.imu is not None and m.imu.yaw_rad is not None:
            self._yaw = m.imu.yaw_rad
            self.rates.note_heading(now, self._yaw)

        status = self.status(now, m)
        mode = select_mode(status)
        feeds = TABLE_I[mode]

        bflow = m.bottom_flow if feeds.vx is Source.BOTTOM_FLOW else None
        fflow = m.front_flow if {Source.FRONT_FLOW, Source.BOTH_FLOWS} & {feeds.vy, feeds.vz} else None
        if m.imu is not None and (bflow is not None or fflow is not None):
            bflow, fflow = self._flow_to_heading(m.imu.roll_rad, m.imu.pitch_rad, bflow, fflow)
        # Each IMU reading is integrated once, over the time since the last one integrated: a
        # link that delivers readings out of step with the ticks (or stops) repeats the last one,
        # and that sample's acceleration is no longer what the vehicle does.
        self._imu_dt += dt
        if m.imu is not None and self._ledger.new("imu", m.imu.stamp_s):
            self._predict(ax, ay, az, min(self._imu_dt, p.imu_timeout_s))
            self._imu_dt = 0.0
        self.health.restart_after_stuck_flow(self.obs)

        if mode is EstimationMode.ALARM_NONE:
            if self._below_m is not None:
                self._below_m += self.obs[2].v * dt
        else:
            self._below_m = self.height.height_m
        live = (self._live_flow_rates("bottom", m.bottom_flow), self._live_flow_rates("front", m.front_flow))
        vx, vy = self._horizontal_speeds(now, m, feeds, status, bflow, fflow, live)
        self._front_range(now, m, vx)
        if self._yaw is not None:
            self.memory.advance(now, vx, vy, self._yaw, altitude_m=self.height.altitude_m, measured=mode >= 0)
        vz_flow = fflow.vz_m_s if feeds.vz is Source.FRONT_FLOW and fflow is not None else None
        climb = self._alarm_climb(now, mode)
        floor0, height0 = self.height.floor_offset_m, self.height.height_m
        height_floor = self._height(now, m, feeds, status, az, vz_flow, climb)
        if abs(self.height.floor_offset_m - floor0) > p.height_jump_m:
            # A floor step: the edge lies within the beam's footprint (its half-width at the longer
            # of the two ranges) of the centre, and the rotors reach body_radius_m further.
            reach = p.body_radius_m + max(height0, self.height.height_m) * math.tan(self._beam_half_angle_rad)
            self._edge = (self.memory.travel_m, self.memory.blind_s, reach)
        vz = self._vertical_speed(feeds, vz_flow, climb, dt, m)

        self.rates.note_speed(now, vx, vy)
        est = StateEstimate(
            height_m=self.height.height_m,
            height_floor_m=height_floor,
            altitude_m=self.height.altitude_m,
            vx_m_s=vx,
            vy_m_s=vy,
            vz_m_s=vz,
            mode=mode,
            odometry=None if self._yaw is None else (self.memory.x, self.memory.y, self._yaw),
            speed_noise_band_m_s=self._noise_band(feeds),
        )
        return est, self.clearances.update(now, m, est, self.front.value, self.rates.rates, self._yaw)

    def _noise_band(self, feeds: Feeds) -> tuple[float, float, float]:
        """``StateEstimate.speed_noise_band_m_s``: for each speed that the mode carries with the IMU
        (no sensor of Table I's row measures it), ``carried_noise_sigma`` standard deviations of the
        walk the IMU's measured noise has put into it. Chasing that walk, the speed loops tilt the
        vehicle at random under rotor vibration (docs/flight.md, Session 32)."""
        k = self.p.carried_noise_sigma
        ox, oy, oz = self.obs
        return (
            k * ox.imu_walk_sd if feeds.vx is Source.RANGE_RATES else 0.0,
            k * oy.imu_walk_sd if feeds.vy is Source.RANGE_RATES else 0.0,
            k * oz.imu_walk_sd if feeds.vz is Source.CARRIED_AND_VAL else 0.0,
        )

    def _imu_silence(self, m: Measurements) -> None:
        """Without an IMU reading nothing measures the vehicle's motion: the odometry cannot place
        what the sonars heard before, so the memory forgets it (the sonars refill it within a
        reading); when the IMU speaks again, the speeds carried through the silence are unknown by
        whatever the vehicle did meanwhile: restarted with the initial variance, the first flow or
        range rate is taken in full, not gated out against a confident stale speed."""
        if m.imu is None:
            self.memory.reset()
            self._imu_silent = self._had_imu
        elif self._imu_silent:
            for o in self.obs:
                o.restart(o.v)
            self._imu_silent = False
            self._imu_dt = 0.0  # the silence is not integrated with the first reading after it
        else:
            self._had_imu = True

    def _front_range(self, now: float, m: Measurements, vx: float) -> None:
        """The front range (the front clearance): carried between the sonar's 10 Hz samples by the
        x observer's speed, corrected by each sample. It measures no speed itself: in modes 2 and 3
        the front sonar's range rate is a measurement of the x observer like any other
        (``_horizontal_speeds``), so one observer holds the speed and the accelerometer's bias
        along x (a range observer with a rate and bias of its own learnt the swings of single
        noisy flow readings: docs/flight.md)."""
        self.front.propagate(now, rate=-vx)
        fs = m.front_sonar
        if fs is not None and fs.range_m is not None and self._ledger.new("front_range", fs.stamp_s):
            self.front.correct(fs.range_m, fs.stamp_s - SONAR_LATENCY_S)

    def _horizontal_speeds(self, now: float, m: Measurements, feeds: Feeds, status: SensorStatus,
                           bflow, fflow, live_rates) -> tuple[float, float]:
        """Horizontal speeds (Table I): the bottom flow's (modes 0 and 1), else the front sonar's
        range rate and the front flow's vy (modes 2 and 3); each is a measurement of its axis's observer
        (``SpeedObserver``), and the loops get the observer's speed. Taken as it came, the
        PX4Flow's output holds the body rotation its own gyro's scale error leaves in (scale x
        rate x distance), and the speed PID closed a loop through it and the attitude that
        diverged with height (a 4 % scale error rolling at 6 Hz reads 0.3 m/s at 2 m); the
        observer, carried by the IMU between readings, passes a fraction of that. In the alarm
        modes nothing in Table I measures them: the paper fills in zero, which leaves a moving
        vehicle coasting on (its speed loop sees no error to brake on); the observers carry the
        last speed on with the IMU instead, so the loop brakes, and the horizontal sonars' range
        rates correct them where they hear a wall (``SonarRangeRates.correct``)."""
        p = self.p
        ox, oy, _ = self.obs
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
            if self._ledger.new("bottom_flow", bflow.stamp_s):
                scale = min(1.0, tof.range_m / bs.range_m) if clamped and status.bottom_tof else 1.0  # type: ignore[union-attr,operator]
                fnoise = self._flow_noise(bs.range_m * scale, bflow.quality)  # type: ignore[union-attr,operator]
                ox.correct(bflow.vx_m_s * scale, fnoise, learn_bias=not clamped)
                oy.correct(bflow.vy_m_s * scale, fnoise, learn_bias=not clamped)
            if feeds.vy is Source.BOTH_FLOWS and fflow is not None and self._ledger.new("front_flow_vy", fflow.stamp_s):
                oy.correct(fflow.vy_m_s, self._flow_noise(m.front_sonar.range_m, fflow.quality))  # type: ignore[union-attr,arg-type]
        elif feeds.vx is Source.FRONT_RANGE_RATE:
            assert fflow is not None
            # Modes 2 and 3: vx is the front sonar's range rate (the slope of its last samples, as in
            # the alarm modes), which is the speed only while the heading holds: turning, the range to a wall at an angle changes without any
            # translation (pushed while yawing, the rate said 0.2 m/s while the vehicle sped up to
            # 0.77 m/s). While turning, vx is carried on with the IMU alone.
            self.rates.correct(now, self._yaw, self.obs, axes=(0,))
            if self._ledger.new("front_flow_vy", fflow.stamp_s):  # one key for this use in every mode
                oy.correct(fflow.vy_m_s, self._flow_noise(m.front_sonar.range_m, fflow.quality))  # type: ignore[union-attr,arg-type]
        else:
            self._angular_bottom_flow(now, m, live_rates[0])
            self._angular_front_flow(now, m, live_rates[1])
            self.rates.correct(now, self._yaw, self.obs)
        return ox.v, oy.v

    def _live_flow_rates(self, unit: str, flow: BottomFlow | FrontFlow | None) -> tuple[float, float] | None:
        """A PX4Flow's angular flow if this tick brings a new reading of ``unit`` ("bottom", "front")
        that does not repeat the one before it bit for bit (a stuck unit repeats its last reading,
        freshly stamped: the first repetition is already the same value), else None. Every reading
        is compared, in every mode, so a unit that stuck before an alarm mode began is known as
        stuck in it."""
        if flow is None or not self._ledger.new(f"{unit}_flow_rates", flow.stamp_s):
            return None
        rates = (flow.rate_x_rad_s, flow.rate_y_rad_s) if isinstance(flow, BottomFlow) else (flow.rate_y_rad_s, flow.rate_z_rad_s)
        if rates[0] is None or rates[1] is None:
            return None
        last = self._last_flow_rates.get(unit)
        self._last_flow_rates[unit] = rates  # type: ignore[assignment]
        return None if rates == last else rates  # type: ignore[return-value]

    def _angular_bottom_flow(self, now: float, m: Measurements, rates: tuple[float, float] | None) -> None:
        """The alarm modes' speed measurement under the vehicle: the bottom PX4Flow's angular flow
        (rad/s, the unit's gyro compensation in it) times the distance its camera sees, the height
        while the TeraRanger measures it (mode -1), else the last height measured carried on by the
        vertical speed (mode -2). Without its sonar the unit has no metric flow, but its camera
        still measures the angular one (``OPTICAL_FLOW_RAD``, which PX4's EKF2 and ArduPilot's EKF
        scale by their own height estimate). Carried by the IMU alone, the speeds drifted with the
        autopilot's attitude-estimate error (0.1 m/s^2 for half a degree): 0.3 m in a 2.7 s loss
        of every range sensor during a link-loss hold, 0.48 m under rotor vibration, a collision
        with a wall 1.1 m away (docs/flight.md, Session 36). A wrong distance (a box passed under
        the vehicle while blind) scales the speed, not its sign: the alarm modes command no
        horizontal speed, and a hold's zero is measured whatever the scale. The bias is not learnt
        from it. ``rates``: this tick's new reading, None when there is none or it repeats the one
        before it bit for bit (a stuck unit's, :meth:`_live_flow_rates`)."""
        p, bf = self.p, m.bottom_flow
        if rates is None or bf is None or self._below_m is None or now - bf.stamp_s > p.flow_timeout_s or bf.quality < p.flow_min_quality:
            return
        self._take_angular_flow(m, bf.stamp_s, rates, self._below_m, bf.quality, bottom=True)

    def _angular_front_flow(self, now: float, m: Measurements, rates: tuple[float, float] | None) -> None:
        """The alarm modes' measurement of the speeds along the front wall, as
        :meth:`_angular_bottom_flow` below the vehicle: the front PX4Flow's angular flow times the
        front range carried (:meth:`_front_range`, by the x speed since the last sonar sample). In
        mode -2 nothing else measures the vertical speed, and the bias the vertical observer
        carried in was the descent's error: a front flow of 0.2 m/s of noise at 4.8 m from its wall,
        taken a moment before every range sensor went, left the vertical bias 0.1 m/s^2 off, and
        the blind descent ran at 0.5 m/s instead of 0.2 into a box edge (docs/flight.md).
        Only a range the sonar measured when the alarm mode began is carried: one it last heard
        long before (a box heard at 2.4 m in the climb, the wall 6.2 m away out of its reach since)
        scaled the flow 2.6x short, and a fall of 1 m/s read as 0.3 (docs/flight.md)."""
        p, ff, d, last = self.p, m.front_flow, self.front.value, self.front.last_sample_t
        if rates is None or ff is None or d is None or now - ff.stamp_s > p.flow_timeout_s or ff.quality < p.flow_min_quality:
            return
        began = now if self._alarm_since is None else self._alarm_since
        if last is None or began - last > p.sonar_timeout_s:
            return
        self._take_angular_flow(m, ff.stamp_s, rates, d, ff.quality, bottom=False)

    def _take_angular_flow(self, m: Measurements, stamp: float, rates: tuple[float, float], d: float, quality: int,
                           *, bottom: bool) -> None:
        """A unit's angular flow times the distance ``d`` its camera sees, turned to the heading frame
        as a metric reading is, taken by the observers of the two axes it sees (bottom: x, y; front:
        y, z) with a metric reading's noise at that distance; the bias is not learnt from it."""
        d = max(d, SONAR_FLOOR_M)
        a, b = rates[0] * d, rates[1] * d
        imu = m.imu
        if bottom:
            bf = BottomFlow(stamp, a, b, quality)
            if imu is not None:
                bf, _ = self._flow_to_heading(imu.roll_rad, imu.pitch_rad, bf, None)
            (o1, z1), (o2, z2) = (self.obs[0], bf.vx_m_s), (self.obs[1], bf.vy_m_s)
        else:
            ff = FrontFlow(stamp, a, b, quality)
            if imu is not None:
                _, ff = self._flow_to_heading(imu.roll_rad, imu.pitch_rad, None, ff)
            (o1, z1), (o2, z2) = (self.obs[1], ff.vy_m_s), (self.obs[2], ff.vz_m_s)
        noise = self._flow_noise(d, quality)
        o1.correct(z1, noise, learn_bias=False)
        o2.correct(z2, noise, learn_bias=False)

    def _alarm_climb(self, now: float, mode: EstimationMode) -> float:
        """"+val." (Table I), filled in once the alarm mode has lasted ``alarm_descent_delay_s``:
        a brief loss of every range sensor is not yet a lost reference, and a vehicle that came to
        rest blind beside a box edge and descended at once brings its rotors onto that edge.

        Nor while an edge the downward sensors heard may be within the rotors' reach: the odometry
        has moved the vehicle less than that edge's reach since it was heard (:attr:`_edge`), for
        as long as the obstacle memory keeps what it heard while blind (``memory_keep_s``). Blind,
        the descent cannot tell which side of the edge it is on, and beside a box it meets the top
        edge with its rotors; the wait holds the height until the sensors come back (a range
        loss lasts seconds) or the memory's keep runs out (docs/flight.md, Limits).

        Nor, for as long, while the odometry has carried the rotors beyond the floor the downward
        beam covered when the loss began (its footprint's radius at the height then, less
        ``body_radius_m``): a vehicle that went blind at speed brakes blind over floor no sensor
        has seen, and an edge there (a box below the beam's reach when the loss began) met the
        rotors in the descent (docs/flight.md, Limits; since session 36 the PX4Flows measure that
        travel). In both alarm modes: mode -1's TeraRanger, a 3 deg laser, sees below the centre,
        not below the rotors."""
        p = self.p
        if mode >= 0:
            self._alarm_since = None
        elif self._alarm_since is None:
            self._alarm_since = now
            below = self._below_m if self._below_m is not None else 0.0
            # How far the centre may move before the rotors reach floor the beam did not cover. Lower
            # (below 1 m) the footprint does not cover the rotors' reach even where the loss began,
            # and there is no margin to judge by: the paper's descent (a take-off blind at 0.5 m
            # waited on every centimetre of drift, and its climb went on to 2.5 m).
            margin = below * math.tan(self._beam_half_angle_rad) - self.p.body_radius_m
            self._seen = (self.memory.x, self.memory.y, margin) if margin > 0.0 else None
        alarm_s = 0.0 if self._alarm_since is None else now - self._alarm_since
        if mode >= 0 or alarm_s < p.alarm_descent_delay_s:
            return 0.0
        if self._edge is not None and alarm_s < p.memory_keep_s:
            travel, blind, reach = self._edge
            if self.memory.travel_m - travel < reach and self.memory.blind_s - blind <= p.memory_keep_s:
                return 0.0
        if self._seen is not None and alarm_s < p.memory_keep_s:
            x0, y0, radius = self._seen
            if math.hypot(self.memory.x - x0, self.memory.y - y0) > radius:
                return 0.0
        return p.alarm_climb_m_s

    def _height(self, now: float, m: Measurements, feeds: Feeds, status: SensorStatus, az: float,
                vz_flow: float | None, climb: float) -> float | None:
        """Height: bottom PX4Flow sonar, else TeraRanger, else integration (mode 3: the front
        flow's vz; mode -2: the alarm value, Table I "i"). Returns the height below which the
        measuring sensor's reading is its clamp within its noise (the flight machine's "down").

        Each range sensor within its range: below the bottom sonar's clamp zone the TeraRanger,
        which reads down to 0.20 m, measures the height (the sonar reads 0.30 m there whether
        the vehicle hovers 0.3 m up or stands on the floor: a hop taken for the touchdown)."""
        p = self.p
        source, latency, height_floor = None, 0.0, None
        if feeds.height is Source.BOTTOM_SONAR:
            source, latency, height_floor = m.bottom_sonar, SONAR_LATENCY_S, SONAR_FLOOR_M
            if status.bottom_tof and source.range_m < p.sonar_clamp_zone_m:  # type: ignore[union-attr,operator]
                source, latency, height_floor = m.bottom_tof, TOF_LATENCY_S, TOF_FLOOR_M
        elif feeds.height is Source.TERARANGER:
            source, latency, height_floor = m.bottom_tof, TOF_LATENCY_S, TOF_FLOOR_M
        if source is None and vz_flow is None:
            self.height.propagate(now, rate=climb)
        else:
            self.height.propagate(now, az, vz_flow)
        if source is not None and self._ledger.new("height", source.stamp_s):
            self.height.update(source.range_m, source.stamp_s - latency)  # type: ignore[arg-type]
        return height_floor

    def _vertical_speed(self, feeds: Feeds, vz_flow: float | None, climb: float, dt: float, m: Measurements) -> float:
        """Vertical speed (Table I): the front flow's, else the height's derivative, plus "+val."
        in the alarm modes.

        "+val." makes the speed loop descend. Filled in alone, a constant +val is an error the
        loop never removes: it descended faster and faster (every range sensor lost, 0.4-0.8 m/s
        into a coaming below). The val is added to the vertical observer's speed instead (carried
        on with the IMU), so the loop settles at a steady descent of val. Mode -1 still has the
        TeraRanger's rate. The front flow's vz is a measurement of the vertical observer; without
        it, the height observer's rate (Table I's derivative) is, but one that corrects the speed
        and not the bias: that rate is itself the IMU's integral corrected by a 10 Hz range, with
        the IMU's errors in it (taken as a bias measurement, it walked the bias to -0.2 m/s^2 over
        a climb, and the carried alarm descent sped up to 0.67 m/s). In mode -2 the speed is
        carried on with the IMU and relaxes towards zero at ``alarm_vz_leak_m_s2``: the vertical
        bias a short floor calibration leaves (~0.02 m/s^2) is unobservable without a vertical
        flow, and the loop, holding the carried speed at -val, turned it into a descent that
        slowed from 0.2 to 0.09 m/s within 7 s (alarm_none_descent)."""
        oz, noise = self.obs[2], self.p.speed_noise_m_s
        if vz_flow is not None:
            if self._ledger.new("front_flow_vz", m.front_flow.stamp_s):  # type: ignore[union-attr]
                oz.correct(vz_flow, self._flow_noise(m.front_sonar.range_m, m.front_flow.quality))  # type: ignore[union-attr,arg-type]
        elif feeds.vz in (Source.HEIGHT_RATE, Source.HEIGHT_RATE_AND_VAL):
            oz.correct(self.height.rate_m_s, noise, learn_bias=False)
        if feeds.vz is Source.HEIGHT_RATE_AND_VAL:
            return self.height.rate_m_s + climb
        if feeds.vz is Source.CARRIED_AND_VAL:
            oz.v -= math.copysign(min(abs(oz.v), self.p.alarm_vz_leak_m_s2 * dt), oz.v)
            return oz.v + climb
        return vz_flow if vz_flow is not None else self.height.rate_m_s

    def _flow_noise(self, range_m: float, quality: int) -> float:
        """The speed noise of a PX4Flow reading: its angular noise times the range it sees (it scales
        its angular flow by that range; PX4's EKF2 weighs flow in rad/s), never below a range
        rate's. Taken with one speed noise whatever the range, the front flow 4.9 m from a wall
        (0.2 m/s of noise there) counted as much as at 2 m and moved the vertical bias enough to
        double the alarm descent that followed; without the floor, the flow at 1 m made the tilt
        jitter over Fig. 7's passes, so near the wall a reading counts as a range rate does. The
        angular noise follows the reading's quality as PX4's EKF2 takes it (``EKF2_OF_N_MIN`` at
        255 to ``EKF2_OF_N_MAX`` at ``EKF2_OF_QMIN``, linearly): on low texture the quality wanders
        about the threshold, and one noise for all made the flow come and go (docs/flight.md)."""
        p = self.p
        span = 255 - p.flow_min_quality
        w = min(1.0, max(0.0, (quality - p.flow_min_quality) / span)) if span > 0 else 1.0
        angular = p.flow_noise_rad_s * w + p.flow_noise_worst_rad_s * (1.0 - w)
        return max(p.speed_noise_m_s, angular * range_m)

    def _flow_to_heading(self, roll: float, pitch: float, bflow, fflow):
        """The PX4Flow units measure in the body frame; the estimate is in the heading frame.
        Turned by the autopilot's ESTIMATED roll and pitch (small angles: v_h = R_y R_x v_b), the
        component a unit does not see taken from the last estimate. Left in the body frame, a
        0.05 rad pitch at 0.4 m/s reads as a 0.02 m/s climb."""
        vx_prev = self.obs[0].v
        vz_prev = self.obs[2].v
        if bflow is not None:
            bflow = BottomFlow(bflow.stamp_s, bflow.vx_m_s + pitch * vz_prev, bflow.vy_m_s - roll * vz_prev, bflow.quality)
        if fflow is not None:
            vx = bflow.vx_m_s if bflow is not None else vx_prev
            fflow = FrontFlow(
                fflow.stamp_s, fflow.vy_m_s - roll * vz_prev, fflow.vz_m_s - pitch * vx + roll * fflow.vy_m_s, fflow.quality
            )
        return bflow, fflow

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
