"""The small observers the state estimation is built from (``estimation.MAVStateUpdater``).

* :class:`SpeedObserver`: one axis's speed and the accelerometer's bias along it, a two-state
  Kalman filter with the IMU as input and flow speeds / range rates as gated measurements;
* :class:`RangeObserver`: a range, its rate and the accelerometer's bias along it, propagated with
  the IMU and corrected by delayed 10 Hz range samples (fixed gains: a triple pole);
* :class:`HeightEstimator`: the bottom range's observer that tells floor steps from motion;
* :class:`RangeSlope`: one sonar's range rate, a least-squares slope over its last samples;
* :class:`StuckCheck`: a sensor repeating its value while another says it changed.
"""

from __future__ import annotations

import math

__all__ = ["HeightEstimator", "RangeObserver", "RangeSlope", "SpeedObserver", "StuckCheck", "WhiteNoiseMeter"]


class RangeObserver:
    """Range and range rate: propagated with a measured acceleration, corrected by delayed samples.

    Third-order observer (range, rate, accelerometer bias) with gains ``k1`` (1/s), ``k2``
    (1/s^2), ``k3`` (1/s^3); state valid at ``self.t``. Without the bias state a 0.03 m/s^2
    accelerometer bias would leave a steady rate error of k1*bias/k2, and the vehicle would creep.
    """

    def __init__(
        self, *, k1: float, k2: float, k3: float = 0.0, max_gap_s: float = 1.0, max_bias: float = 0.5,
        jump_m: float | None = None,
    ) -> None:
        self.k1, self.k2, self.k3 = k1, k2, k3
        #: a sample this far from the prediction is another surface (a wall's edge passed, a
        #: pillar come into the beam), not motion: the range re-seats, rate and bias stay
        self.jump_m = jump_m
        self.max_bias = max_bias  # m/s^2: a calibrated accelerometer's residual bias is far below
        self.bias = 0.0
        self.max_gap_s = max_gap_s
        self.value: float | None = None
        self.rate = 0.0
        self.t = 0.0
        self.last_sample_t: float | None = None
        self.rate_measured = False  # the last propagation took a measured rate (optical flow)

    def propagate(self, t: float, accel: float = 0.0, rate: float | None = None) -> None:
        """Advance to ``t`` with ``accel``; or with a measured ``rate`` that replaces the estimate."""
        dt = t - self.t
        self.t = t
        self.rate_measured = rate is not None
        if self.value is None or dt <= 0.0:
            if rate is not None:
                self.rate = rate
            return
        if rate is not None:
            self.value += 0.5 * (self.rate + rate) * dt
            self.rate = rate
        else:
            a = accel - self.bias
            self.value += self.rate * dt + 0.5 * a * dt * dt
            self.rate += a * dt

    def at(self, t_meas: float) -> float:
        """The estimate back-dated to ``t_meas`` (a delayed sample is compared with this)."""
        return (self.value or 0.0) - self.rate * (self.t - t_meas)

    def correct(self, z: float, t_meas: float) -> None:
        last, self.last_sample_t = self.last_sample_t, t_meas
        if self.value is None or last is None or t_meas - last > self.max_gap_s:
            self.value = z + self.rate * (self.t - t_meas)
            return
        ts = min(max(t_meas - last, 1e-3), 0.3)
        r = z - self.at(t_meas)
        if self.jump_m is not None and abs(r) > self.jump_m:
            # Taken as motion, the front range's step from 1.0 to 2.8 m (the vehicle slid past a
            # pillar's end) read as 2 m/s away from it and the bias state hit its limit (a speed
            # observer that adopted that rate flew the vehicle into the far wall).
            self.value += r
            return
        self.value += min(self.k1 * ts, 1.0) * r
        if self.rate_measured:
            # The rate comes from optical flow, not from the accelerometer: the residual says
            # nothing about the accelerometer's bias. Integrated anyway, sonar noise walked the
            # bias to ~3 m/s^2 over a long flight, and the first IMU-propagated second after a
            # bottom-flow loss drove the speed estimate the wrong way (safety campaign: mode 2 at
            # a wall, estimated -0.7 m/s while flying into it at +0.7 m/s).
            return
        self.rate += self.k2 * ts * r
        self.bias = max(-self.max_bias, min(self.max_bias, self.bias - self.k3 * ts * r))


class WhiteNoiseMeter:
    """The variance of a signal's white noise, measured as it runs: half the running mean square of
    consecutive differences over ``window_s`` (a white noise's variance; a smooth change, a gust or a
    manoeuvre, adds little). The IMU's noise as the speed observers and the disturbance observers
    (``control.AccelObserver``) see it."""

    __slots__ = ("window_s", "variance", "_last")

    def __init__(self, window_s: float = 1.0) -> None:
        self.window_s = window_s
        self.variance = 0.0
        self._last: float | None = None

    def add(self, x: float, dt: float) -> None:
        if self._last is not None:
            step = x - self._last
            self.variance += (0.5 * step * step - self.variance) * min(1.0, dt / self.window_s)
        self._last = x

    def forget_last(self) -> None:
        """The next sample starts a new run of differences (the variance is kept)."""
        self._last = None


class SpeedObserver:
    """One axis's speed and the accelerometer's bias along it: a two-state Kalman filter.

    State ``(v, b)``: the speed along the axis (heading frame, m/s) and the accelerometer's bias
    along it (m/s^2; mostly the autopilot's attitude-estimate error times g, which wanders in
    flight). :meth:`predict` carries the speed with the IMU's acceleration less ``b``;
    :meth:`correct` takes whatever measures the speed (a PX4Flow speed, a range rate) with its
    noise. An innovation further than ``gate`` standard deviations is not used (a new surface in
    a sonar's beam, a flow glitch). With no measurement used (the alarm modes, rejections) the
    speed is carried on with the IMU and its variance grows, so the gate widens until a
    measurement consistent with that uncertainty is taken again. The gate can also close for good:
    after a blind spell the speed loop steers the vehicle by the carried speed, so the true speed
    runs away from it faster than the variance grows, and every measurement is refused (the
    bottom flow read -0.3 to -1.4 m/s for six seconds, the estimate
    stayed at +0.1 to +0.6, the vehicle flew backwards into the wall at 2 m/s). So
    ``RESTART_AFTER`` measurements refused in a row restart the speed at the last of them.

    ``accel_noise`` (m/s^2/sqrt(Hz)) and ``bias_walk`` (m/s^2/sqrt(s)) are the process noise
    densities; the per-measurement noise comes with each :meth:`correct`. The IMU's own white
    noise, measured in flight (half the running mean square of consecutive differences of its
    acceleration over 1 s, :class:`WhiteNoiseMeter`, as the disturbance observers measure theirs), is added
    to ``accel_noise``: rotor vibration raises it 10x and more (a vibration fault of rate 0.44 is
    1.3 m/s^2 a tick), and a filter that kept trusting the IMU as in calm air followed the 10 Hz
    range rates 0.3 m/s late in mode 2, where the link-loss hold rocked the vehicle 0.32 m off
    its point.
    """

    V0, B0 = 0.5**2, 0.1**2  # initial variances: speed unknown within 0.5 m/s, bias within 0.1 m/s^2
    # measurements refused in a row: half a second of the 10 Hz flows and sonar range rates, which are taken once
    # a reading; 0.1 s of the height's rate, which is offered every 50 Hz tick (modes 0 and -1)
    RESTART_AFTER = 5

    __slots__ = ("v", "b", "p00", "p01", "p11", "q_a", "q_b", "gate", "refused", "imu_noise", "walk_var")

    def __init__(self, *, accel_noise: float, bias_walk: float, gate: float) -> None:
        self.q_a, self.q_b, self.gate = accel_noise**2, bias_walk**2, gate
        self.v = self.b = 0.0
        self.p00, self.p01, self.p11 = self.V0, 0.0, self.B0
        self.refused = 0
        self.imu_noise = WhiteNoiseMeter()  # the IMU's white-noise variance along this axis, (m/s^2)^2
        # Variance of the random walk the IMU's own white noise has put into ``v`` since the
        # measurements last held it (m/s)^2: see :attr:`imu_walk_sd`.
        self.walk_var = 0.0

    def predict(self, accel: float, dt: float) -> None:
        if dt <= 0.0:
            return
        self.imu_noise.add(accel, dt)
        self.v += (accel - self.b) * dt
        self.walk_var += self.imu_noise.variance * dt * dt
        p00, p01, p11 = self.p00, self.p01, self.p11
        # a white noise of variance v per sample of length dt: density v * dt
        self.p00 = p00 - 2.0 * dt * p01 + dt * dt * p11 + (self.q_a + self.imu_noise.variance * dt) * dt
        self.p01 = p01 - dt * p11
        self.p11 = p11 + self.q_b * dt

    def correct(self, z: float, noise: float, *, then: float | None = None, learn_bias: bool = True) -> bool:
        """Take a measurement ``z`` of the speed with standard deviation ``noise``; ``then``: the
        estimate of the moment ``z`` was measured (a delayed measurement's innovation is taken
        against it and applied now). ``learn_bias=False``: a measurement that shares the IMU's
        errors (a rate that is itself the IMU's integral corrected by a range) corrects the
        speed only; the bias is a "consider" state for it (Schmidt-Kalman). Returns whether it
        was used."""
        y = z - (self.v if then is None else then)
        s = self.p00 + noise * noise
        if not self._within_gate(y, s):
            self.refused += 1
            if self.refused < self.RESTART_AFTER:
                return False
            self.restart(self.v + y)  # the measurement, brought to now
            return True
        self.refused = 0
        k0 = self.p00 / s
        self.v += k0 * y
        self.walk_var *= (1.0 - k0) * (1.0 - k0)
        p00, p01 = self.p00, self.p01
        self.p00 = (1.0 - k0) * p00
        self.p01 = (1.0 - k0) * p01
        if learn_bias:
            k1 = p01 / s
            self.b += k1 * y
            self.p11 -= k1 * p01
        return True

    def consistent(self, z: float, noise: float, *, then: float | None = None) -> bool:
        """Whether a measurement ``z`` lies within the gate (what :meth:`correct` would use), with no
        side effect: whatever else reads the same sensor asks this first."""
        return self._within_gate(z - (self.v if then is None else then), self.p00 + noise * noise)

    def _within_gate(self, innovation: float, variance: float) -> bool:
        return innovation * innovation <= self.gate * self.gate * variance

    def restart(self, v: float) -> None:
        """Restart the speed at ``v`` (its variance too); the bias is kept."""
        self.v, self.p00, self.p01 = v, self.V0, 0.0
        self.refused = 0
        self.walk_var = 0.0

    @property
    def imu_walk_sd(self) -> float:
        """Standard deviation of what the IMU's own noise (as measured) has made of the carried
        speed since the measurements last held it (m/s). Calm, the walk stays within 0.02 m/s over
        2 s; under rotor vibration of 1.4 m/s^2 a tick it is 0.27 m/s."""
        return math.sqrt(self.walk_var)


class HeightEstimator:
    """Altitude over the take-off floor from a downward range, robust to floor steps.

    A change between consecutive ranges that vertical motion cannot explain (more than
    ``jump_m`` away from the prediction) is a discontinuity of the floor, e.g. overflying a box:
    it moves the floor offset instead of the altitude. ``height`` (range to the surface below)
    steps with the floor while ``altitude`` stays continuous.
    """

    def __init__(
        self, *, jump_m: float, k1: float, k2: float, k3: float = 0.0, settle_samples: int = 2, step_min_height_m: float = 0.35
    ) -> None:
        self.jump_m = jump_m
        self.step_min_height_m = step_min_height_m
        self.settle_samples = settle_samples
        self._settling = 0  # samples after a floor step still taken as the floor settling
        self.floor_offset_m = 0.0
        self.obs = RangeObserver(k1=k1, k2=k2, k3=k3)

    @property
    def altitude_m(self) -> float:
        return self.obs.value or 0.0

    @property
    def height_m(self) -> float:
        return self.altitude_m - self.floor_offset_m

    @property
    def rate_m_s(self) -> float:
        return self.obs.rate

    def propagate(self, t: float, accel: float = 0.0, rate: float | None = None) -> None:
        self.obs.propagate(t, accel, rate)

    def update(self, range_m: float, t_meas: float) -> None:
        o = self.obs
        fresh = o.value is None or o.last_sample_t is None or t_meas - o.last_sample_t > o.max_gap_s
        raw = range_m + self.floor_offset_m
        # Near the floor the range sensors clamp at their minimum (sonar 0.3 m, TeraRanger 0.2 m):
        # a reading that parts from the prediction there is the clamp, not a step (a light
        # vehicle's take-off outran its clamped sonar by 0.17 m).
        low = min(range_m, (o.value or 0.0) - self.floor_offset_m) < self.step_min_height_m
        if not fresh and not low:
            pred = o.at(t_meas)
            if abs(raw - pred) > self.jump_m or self._settling > 0:
                # A step of the floor; and for the next samples, while the beam's footprint still
                # straddles the edge, what the prediction does not explain belongs to the floor
                # too: taken from the first sample alone, a slant echo off the box's edge (1.43 m
                # over a 1.55 m floor) left the altitude 0.12 m high for the rest of the flight.
                self._settling = self.settle_samples if abs(raw - pred) > self.jump_m else self._settling - 1
                self.floor_offset_m += pred - raw
                raw = pred
        o.correct(raw, t_meas)


class RangeSlope:
    """Rate of change of one range sensor from its last samples (least-squares line over
    ``window_s``); None with fewer than ``min_samples`` consecutive valid samples. ``full``: the
    samples span the window (at least ``full_span_s``: 0.4 s of the 10 Hz sonars), the slope whose
    noise ``speed_noise_m_s`` states (three consecutive samples, 0.2 s apart, give a slope 2.2
    times as noisy; three across the window, every other reading beyond the usable range, 1.1
    times), and no echo was missed (:meth:`miss`) among them."""

    def __init__(self, *, window_s: float = 0.45, max_gap_s: float = 0.3, min_samples: int = 3, full_span_s: float = 0.35) -> None:
        self.window_s, self.max_gap_s, self.min_samples = window_s, max_gap_s, min_samples
        self.full_span_s = full_span_s
        self._missed_t: float | None = None  # the last reading that heard no echo (see miss)
        self.samples: list[tuple[float, float]] = []
        self._fit: float | None = None  # the line's slope over the current samples (cached)
        self._fit_valid = False
        #: mean stamp of the samples the last rate was fitted to: the rate is the speed there
        self.t_mid: float | None = None

    def add(self, t: float, range_m: float | None) -> None:
        self._fit_valid = False
        if range_m is None:
            self.samples.clear()
            return
        if self.samples and t - self.samples[-1][0] > self.max_gap_s:
            self.samples.clear()
        self.samples.append((t, range_m))
        while self.samples and t - self.samples[0][0] > self.window_s:
            self.samples.pop(0)

    def miss(self, t: float) -> None:
        """A reading at ``t`` heard no echo: the samples around it need not be one surface's (a sonar
        at a shallow incidence hears its surface through whichever rays catch an echo)."""
        self._missed_t = t

    @property
    def full(self) -> bool:
        s = self.samples
        return (
            len(s) >= self.min_samples
            and s[-1][0] - s[0][0] >= self.full_span_s
            and (self._missed_t is None or self._missed_t < s[0][0])
        )

    def rate(self, now: float) -> float | None:
        s = self.samples
        if len(s) < self.min_samples or now - s[-1][0] > self.max_gap_s + 0.1:
            return None
        if not self._fit_valid:  # samples come at 10 Hz, the question at 50 Hz
            n = len(s)
            tm = sum(t for t, _ in s) / n
            rm = sum(r for _, r in s) / n
            den = sum((t - tm) ** 2 for t, _ in s)
            self._fit = None if den <= 0.0 else sum((t - tm) * (r - rm) for t, r in s) / den
            self._fit_valid = True
            self.t_mid = tm
        return self._fit


class StuckCheck:
    """A sensor that repeats its last value bit for bit (a hung driver or bus re-sending the last
    frame, freshly stamped) while another sensor says the value has changed is stuck: after
    ``samples`` equal readings, once the value when the repeats began (``reference``, else the
    reading itself) plus the integral of ``rates`` since (flow: the IMU's acceleration; range: the
    speed along the sensor's axis) differs from the repeated reading by more than
    ``change_limit``. A
    repeat alone is not enough: a quantised output (PX4Flow's integer pixel flow, a 1 mm sonar)
    repeats in steady flight. Safety campaign: a bottom flow stuck at -0.43 m/s during a link loss made the
    station keeping accelerate the vehicle to 2 m/s into a wall; a front flow stuck at +0.03 m/s
    vertical during a landing let the descent speed up to 1.5 m/s into the floor."""

    def __init__(self, samples: int, change_limit: float, max_gap_s: float = 0.3) -> None:
        self.samples, self.change_limit = samples, change_limit
        #: a reading after a longer silence starts the judgement afresh (see :meth:`check`)
        self.max_gap_s = max_gap_s
        self._stamp: float | None = None
        self._value: tuple[float, ...] | None = None
        self._repeats = 0
        self._dv: list[float] = []  # IMU speed change since the repeats began, per component
        self._ref: tuple[float, ...] = ()  # the true value when the repeats began (best estimate)
        self._latched = False

    def check(
        self, stamp_s: float, value: tuple[float, ...], rates: tuple[float, ...],
        reference: tuple[float | None, ...] | None = None,
    ) -> bool:
        """True while the sensor is stuck; call with every reading and the rates of change that
        other sensors give for its components (a repeated stamp is ignored). ``reference``: the
        best estimate of each component without this reading's noise (a filtered speed; None:
        the reading itself), taken as the true value when the repeats begin. Judged from the
        repeated reading instead, a stuck bottom flow 0.07 m/s off the true speed (its noise)
        needed 0.22 m/s of real change to be found, and the vehicle crept 0.11 m inside the stop
        line meanwhile."""
        if stamp_s != self._stamp:
            # Across a silence the rates are unknown: one sample's rate times the silence is no
            # integral (a bottom PX4Flow dropped for 3 s came back stuck at its last value; its
            # rate, the IMU's braking at that moment, times 3 s put the "likely" speed at -1.4
            # m/s while the vehicle flew at +0.1, and the restart from it flew the vehicle into
            # the wall at 1 m/s: fault-pair probe, 2026-11-28). The first reading after it is a
            # new start; repeats of it are judged from there, against the estimate then.
            silence = self._stamp is not None and stamp_s - self._stamp > self.max_gap_s
            if value == self._value and self._stamp is not None and not silence:
                self._repeats += 1
                if self._repeats == 1:  # the estimate has seen the first reading: the true value then
                    ref = reference or (None,) * len(value)
                    self._ref = tuple(v if r is None else r for v, r in zip(value, ref))
                dt = stamp_s - self._stamp
                self._dv = [dv + a * dt for dv, a in zip(self._dv, rates)]
            else:
                self._repeats = 0
                self._dv = [0.0] * len(value)
                self._latched = False
                self._ref = value
            self._stamp, self._value = stamp_s, value
        if self._repeats < self.samples - 1:
            return False
        # Once found, stuck until the value changes: the integrated change wanders back under
        # the limit when the vehicle brakes, and the stuck value was trusted again (flickering
        # between the flow and the range-rate estimate at a wall).
        self._latched = self._latched or max(abs(x) for x in self._disagreement()) > self.change_limit
        return self._latched

    def _disagreement(self) -> list[float]:
        return [r + dv - v for r, dv, v in zip(self._ref, self._dv, self._value or ())]

    def likely_value(self) -> tuple[float, ...]:
        """What the sensor would read now had it not stuck: the reference when the repeats
        began plus the change the other sensors integrated since."""
        return tuple(r + dv for r, dv in zip(self._ref, self._dv))
