"""Flight control state machine (the paper's Fig. 4): landed, taking_off, flying, descending,
landing."""

from __future__ import annotations

import enum

from inspect_pipe.flight_stack.estimation import SONAR_FLOOR_M
from inspect_pipe.flight_stack.messages import EstimationMode, StateEstimate, message
from inspect_pipe.flight_stack.params import BehaviorParams, FlightMachineParams

__all__ = ["FlightMachine", "FlightState", "FlightEvents", "ImpactDetector"]


class FlightState(str, enum.Enum):
    LANDED = "landed"
    TAKING_OFF = "taking_off"
    FLYING = "flying"
    DESCENDING = "descending"
    LANDING = "landing"


@message
class FlightEvents:
    """What the machine reacts to in one tick."""

    takeoff_pressed: bool = False
    land_requested: bool = False  # land button or low_battery_land
    high_thrust: bool = False  # collective thrust at or above hover
    # IMU jolt upwards with thrust at most hover, or the floor's lasting push where no height is
    # measured (OnboardStack._floor_holds): the floor stopped us
    impact: bool = False


class ImpactDetector:
    """The floor's jolt: an upward acceleration the last set-point does not explain (the
    controller's ``unexplained_lift_m_s2``) beyond ``accel_m_s2`` and beyond ``noise_sigma`` times
    the RMS of that unexplained lift over the last ~1 s of flight. Rotor vibration makes that
    noise: at 1.15 m/s^2 a 3 m/s^2 spike came by chance within 0.2 s of an alarm mode, the vehicle
    took it for a touchdown and ramped its thrust down in mid-air."""

    def __init__(self, accel_m_s2: float, noise_sigma: float, window_ticks: int = 50) -> None:
        self.accel_m_s2, self.noise_sigma, self.window_ticks = accel_m_s2, noise_sigma, window_ticks
        self.mean_square = 0.0

    def update(self, lift_m_s2: float, airborne: bool) -> bool:
        """Whether ``lift_m_s2`` is a jolt; ``airborne``: flying or descending (the noise is
        learnt there, not on the floor or while landing)."""
        threshold = max(self.accel_m_s2, self.noise_sigma * self.mean_square ** 0.5)
        if airborne:
            self.mean_square += (min(lift_m_s2 * lift_m_s2, threshold * threshold) - self.mean_square) / self.window_ticks
        return lift_m_s2 > threshold


class FlightMachine:
    """Transitions on user buttons, the estimated height, time and thrust. ``now`` passed in.

    landed -> taking_off: take-off button (unless landing is requested, e.g. low battery).
    taking_off -> flying: height above ``flying_height_m`` or ``takeoff_high_thrust_s`` at
    high thrust. taking_off/flying -> descending: land button or low battery.
    descending -> landing: height below ``flying_height_m``.
    flying -> landing: alarm mode -1 below that height, or in any alarm mode the jolt of
    touching the floor (mode -2 has no height reference: the descent ends on the floor).
    landing -> landed: touchdown (height at the sonar's minimum, no vertical speed) and the thrust
    ramp-down finished, or the ramp's time-out (only without a height reference or below 0.5 m).
    """

    def __init__(self, params: FlightMachineParams | None = None, behaviors: BehaviorParams | None = None) -> None:
        self.p = params or FlightMachineParams()
        # No height measured: the fastest the vehicle may be descending, twice the largest vertical
        # speed the behaviours command (what a jolt is judged against, see ``update``).
        self.fastest_descent_m_s = 2.0 * (behaviors or BehaviorParams()).max_vertical_speed_m_s
        self.state = FlightState.LANDED
        self.entered_s = 0.0
        self.high_thrust_s = 0.0
        self.touchdown_s: float | None = None
        self._ground_s = 0.0  # how long the landing has looked like the ground
        self._bounced = False  # a touchdown of this landing was cancelled: the vehicle bounced
        self._measured: tuple[float, float] | None = None  # (height, time) last measured in flight

    def _go(self, state: FlightState, now: float) -> None:
        self.state = state
        self.entered_s = now
        self.high_thrust_s = 0.0
        self.touchdown_s = None
        self._ground_s = 0.0
        self._bounced = False

    def time_in_state(self, now: float) -> float:
        return now - self.entered_s

    def update(self, now: float, dt: float, est: StateEstimate, ev: FlightEvents) -> FlightState:
        p, s = self.p, self.state
        # The height last measured in flight (mode -1's TeraRanger counts; mode 3 integrates its
        # height, mode -2 has none): what bounds a jolt where no height is measured, below.
        unmeasured = est.mode < 0 or est.mode == EstimationMode.FRONT
        if s is FlightState.LANDED:
            self._measured = None
        elif est.mode == EstimationMode.ALARM_TOF or not unmeasured:
            self._measured = (est.height_m, now)
        if s is FlightState.LANDED:
            if ev.takeoff_pressed and not ev.land_requested:
                self._go(FlightState.TAKING_OFF, now)
        elif s is FlightState.TAKING_OFF:
            self.high_thrust_s = self.high_thrust_s + dt if ev.high_thrust else 0.0
            if ev.land_requested:
                self._go(FlightState.DESCENDING, now)
            elif est.mode >= 0 and est.height_m >= p.flying_height_m or self.high_thrust_s >= p.takeoff_high_thrust_s:
                self._go(FlightState.FLYING, now)
        elif s is FlightState.FLYING or s is FlightState.DESCENDING:
            # No measured height or vertical speed (alarm modes, whose vertical speed is the
            # filled-in '+val.'; mode 3 integrates the height): the floor's jolt is the touchdown.
            # A vehicle that drifted into front-wall range during an alarm descent reached the
            # floor in mode 3 and sat there "flying". Mode -1 still measures the height (the
            # TeraRanger): a jolt above flying_height_m is not the floor (a vibration fault's
            # first spikes at 3.5 m ramped the thrust down in mid-air).
            # Mode -2 and mode 3 have no height to test a jolt by, but the last measured one
            # still bounds it: a jolt sooner than a descent at ``fastest_descent_m_s`` (1.2 m/s)
            # from that height could reach the floor is not the floor (every range sensor lost at 2.06 m,
            # a vibration fault's first spikes 0.7 s later: the ramp-down began there and the
            # vehicle fell at 4 m/s; found by pairing fault classes by hand, 2026-11-28).
            high = est.mode == EstimationMode.ALARM_TOF and est.height_m >= p.flying_height_m
            if unmeasured and not high and self._measured is not None:
                h, t = self._measured
                high = now - t < (h - p.flying_height_m) / self.fastest_descent_m_s
            if unmeasured and ev.impact and not high:
                self._go(FlightState.LANDING, now)
                self.touchdown_s = now
            elif s is FlightState.FLYING and ev.land_requested:
                self._go(FlightState.DESCENDING, now)
            elif (s is FlightState.DESCENDING or est.mode == EstimationMode.ALARM_TOF) and est.height_m < p.flying_height_m:
                self._go(FlightState.LANDING, now)
        elif s is FlightState.LANDING:
            # Down: the height at its sensor's minimum, where it clamps, within its noise (the
            # estimator says which sensor measures it: ``StateEstimate.height_floor_m``); with no
            # measured height, the sonar's.
            down_m = est.height_floor_m if est.height_floor_m is not None else SONAR_FLOOR_M
            at_floor = est.height_m <= down_m
            # The jolt is the floor only where no height is measured, or where the measured one is at
            # its floor too (a vibration fault that began in the descent
            # gave a spike at 0.45 m, 0.08 m above the floor by the sonar; the thrust ramped down there
            # and the vehicle hit the floor at 1.2 m/s). A true touchdown away from that reading is
            # still found by the height and speed at rest, ``touchdown_confirm_s`` later.
            measured = not unmeasured or est.mode == EstimationMode.ALARM_TOF
            impact = ev.impact and (at_floor or not measured)
            on_ground = (at_floor and abs(est.vz_m_s) < 0.15) or impact
            # The time-out stands in for a touchdown the sensors cannot confirm; with a valid
            # height well above the floor, or still descending, the vehicle is not down (safety campaign: a battery sag
            # ended mid-landing, the vehicle climbed back to 1 m, the time-out cut the thrust
            # there and it fell at 2.3 m/s).
            timed_out = self.time_in_state(now) > p.flying_height_m / p.landing_speed_m_s + 3.0 and (
                unmeasured or (est.height_m <= 0.5 and abs(est.vz_m_s) < 0.1)
            )
            # On the ground for a moment, not at a bounce's turning point (safety campaign: a
            # battery sag's recovery bounced the vehicle through 0.35 m with zero speed; the ramp
            # began and it fell from 0.57 m). A vehicle back above 0.5 m, or rising at more than
            # 0.2 m/s (a battery sag ending after touchdown), is not down.
            if on_ground and not impact:
                self._ground_s = self._ground_s + dt
            else:
                self._ground_s = 0.0
            if self.touchdown_s is not None and not unmeasured and (est.height_m > 0.5 or est.vz_m_s > 0.2):
                self.touchdown_s = None
                self._bounced = True
            # With no height measured, the jolt taken for the floor may have been a vibration fault's
            # first spikes in mid-air, past the time bound above (every range sensor lost at 1.47 m,
            # the spikes 1.2 s later: the ramp-down began and the vehicle fell 1.3 m onto the tank
            # top at 2.6 m/s). On the floor the vehicle cannot go on
            # descending: a carried vertical speed below the fastest descent the machine commands
            # (``descend_speed_m_s``) once the ramp began is a fall, and the vehicle flies on (the
            # alarm descent resumes; a true touchdown, where it stops, is taken at the next jolt).
            if self.touchdown_s is not None and unmeasured and est.vz_m_s < -p.descend_speed_m_s:
                self.touchdown_s = None
                self._go(FlightState.FLYING, now)
                return self.state
            # After a bounce, the top of the next hop also reads "at the sensor's minimum, not
            # moving" for a moment (the sonar's minimum is 0.3 m): only a longer rest, or the
            # floor's jolt, is a touchdown then (safety campaign: a battery sag ended at touchdown,
            # the vehicle hopped, the ramp began at the hop's top, 0.23 m up, and it fell at 1 m/s).
            confirm_s = p.touchdown_confirm_s * (3.0 if self._bounced else 1.0)
            if self.touchdown_s is None and (self._ground_s >= confirm_s or impact or timed_out):
                self.touchdown_s = now
            if self.touchdown_s is not None and now - self.touchdown_s >= p.landing_ramp_s:
                self._go(FlightState.LANDED, now)
        return self.state

    def thrust_cap(self, now: float, hover_thrust_frac: float) -> float:
        """Landing: after touchdown the thrust ramps down linearly from hover to zero."""
        if self.state is FlightState.LANDING and self.touchdown_s is not None:
            k = 1.0 - (now - self.touchdown_s) / self.p.landing_ramp_s
            return max(0.0, hover_thrust_frac * k)
        return 1.0
