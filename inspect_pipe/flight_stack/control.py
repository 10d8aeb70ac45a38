"""Speed and height control: PID speed controllers on X, Y, Z and a height PID that replaces the
vertical speed PID when the vertical command is zero. Output is the attitude and thrust set-point
that the autopilot firmware's attitude controller tracks."""

from __future__ import annotations

import enum
import math

from inspect_pipe.flight_stack.messages import AttitudeSetpoint, SpeedCommand, StateEstimate
from inspect_pipe.flight_stack.observers import WhiteNoiseMeter
from inspect_pipe.flight_stack.params import BehaviorParams, ControlParams

__all__ = ["FlightController", "PID", "VerticalMode"]

G = 9.81


class PID:
    """PID with a clamped integrator and optional measured derivative. Time step passed in."""

    def __init__(
        self, kp: float, ki: float, kd: float = 0.0, *, integral_limit: float = math.inf, integrate_band: float = math.inf,
    ) -> None:
        self.kp, self.ki, self.kd = kp, ki, kd
        self.integral_limit = integral_limit
        # Integral separation: errors beyond ``integrate_band`` are transients (a braking
        # manoeuvre the reference model has not followed, a speed estimate restarted at a new
        # measurement), not a missing trim; integrated, they left a trim behind that crept the
        # vehicle back from the wall after a stop.
        self.integrate_band = integrate_band
        self.integral = 0.0
        self._prev_error: float | None = None

    def reset(self, integral: float = 0.0) -> None:
        self.integral = integral
        self._prev_error = None

    def update(
        self, error: float, dt: float, *, rate: float | None = None, freeze: bool = False,
        integrate: float | None = None,
    ) -> float:
        """``rate``: d(error)/dt when measured directly (avoids differentiating noise);
        ``integrate``: the error the integrator takes, when not ``error`` (a reference model's
        tracking error: a command step is the P term's to follow, so the integrator does not wind
        up on a step; the fast unwinding this PID had before the reference models is gone with it,
        docs/flight.md)."""
        ie = error if integrate is None else integrate
        if not freeze and dt > 0.0 and abs(ie) <= self.integrate_band:
            self.integral = max(-self.integral_limit, min(self.integral_limit, self.integral + self.ki * ie * dt))
        if rate is None:
            rate = 0.0 if self._prev_error is None or dt <= 0.0 else (error - self._prev_error) / dt
        self._prev_error = error
        return self.kp * error + self.integral + self.kd * rate


class AccelObserver:
    """Disturbance observer on one axis, from the IMU (inner acceleration feedback, as
    ArduPilot's vertical acceleration loop): the set-point sent should give a nominal vehicle an
    acceleration (``applied``, through the attitude and motor lag ``lag_s``, plus the nominal
    response such as rotor drag); the IMU says what it gave. The difference, low-passed with
    ``tau_s``, is a disturbance: a thrust shortfall (battery sag, weaker motors, a heavier
    vehicle) or wind. It is added to the command at once, instead of waiting for a position or
    speed loop to meet it with an error, which a battery sag or a gust had time to turn into
    lost height or a stop line passed (docs/flight.md, Control). What it does not make up (the
    IMU's bias, beyond ``limit``) is left to the integrators."""

    def __init__(self, *, tau_s: float, lag_s: float, limit: float) -> None:
        self.tau_s, self.lag_s, self.limit = tau_s, lag_s, limit
        self.value = 0.0  # m/s^2 missing from the nominal response
        self._expected: float | None = None  # the applied acceleration through the lag
        self._applied = 0.0
        self._nominal = 0.0
        # The accelerometer's bias, learnt at rest on the floor (where the true acceleration is
        # 0): uncorrected, the observer would "make up" the bias and push the vehicle with it.
        self.bias = 0.0
        self._bias_n = 0
        # The IMU's noise as this observer sees it: the white noise of its surprise over 1 s, as
        # ImpactDetector's window (50 ticks; a gust's smooth push adds little)
        self.noise = WhiteNoiseMeter(window_s=1.0)

    def reset(self) -> None:
        self.value, self._expected, self._applied, self._nominal = 0.0, None, 0.0, 0.0
        self.noise.forget_last()

    def calibrate(self, measured: float | None) -> None:
        """One IMU reading taken at rest (landed): running mean of the bias, over the last ~100."""
        if measured is None:
            return
        self._bias_n = min(self._bias_n + 1, 100)
        self.bias += (measured - self.bias) / self._bias_n

    def applied(self, accel: float) -> None:
        """The acceleration the set-point just sent asks of a nominal vehicle."""
        self._applied = accel

    def update(self, measured: float | None, dt: float, *, nominal: float = 0.0) -> float:
        """New estimate from the IMU's ``measured`` acceleration since the last set-point;
        ``nominal``: the nominal vehicle's own acceleration (drag), low-passed with ``tau_s``
        (it comes from a noisy speed estimate)."""
        if self.tau_s <= 0.0 or dt <= 0.0:
            return self.value
        self._nominal += (nominal - self._nominal) * min(1.0, dt / (self.tau_s + dt))
        nominal = self._nominal
        prev = self._expected
        self._expected = self._applied if prev is None else prev + (self._applied - prev) * min(1.0, dt / (self.lag_s + dt))
        if measured is not None and prev is not None:
            surprise = self._expected + nominal - (measured - self.bias)
            self.noise.add(surprise, dt)
            d = self.value + (surprise - self.value) * min(1.0, dt / self.tau_s)
            self.value = max(-self.limit, min(self.limit, d))
        return self.value

    def value_noise(self, dt: float) -> float:
        """Standard deviation that the IMU's noise alone gives :attr:`value` (a white noise through
        the first-order low-pass of ``tau_s``)."""
        if self.tau_s <= 0.0 or dt <= 0.0:
            return 0.0
        return math.sqrt(self.noise.variance * dt / (2.0 * self.tau_s))

    def surprise(self, measured: float) -> float:
        """How much more acceleration the IMU felt than the last set-point explains for this
        vehicle (its nominal response less the shortfall learnt so far)."""
        expected = (self._expected if self._expected is not None else self._applied) - self.value
        return measured - self.bias - expected


def _beyond(value: float, band: float) -> float:
    """``value`` less ``band`` towards zero (0 within the band)."""
    return math.copysign(max(abs(value) - band, 0.0), value)


class VerticalMode(enum.Enum):
    SPEED = "speed"
    HEIGHT = "height"


class FlightController:
    """Runs on the paper's secondary ARM7: speed command + state estimate -> attitude set-point."""

    def __init__(self, params: ControlParams | None = None, behaviors: BehaviorParams | None = None) -> None:
        p = self.p = params or ControlParams()
        # The speed loop's lag, as the behaviours predict a stop with it: where a vertical command
        # ends, the height is latched where the vehicle will come to rest.
        self.latch_lead_s = (behaviors or BehaviorParams()).response_time_s
        lim = p.integral_limit_m_s2
        # PI on the XY speeds: no derivative (the flow speed is too noisy to differentiate), and
        # no leak of the integrators (a leak makes the loop proportional-only against whatever
        # bias is left: steady speeds ran 10 % below the command, 0.179 m/s for 0.20).
        xy = dict(integral_limit=lim, integrate_band=p.speed_integrate_band_m_s)
        self.pid_vx = PID(p.speed_kp_1_s, p.speed_ki_1_s2, **xy)
        self.pid_vy = PID(p.speed_kp_1_s, p.speed_ki_1_s2, **xy)
        vlim = p.vertical_trim_limit_m_s2
        self.pid_vz = PID(p.vz_kp_1_s, p.vz_ki_1_s2, integral_limit=vlim)
        self.pid_height = PID(p.height_kp_1_s2, p.height_ki_1_s3, p.height_kd_1_s, integral_limit=vlim)
        self.height_ref_m: float | None = None
        self.vertical_mode = VerticalMode.SPEED
        self._vz_ref: float | None = None  # the vertical speed reference model (see update)
        self._vxy_ref: tuple[float, float] | None = None  # the horizontal speeds' reference model
        # Disturbance observers (m/s^2 the IMU shows missing): thrust shortfall, wind.
        lag = p.accel_observer_lag_s
        obs_xy = dict(tau_s=p.accel_observer_tau_s, limit=p.accel_observer_xy_limit_m_s2, lag_s=lag)
        self.obs_x = AccelObserver(**obs_xy)
        self.obs_y = AccelObserver(**obs_xy)
        self.obs_z = AccelObserver(tau_s=p.accel_observer_tau_s, limit=p.vertical_trim_limit_m_s2, lag_s=lag)

    def reset(self) -> None:
        for pid in (self.pid_vx, self.pid_vy, self.pid_vz, self.pid_height):
            pid.reset()
        self.height_ref_m = None
        self.vertical_mode = VerticalMode.SPEED
        self._vz_ref = None
        self._vxy_ref = None
        for o in (self.obs_x, self.obs_y, self.obs_z):
            o.reset()

    @property
    def accel_bias(self) -> tuple[float, float, float]:
        """The accelerometer's bias learnt at rest (heading frame, m/s^2)."""
        return (self.obs_x.bias, self.obs_y.bias, self.obs_z.bias)

    def unexplained_lift_m_s2(self, az_measured: float) -> float:
        """How much more upward acceleration the IMU felt than the last set-point explains, for
        this vehicle (nominal response less the shortfall the observer has learnt): the floor's
        jolt at touchdown. Judged against the nominal hover thrust instead, a light vehicle's
        ordinary climb is such a jolt."""
        return self.obs_z.surprise(az_measured)

    def calibrate_at_rest(self, accel_measured: tuple[float, float, float] | None) -> None:
        """An IMU reading taken on the floor, motors off: it is the accelerometer's bias."""
        if accel_measured is not None:
            for o, a in zip((self.obs_x, self.obs_y, self.obs_z), accel_measured):
                o.calibrate(a)

    def hold_height(self, ref_m: float) -> None:
        self.height_ref_m = ref_m

    def hand_trim_to_observer(self) -> None:
        """The vertical trim found without the IMU becomes the disturbance observer's, which takes
        the IMU from now on (the take-off ends: on the floor the IMU cannot tell a thrust
        shortfall, so the ramp finds it in the integrator). Left in the integrator it is counted
        twice: the observer makes up whatever the vehicle does less than the set-point asks, the
        integrator's trim included, so that trim became an extra climb only the height error
        could cancel (-28 % thrust: the hover at 1 m overshot to 2.1 m). Bumpless: the thrust
        asked is the same on either side."""
        o, lim = self.obs_z, self.obs_z.limit
        o.value = max(-lim, min(lim, o.value + self.pid_vz.integral))
        self.pid_vz.integral = 0.0

    def update(
        self,
        cmd: SpeedCommand,
        est: StateEstimate,
        dt: float,
        *,
        allow_height_hold: bool = True,
        freeze_integrators: bool = False,
        freeze_xy_integrators: bool = False,
        relax_xy_integrators: bool = False,
        thrust_cap_frac: float = 1.0,
        accel_measured: tuple[float, float, float] | None = None,
    ) -> AttitudeSetpoint:
        """``accel_measured``: the IMU's acceleration (heading frame) since the last set-point,
        given while airborne: it feeds the disturbance observers (None leaves them as they are).
        ``relax_xy_integrators``: no speed is measured; the XY trims relax to zero and take nothing."""
        p = self.p
        freeze_xy = freeze_integrators or freeze_xy_integrators
        # Drag feed-forward: the trim that holds a commanded speed against rotor drag comes from
        # the command, not from the integrators, so it vanishes the moment the command drops to
        # zero. Integrated, it stayed behind after a stop (at the ki of 0.6 /s^2 it then had, it
        # took seconds to unwind) and crept the vehicle past the stop line at a wall (safety
        # campaign: link-loss "hover" 2 s late while the repulsion pushed it back out, overshoot).
        ff = p.speed_drag_ff_1_s
        # The XY integrators take the speed's deviation from a reference model of the command (a
        # first-order lag with the P term's time constant), as the vertical one does below: a
        # command step is the P term's to follow, so the integrators can be fast (ki 5 /s^2, an
        # integral time of 0.44 s, damping 0.49 with kp 2.2) without winding up on every step, and
        # they then follow the air's slowly varying push (0.04 m/s^2 rms, 2 s correlation in the
        # simulator) that the P term alone left as 0.02 m/s of speed error: inspection passes
        # 0.173-0.239 m/s for 0.20 on 20 seeds of Fig. 7 with ki 0.6 on the raw error, 9 of 60
        # passes off by more than 0.01 with ki 3, none of 60 on fresh seeds with 5 (docs/flight.md).
        rx, ry = self._vxy_ref if self._vxy_ref is not None else (est.vx_m_s, est.vy_m_s)
        k = min(1.0, p.speed_kp_1_s * dt)
        rx, ry = rx + (cmd.vx_m_s - rx) * k, ry + (cmd.vy_m_s - ry) * k
        self._vxy_ref = (rx, ry)
        if relax_xy_integrators:
            # Nothing measures the speed (the alarm modes): the trims take nothing, and what they
            # hold relaxes at the rate they build. Held, a trim that had answered a gust pushes on
            # after the gust ended, unseen.
            freeze_xy = True
            keep = max(0.0, 1.0 - p.speed_ki_1_s2 / p.speed_kp_1_s * dt)
            self.pid_vx.integral *= keep
            self.pid_vy.integral *= keep
        # Where no sensor measures the speed (the alarm modes), an error the IMU's own noise could
        # have made of the carried speed is left alone (``StateEstimate.speed_noise_band_m_s``).
        bx, by, bz = est.speed_noise_band_m_s
        ax = self.pid_vx.update(_beyond(cmd.vx_m_s - est.vx_m_s, bx), dt, freeze=freeze_xy, integrate=rx - est.vx_m_s)
        ay = self.pid_vy.update(_beyond(cmd.vy_m_s - est.vy_m_s, by), dt, freeze=freeze_xy, integrate=ry - est.vy_m_s)
        ax += ff * cmd.vx_m_s
        ay += ff * cmd.vy_m_s
        mode = VerticalMode.HEIGHT if allow_height_hold and abs(cmd.vz_m_s) < 1e-6 else VerticalMode.SPEED
        if mode is VerticalMode.HEIGHT:
            if self.vertical_mode is not VerticalMode.HEIGHT or self.height_ref_m is None:
                if self.height_ref_m is None:
                    # Hold where the vehicle will come to rest, not where the stick was centred:
                    # no bounce back after a climb or a descent. Its speed is the one the speed
                    # loop was driving it at (the reference model below), not the estimate of
                    # that tick: scaled by the lead, one noisy reading moved the hold by 0.19 m
                    # (a 0.15 s climb latched 0.1 m below where it began, and over a coaming the
                    # rotors then skimmed its top: docs/flight.md, Session 35).
                    vz = self._vz_ref if self._vz_ref is not None else est.vz_m_s
                    self.height_ref_m = est.altitude_m + vz * self.latch_lead_s
                # Bumpless hand-over: the speed loop's trim becomes the height loop's.
                self.pid_height.reset(self.pid_vz.integral)
            err = self.height_ref_m - est.altitude_m
            # Integrate only near the reference (a climb to it would otherwise wind the trim up),
            # or while far from it and not moving towards it: the trim is missing (a heavier
            # vehicle or weaker motors than nominal would otherwise sit below the reference, or
            # on the floor, for ever: the safety campaign's +-30 % mass/thrust episodes).
            band = p.height_integral_band_m
            near = abs(err) < band
            towards = min(0.5 * abs(err), 0.3)  # m/s: a vehicle with its trim approaches at least this fast
            stalled = (err > band and est.vz_m_s < towards) or (err < -band and est.vz_m_s > -towards)
            az = self.pid_height.update(err, dt, rate=-est.vz_m_s, freeze=freeze_integrators or not (near or stalled))
            trim = self.pid_height.integral
        else:
            if self.vertical_mode is VerticalMode.HEIGHT:
                # Hand over the height loop's trim (its integrator), not its whole output: its P and
                # D terms answer its own height error and the noisy vertical speed of that tick,
                # and kept as trim they became a lasting push (0.2 m/s^2 from one tick's D term
                # made Fig. 7's 0.2 m/s descent 0.218 m/s; into an alarm mode, the answer to the
                # alarm's filled-in state drove its descent to 0.48 m/s instead of 0.2).
                # A thrust shortfall the P term was making up (a battery sag) is the vertical
                # disturbance observer's, which carries on across the hand-over.
                lim = self.pid_vz.integral_limit
                self.pid_vz.reset(max(-lim, min(lim, self.pid_height.integral)))
                self._vz_ref = None
            self.height_ref_m = None
            # The integrator takes the speed's deviation from a reference model of the command (a
            # first-order lag with the P term's own time constant, 1 / vz_kp), not from the
            # command itself: a step of the command is the P term's to follow, and integrated it
            # wound up a trim the vehicle overshot with (0.27 m/s for 0.2 after each inspection
            # step, 1.5 s to unwind). A missing trim still shows as a lasting deviation, and at a
            # steady command the model is the command: no steady error either way. In mode -2 the
            # P term leaves alone the band the IMU's noise could have made of the carried vz; the
            # integrator does not (with the band, the alarm descent met the floor too softly for
            # the touchdown's jolt in alarm_stuck_teraranger: docs/flight.md, Session 33).
            if self._vz_ref is None:
                self._vz_ref = est.vz_m_s
            self._vz_ref += (cmd.vz_m_s - self._vz_ref) * min(1.0, p.vz_kp_1_s * dt)
            az = self.pid_vz.update(_beyond(cmd.vz_m_s - est.vz_m_s, bz), dt, freeze=freeze_integrators,
                                    integrate=self._vz_ref - est.vz_m_s)
            trim = self.pid_vz.integral
        self.vertical_mode = mode

        meas = accel_measured or (None, None, None)
        # Rotor drag is part of the nominal response: only what drag does not explain is a
        # disturbance (wind).
        drag = p.accel_observer_drag_1_s
        # What the attitude estimate's transient can make the IMU show (``accel_observer_xy_band_m_s2``,
        # g x 0.6 deg) is not taken for a disturbance: the in-flight bias leaves the estimate's
        # transients in, and answered, they pushed the inspection sweep 6 % below its 0.20 m/s.
        # Nor is what the IMU's own noise, measured in flight, makes them show: under rotor
        # vibration they turned noise into tilt (1.4 m/s^2 a tick gave pushes of 0.3-0.7 m/s^2 for
        # a second at a time, and in an alarm mode nothing measured what they did).
        band = p.accel_observer_xy_band_m_s2
        k = p.accel_observer_noise_sigma
        vx_obs = self.obs_x.update(meas[0], dt, nominal=-drag * est.vx_m_s)
        vy_obs = self.obs_y.update(meas[1], dt, nominal=-drag * est.vy_m_s)
        ax += _beyond(vx_obs, max(band, k * self.obs_x.value_noise(dt)))
        ay += _beyond(vy_obs, max(band, k * self.obs_y.value_noise(dt)))

        amax = G * math.tan(p.max_tilt_rad)
        ax = max(-amax, min(amax, ax))
        ay = max(-amax, min(amax, ay))
        # The acceleration limit applies around the trim (the integrator), so a vehicle that needs
        # a large trim to hover keeps its full authority to climb and descend.
        az = trim + max(-p.max_vertical_accel_m_s2, min(p.max_vertical_accel_m_s2, az - trim))
        # The observed shortfall is trim too: outside that limit.
        az += self.obs_z.update(meas[2], dt)
        pitch = math.atan2(ax, G)
        roll = -math.atan2(ay, G)
        tilt = math.cos(roll) * math.cos(pitch)
        thrust = p.hover_thrust_frac * (1.0 + az / G) / tilt
        thrust = max(0.0, min(thrust, 1.0, thrust_cap_frac))
        self.obs_x.applied(ax)
        self.obs_y.applied(ay)
        self.obs_z.applied(G * (thrust * tilt / p.hover_thrust_frac - 1.0))
        return AttitudeSetpoint(roll_rad=roll, pitch_rad=pitch, yaw_rate_rad_s=cmd.yaw_rate_rad_s, thrust_frac=thrust)
