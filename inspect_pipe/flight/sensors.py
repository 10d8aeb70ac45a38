"""Simulated sensors with their real rates, ranges, noise and latency.

* PX4Flow (bottom and front): 100 Hz, 20 ms latency. The camera sees angular flow (rad/s): the
  velocity across its axis over the distance along it, plus the body rotation; the unit's own
  gyro (bias, scale error, noise) takes the rotation out and its own sonar's last range scales
  what is left to metres per second, as the PX4Flow firmware does. Angular noise and quality
  0..255 follow the texture and the light; without a sonar echo it has no metric scale (its
  metric flow reads 0) but still measures the angular flow, as the unit's ``OPTICAL_FLOW_RAD`` does; its
  MaxBotix HRLV-EZ4 sonar at 10 Hz, 0.3..5 m, 50 ms latency.
* Side HRLV-EZ4 sonars (left, right): 10 Hz, 5 m.
* Every horizontal sonar has a beam, not a ray: an ultrasonic ranger reports its first echo, the
  nearest surface inside its beam. The beam is a horizontal fan of ``sonar_beam_rays`` rays over
  +-``sonar_half_beam_deg`` (15 deg: MaxBotix's narrow-beam HRLV-EZ4 against the large flat plates
  of a hold); the nearest hit is the reading. A single ray along the axis missed the edge of a
  pillar or coaming that a real sonar hears (safety campaign: slides along a wall into a pillar's
  side). The downward PX4Flow sonar has the same beam as a cone: the axis and ``sonar_cone_rays``
  rays around it at the half-width, so a box top or a coaming under the rim of the beam is its
  reading before the vehicle's centre is over it (as a real HRLV-EZ4 hears it). The TeraRanger
  One, a laser with a 3 deg beam, stays a single ray.
* TeraRanger One (bottom): 100 Hz, 0.2..14 m, 10 ms latency, +-2 cm.
* Sonars miss their echo at shallow incidence: a flat steel plate reflects the pulse away, so a ray
  meeting its surface more than ``grazing_deg`` off the normal returns nothing with a probability
  growing to 1 at ``miss_all_deg``.
* The autopilot's IMU: the accelerometer's specific force in the body frame (gravity and tilt
  included, mean per control tick) with bias, noise and rotor vibration; gyro rates with bias and
  noise; and the autopilot's attitude estimate as a quantity of its own (:class:`AttitudeError`:
  a level bias, a slow drift, transients under sustained acceleration and fast rotation).

A reading is delivered at ``sample time + latency`` and stamped with its delivery time (what the
onboard computer sees). A sensor under a ``sensor_dropout`` fault delivers nothing; the other
sensor faults of the scenario format (packet loss, stuck readings, spurious max-range echoes at
grazing incidence, loss of every range sensor, flow quality zero) come in as :class:`SensorFaults`
and draw their randomness from a generator of their own, so a flight without them is unchanged.
"""

from __future__ import annotations

import math
import random

import numpy as np
from collections import deque
import dataclasses
from dataclasses import dataclass, field

from inspect_pipe.flight.scenario import SensorName
from inspect_pipe.flight.vehicle_sim import QuadrotorSim
from inspect_pipe.flight_stack.messages import G_M_S2, BottomFlow, FrontFlow, ImuReading, Measurements, RangeReading

__all__ = ["AttitudeError", "AttitudeSpec", "FlowSpec", "ImuSpec", "RangeSpec", "SensorFaults", "SensorSuite", "SensorSpecs"]


@dataclass(frozen=True)
class RangeSpec:
    rate_hz: float
    latency_s: float
    min_range_m: float
    max_range_m: float
    noise_m: float
    noise_per_m: float = 0.0


@dataclass(frozen=True)
class FlowSpec:
    rate_hz: float = 100.0
    latency_s: float = 0.02
    noise_rad_s: float = 0.02  # angular flow noise on a well-lit, textured surface
    bias_m_s: float = 0.002  # std of the per-unit metric bias (lens, mounting)
    gyro_bias_rad_s: float = 0.001  # std of the unit's L3GD20 gyro bias left after its start-up calibration (0.06 deg/s)
    gyro_scale: float = 0.02  # std of the unit's gyro scale error (rotation left in the compensated flow)
    gyro_noise_rad_s: float = 0.005
    quality: int = 200  # on a textured, lit surface
    light_range_m: float = 4.0  # beyond it the image darkens as 1/d^2 (the vehicle's own light)


@dataclass(frozen=True)
class ImuSpec:
    noise_m_s2: float = 0.05  # white noise of the 50 Hz mean specific force
    bias_m_s2: float = 0.03  # std of the residual accelerometer bias after calibration
    vibration_m_s2: float = 0.1  # std of rotor vibration left in the 50 Hz mean (raised by the vibration fault)
    gyro_noise_rad_s: float = 0.003
    gyro_bias_rad_s: float = 0.002
    yaw_drift_rad_s: float = 0.002  # std of the heading estimate's drift rate (0.1 deg/s)


@dataclass(frozen=True)
class AttitudeSpec:
    """Error of the autopilot's roll/pitch estimate (a complementary filter / EKF fusing the gyro
    with the accelerometer as the gravity reference)."""

    level_bias_rad: float = 0.005  # std of the constant part: level calibration, board alignment (0.3 deg)
    drift_rad: float = 0.003  # std of the slow wander (gyro bias not yet fused out)
    drift_tau_s: float = 20.0
    accel_coupling: float = 0.05  # share of the apparent tilt (a_horizontal / g) a sustained acceleration leaves
    accel_tau_s: float = 1.0  # how fast that share builds up and fades (the accelerometer fusion's time constant)
    gyro_scale: float = 0.01  # std of the gyro scale error: a fast rotation leaves scale x angle, fused out over accel_tau_s
    vibration_rad_per_m_s2: float = 0.002  # attitude noise per m/s^2 of vibration


@dataclass(frozen=True)
class SensorSpecs:
    flow: FlowSpec = FlowSpec()
    imu: ImuSpec = ImuSpec()
    attitude: AttitudeSpec = AttitudeSpec()
    sonar: RangeSpec = RangeSpec(10.0, 0.05, 0.3, 5.0, 0.005, 0.002)
    tof: RangeSpec = RangeSpec(100.0, 0.01, 0.2, 14.0, 0.02)
    grazing_deg: float = 35.0  # incidence from the surface normal beyond which a sonar may miss its echo
    miss_all_deg: float = 75.0  # incidence at which a sonar hears no echo from a flat plate at all
    sonar_half_beam_deg: float = 15.0  # horizontal sonars: half-width of the beam
    sonar_beam_rays: int = 5  # rays across the beam (odd: one on the axis)
    sonar_cone_rays: int = 8  # downward sonar: rays around the axis at the half-width (0: the axis alone)


@dataclass(frozen=True)
class SensorFaults:
    """Sensor faults active during one physics step (besides ``dropped`` sensors)."""

    packet_loss: dict = field(default_factory=dict)  # SensorName -> probability a sample is lost
    stuck: frozenset = frozenset()  # SensorName: repeats its last reading
    spurious_max_range: dict = field(default_factory=dict)  # SensorName -> probability at grazing incidence
    range_loss: bool = False  # every range sensor silent
    flow_quality_zero: frozenset = frozenset()  # SensorName (bottom_flow, front_flow)
    low_texture: dict = field(default_factory=dict)  # SensorName (a flow) -> share of texture and light lost
    vibration_m_s2: float = 0.0  # rotor vibration added to the IMU's (std of the 50 Hz mean)

    def any(self) -> bool:
        return bool(
            self.packet_loss or self.stuck or self.spurious_max_range or self.range_loss or self.flow_quality_zero
            or self.low_texture or self.vibration_m_s2
        )


NO_FAULTS = SensorFaults()


class _NormalStream:
    """Gaussian noise drawn in blocks from numpy's PCG64: the sensors draw about 900 samples per
    simulated second, and ``random.gauss`` one at a time was 8 % of a campaign's CPU time."""

    __slots__ = ("_gen", "_buf", "_i")

    def __init__(self, seed: int, block: int = 4096) -> None:
        self._gen = np.random.Generator(np.random.PCG64(seed))
        self._buf: list[float] = self._gen.standard_normal(block).tolist()
        self._i = 0

    def gauss(self, mu: float, sigma: float) -> float:
        i = self._i
        if i == len(self._buf):
            self._buf = self._gen.standard_normal(len(self._buf)).tolist()
            i = 0
        self._i = i + 1
        return mu + sigma * self._buf[i]


def _fan(axis_yaw_rad: float, specs: SensorSpecs) -> tuple[tuple[float, float, float], ...]:
    """Body-frame unit directions across a horizontal sonar's beam, the axis first."""
    n, half = max(1, specs.sonar_beam_rays), math.radians(specs.sonar_half_beam_deg)
    offsets = [0.0] + [half * (2.0 * k / (n - 1) - 1.0) for k in range(n) if n > 1 and 2 * k != n - 1]
    return tuple((math.cos(axis_yaw_rad + o), math.sin(axis_yaw_rad + o), 0.0) for o in offsets)


def _cone(specs: SensorSpecs) -> tuple[tuple[float, float, float], ...]:
    """Body-frame unit directions of the downward sonar's beam: the axis first, then
    ``sonar_cone_rays`` rays evenly around it at ``sonar_half_beam_deg``."""
    half, n = math.radians(specs.sonar_half_beam_deg), specs.sonar_cone_rays
    rim = tuple(
        (math.sin(half) * math.cos(2 * math.pi * k / n), math.sin(half) * math.sin(2 * math.pi * k / n), -math.cos(half))
        for k in range(n)
    )
    return ((0.0, 0.0, -1.0),) + rim


def _body_kinematics(sim: QuadrotorSim) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The vehicle's velocity (m/s) and angular rates (rad/s) in the body frame."""
    (vx, vy, vz, p, q, r), (R0, R1, R2, R3, R4, R5, R6, R7, R8) = sim.kinematics()
    return (R0 * vx + R3 * vy + R6 * vz, R1 * vx + R4 * vy + R7 * vz, R2 * vx + R5 * vy + R8 * vz), (p, q, r)


class AttitudeError:
    """Error of the autopilot's roll and pitch estimate, advanced at each IMU reading (rad):
    a constant level bias, an Ornstein-Uhlenbeck drift, the share of the apparent tilt that a
    sustained horizontal acceleration leaves in an accelerometer-referenced filter (built up and
    faded over ``accel_tau_s``), the gyro scale error's residue after a fast rotation, and noise
    that grows with the vibration."""

    def __init__(self, spec: AttitudeSpec, seed: int) -> None:
        self.s = spec
        self.noise = _NormalStream(seed, block=1024)
        g = self.noise.gauss
        self.bias = (g(0.0, spec.level_bias_rad), g(0.0, spec.level_bias_rad))
        self.drift = [g(0.0, spec.drift_rad), g(0.0, spec.drift_rad)]
        self.scale = (g(0.0, spec.gyro_scale), g(0.0, spec.gyro_scale))
        self.accel = [0.0, 0.0]
        self.gyro = [0.0, 0.0]

    def advance(self, dt: float, a_heading: tuple[float, float], rates: tuple[float, float], vibration_m_s2: float) -> tuple[float, float]:
        """(roll error, pitch error) after ``dt`` with heading-frame acceleration ``a_heading``
        (x, y) and body rates ``rates`` (p, q)."""
        s, g = self.s, self.noise.gauss
        kd = dt / s.drift_tau_s
        sd = s.drift_rad * math.sqrt(2.0 * kd)
        ka = min(1.0, dt / s.accel_tau_s)
        # An accelerometer taken for gravity while accelerating at a: roll a_y/g, pitch -a_x/g.
        apparent = (a_heading[1] / G_M_S2, -a_heading[0] / G_M_S2)
        sv = s.vibration_rad_per_m_s2 * vibration_m_s2
        out = []
        for i in range(2):
            self.drift[i] += -kd * self.drift[i] + sd * g(0.0, 1.0)
            self.accel[i] += ka * (s.accel_coupling * apparent[i] - self.accel[i])
            self.gyro[i] += self.scale[i] * rates[i] * dt - ka * self.gyro[i]
            out.append(self.bias[i] + self.drift[i] + self.accel[i] + self.gyro[i] + sv * g(0.0, 1.0))
        return out[0], out[1]


_RANGE_CHANNELS = frozenset({"bottom_sonar", "front_sonar", "left_sonar", "right_sonar", "bottom_tof"})


class _Channel:
    """One periodic sensor output with a delivery queue."""

    __slots__ = ("period", "latency", "next_t", "queue", "latest", "last_value")

    def __init__(self, rate_hz: float, latency_s: float, phase: float) -> None:
        self.period = 1.0 / rate_hz
        self.latency = latency_s
        self.next_t = phase * self.period
        self.queue: deque = deque()
        self.latest = None
        self.last_value = None  # the last value sampled (a stuck sensor repeats it)

    def deliver(self, now: float):
        """The latest reading delivered by ``now``."""
        q = self.queue
        while q and q[0][0] <= now:
            self.latest = q.popleft()[1]
        return self.latest


class SensorSuite:
    """All sensors of the vehicle; ``sample(sim, dropped)`` after each physics step,
    ``read(now)`` at each control tick."""

    def __init__(self, specs: SensorSpecs | None = None, *, seed: int = 0) -> None:
        self.s = specs or SensorSpecs()
        self.rng = random.Random(seed * 104729 + 3)
        r = self.rng
        fl, so, tof = self.s.flow, self.s.sonar, self.s.tof
        self.ch = {
            "bottom_flow": _Channel(fl.rate_hz, fl.latency_s, r.random()),
            "bottom_sonar": _Channel(so.rate_hz, so.latency_s, r.random()),
            "front_flow": _Channel(fl.rate_hz, fl.latency_s, r.random()),
            "front_sonar": _Channel(so.rate_hz, so.latency_s, r.random()),
            "left_sonar": _Channel(so.rate_hz, so.latency_s, r.random()),
            "right_sonar": _Channel(so.rate_hz, so.latency_s, r.random()),
            "bottom_tof": _Channel(tof.rate_hz, tof.latency_s, r.random()),
        }
        self._imu_prev = None
        self._next_due = 0.0
        self._imu_bias = tuple(r.gauss(0, self.s.imu.bias_m_s2) for _ in range(3))
        # Gyro, PX4Flow gyro and attitude-estimate errors: generators of their own.
        er = random.Random(seed * 7919 + 31)
        self._gyro_bias = tuple(er.gauss(0, self.s.imu.gyro_bias_rad_s) for _ in range(3))
        fl_ = self.s.flow
        self._px_gyro = {
            k: (tuple(er.gauss(0, fl_.gyro_bias_rad_s) for _ in range(2)), tuple(er.gauss(0, fl_.gyro_scale) for _ in range(2)))
            for k in ("bottom_flow", "front_flow")
        }
        self.attitude_error = AttitudeError(self.s.attitude, seed * 104729 + 37)
        self.echo_rng = random.Random(seed * 15485863 + 41)  # sonar misses at shallow incidence
        self._px_true: dict[str, float | None] = {"bottom_flow": None, "front_flow": None}
        self.noise = _NormalStream(seed * 104729 + 11)  # per-sample measurement noise
        self._unscaled_noise = _NormalStream(seed * 104729 + 53, block=1024)  # PX4Flow readings without a range
        # Heading drift of a gyro-only attitude estimate (no usable compass in a steel hold); its
        # own generator, so the other noise sequences stay as they were.
        self._yaw_drift_rad_s = random.Random(seed * 7919 + 29).gauss(0.0, self.s.imu.yaw_drift_rad_s)
        self.bias = {k: (r.gauss(0, fl.bias_m_s), r.gauss(0, fl.bias_m_s)) for k in ("bottom_flow", "front_flow")}
        # Last sonar range each PX4Flow scales its flow with.
        self._px_range: dict[str, float | None] = {"bottom_flow": None, "front_flow": None}
        self._owner = {
            "bottom_flow": SensorName.BOTTOM_FLOW, "bottom_sonar": SensorName.BOTTOM_FLOW,
            "front_flow": SensorName.FRONT_FLOW, "front_sonar": SensorName.FRONT_FLOW,
            "left_sonar": SensorName.LEFT_SONAR, "right_sonar": SensorName.RIGHT_SONAR,
            "bottom_tof": SensorName.BOTTOM_TOF,
        }
        self.fault_rng = random.Random(seed * 15485863 + 17)  # only faults draw from it
        self._faults = NO_FAULTS
        self._dirs = {
            "bottom_sonar": _cone(self.s), "bottom_tof": ((0.0, 0.0, -1.0),),
            "front_sonar": _fan(0.0, self.s), "left_sonar": _fan(math.pi / 2, self.s), "right_sonar": _fan(-math.pi / 2, self.s),
        }
        # (name, channel, owning unit, beam directions or None for a flow output) in sampling
        # order (the order the noise is drawn in).
        self._channels = tuple((name, ch, self._owner[name], self._dirs.get(name)) for name, ch in self.ch.items())

    def _imu(self, now: float, sim: QuadrotorSim) -> ImuReading | None:
        """Mean specific force since the last reading (finite difference of the true velocity,
        gravity added, turned into the body frame), gyro rates, and the attitude estimate."""
        (vx, vy, vz, p, q, r), (R0, R1, R2, R3, R4, R5, R6, R7, R8) = sim.kinematics()
        prev, self._imu_prev = self._imu_prev, (now, (vx, vy, vz))
        if prev is None or now <= prev[0]:
            return None
        t0, (vx0, vy0, vz0) = prev
        dt = now - t0
        ax, ay, az = (vx - vx0) / dt, (vy - vy0) / dt, (vz - vz0) / dt
        fz_w = az + G_M_S2
        spec = self.s.imu
        vib = spec.vibration_m_s2 + self._faults.vibration_m_s2
        g, sigma = self.noise.gauss, math.sqrt(spec.noise_m_s2 ** 2 + vib * vib)
        b = self._imu_bias
        fx = R0 * ax + R3 * ay + R6 * fz_w + b[0] + g(0.0, sigma)
        fy = R1 * ax + R4 * ay + R7 * fz_w + b[1] + g(0.0, sigma)
        fz = R2 * ax + R5 * ay + R8 * fz_w + b[2] + g(0.0, sigma)
        roll, pitch, yaw = sim.euler()
        c, sn = math.cos(yaw), math.sin(yaw)
        d_roll, d_pitch = self.attitude_error.advance(dt, (c * ax + sn * ay, -sn * ax + c * ay), (p, q), vib)
        sim.attitude_error = (d_roll, d_pitch)  # the firmware levels its estimate, not the truth
        gb, gs = self._gyro_bias, spec.gyro_noise_rad_s
        return ImuReading(
            now, fx, fy, fz,
            yaw + self._yaw_drift_rad_s * now,  # the autopilot's gyro-integrated heading
            roll + d_roll, pitch + d_pitch,
            p + gb[0] + g(0.0, gs), q + gb[1] + g(0.0, gs), r + gb[2] + g(0.0, gs),
        )

    def _range(self, spec: RangeSpec, true_m: float | None) -> float | None:
        if true_m is None or true_m > spec.max_range_m:
            return None
        noisy = true_m + self.noise.gauss(0.0, spec.noise_m + spec.noise_per_m * true_m)
        return max(spec.min_range_m, round(noisy, 3))  # the HRLV reports its minimum when closer

    @property
    def next_due_s(self) -> float:
        """Simulated time of the next sample of any channel (before it, ``sample`` does nothing)."""
        return self._next_due

    def sampler(self, dropped: frozenset[SensorName], faults: SensorFaults = NO_FAULTS) -> "_Sampler":
        """``sample`` with these faults as a callable for ``QuadrotorSim.step``; it carries
        ``next_due_s`` so the physics loop skips the call between samples."""
        return _Sampler(self, dropped, faults)

    def sample(self, sim: QuadrotorSim, dropped: frozenset[SensorName], faults: SensorFaults = NO_FAULTS) -> None:
        t = sim.t
        reached = t + 1e-9  # a sample is due once its time is reached, to within rounding
        if reached < self._next_due:
            return
        self._faults = faults
        faulty = faults is not NO_FAULTS and faults.any()
        pos = kin = None  # the vehicle's state, read once per sample
        next_due = math.inf
        for name, ch, owner, dirs in self._channels:
            next_t = ch.next_t
            if reached < next_t:
                if next_t < next_due:
                    next_due = next_t
                continue
            ch.next_t = next_t = next_t + ch.period
            if next_t < next_due:
                next_due = next_t
            if (dropped and owner in dropped) or (faults.range_loss and name in _RANGE_CHANNELS):
                if name.endswith("flow") or (faults.range_loss and name in ("bottom_sonar", "front_sonar")):
                    self._px_range[name.replace("sonar", "flow")] = None
                    self._px_true[name.replace("sonar", "flow")] = None
                    if not name.endswith("flow"):  # the unit's camera still sees along its axis
                        if pos is None:
                            pos = sim.position
                        self._px_true[name.replace("sonar", "flow")] = sim.first_echo(pos, dirs[:1])
                continue
            stamp = t + ch.latency  # delivery time: what the onboard clock stamps
            if faulty:
                if owner in faults.packet_loss and self.fault_rng.random() < faults.packet_loss[owner]:
                    continue
                if owner in faults.stuck and ch.last_value is not None:
                    ch.queue.append((stamp, dataclasses.replace(ch.last_value, stamp_s=stamp)))
                    continue
            if dirs is None:
                if kin is None:
                    kin = _body_kinematics(sim)
                value = self._measure_flow(name, owner, kin, stamp)
            else:
                if pos is None:
                    pos = sim.position
                value = self._measure_range(name, owner, dirs, sim, pos, stamp)
            ch.last_value = value
            ch.queue.append((stamp, value))
        self._next_due = next_due

    def _echo_heard(self, incidence_rad: float) -> bool:
        """Whether a sonar ray meeting a flat surface at ``incidence_rad`` from its normal hears
        the echo: always within ``grazing_deg``, never beyond ``miss_all_deg``, linear between."""
        s = self.s
        lo, hi = math.radians(s.grazing_deg), math.radians(s.miss_all_deg)
        if incidence_rad <= lo:
            return True
        return incidence_rad < hi and self.echo_rng.random() >= (incidence_rad - lo) / (hi - lo)

    def _measure_range(self, name: str, owner: SensorName, dirs, sim: QuadrotorSim, pos, stamp: float) -> RangeReading:
        """The nearest echo over the sensor's rays, with noise."""
        s = self.s
        if name == "bottom_tof":
            spec, spurious, accept = s.tof, None, None  # a laser's diffuse return: no specular miss
        else:
            spurious_faults = self._faults.spurious_max_range
            spec, spurious, accept = s.sonar, spurious_faults.get(owner) if spurious_faults else None, self._echo_heard
        true_m = sim.first_echo(pos, dirs, accept)
        rng = self._range(spec, true_m)
        # A reading implies an echo: the incidence is that of the ray that made it.
        if spurious and rng is not None and sim.incidence_rad() > math.radians(s.grazing_deg):
            if self.fault_rng.random() < spurious:
                rng = spec.max_range_m  # the echo skidded off: the sonar reports open space
        if name in ("bottom_sonar", "front_sonar"):
            if true_m is None:  # the sonar missed its echo; the unit's camera still sees along its axis
                true_m = sim.first_echo(pos, dirs[:1])
            unit = name.replace("sonar", "flow")
            self._px_range[unit], self._px_true[unit] = rng, true_m
        return RangeReading(stamp, rng)

    def _measure_flow(self, name: str, owner: SensorName, kin, stamp: float) -> BottomFlow | FrontFlow:
        """PX4Flow output (metric, sensor frame = body axes): angular flow = velocity across the
        optical axis / distance along it + the body rotation; the unit's gyro takes the rotation
        out (its bias and scale error stay), its sonar's last range scales to m/s. ``kin``: body
        velocity and rates."""
        (vbx, vby, vbz), (p, q, r) = kin
        fl = self.s.flow
        scale_range, true_range = self._px_range[name], self._px_true[name]
        faults = self._faults
        if not true_range:
            return (BottomFlow if name == "bottom_flow" else FrontFlow)(stamp, 0.0, 0.0, 0, scaled=False)  # nothing in view
        # Without its sonar's range the unit still measures the angular flow (and its quality);
        # the metric flow reads 0. Those readings draw from a generator of their own, so flights
        # where every unit has its range keep their noise sequences.
        g = self.noise.gauss if scale_range is not None else self._unscaled_noise.gauss
        # Image quality: texture (the low_texture fault takes a share away) and light (the
        # vehicle's own light falls off as 1/d^2 beyond ``light_range_m``).
        texture = 1.0 - faults.low_texture.get(owner, 0.0) if faults.low_texture else 1.0
        light = min(1.0, (fl.light_range_m / true_range) ** 2)
        share = texture * light
        quality = int(fl.quality * share + g(0.0, 15.0))
        quality = 0 if quality < 0 else 255 if quality > 255 else quality  # 0..255
        if faults.flow_quality_zero and owner in faults.flow_quality_zero:
            quality = 0
        sigma = fl.noise_rad_s * (1.0 + 3.0 * (1.0 - share))
        (gbx, gby), (gsx, gsy) = self._px_gyro[name]
        gn = fl.gyro_noise_rad_s
        if name == "bottom_flow":
            # Camera along -z: x flow = vx/d - q, y flow = vy/d + p (rotation in rad/s).
            across, rot = (vbx, vby), (-q, p)
        else:
            # Camera along +x: y flow = vy/d + r, z flow = vz/d - q.
            across, rot = (vby, vbz), (r, -q)
        bx, by = self.bias[name]
        out, rates = [], []
        for v, w, gb, gsc, b in ((across[0], rot[0], gbx, gsx, bx), (across[1], rot[1], gby, gsy, by)):
            flow_rad_s = v / true_range + w
            compensated = flow_rad_s - (w * (1.0 + gsc) + gb + g(0.0, gn))
            rate = compensated + g(0.0, sigma)
            rates.append(rate)
            out.append(rate * scale_range + b if scale_range is not None else 0.0)
        return (BottomFlow if name == "bottom_flow" else FrontFlow)(
            stamp, out[0], out[1], quality, rates[0], rates[1], scale_range is not None
        )

    def read(self, now: float, sim: QuadrotorSim) -> Measurements:
        """Latest reading each sensor has delivered by ``now``, and the IMU's mean specific force
        since the previous read (body frame) with the autopilot's attitude estimate."""
        latest = {name: ch.deliver(now) for name, ch in self.ch.items()}
        return Measurements(imu=self._imu(now, sim), **latest)


class _Sampler:
    __slots__ = ("suite", "dropped", "faults")

    def __init__(self, suite: SensorSuite, dropped: frozenset[SensorName], faults: SensorFaults) -> None:
        self.suite, self.dropped, self.faults = suite, dropped, faults

    @property
    def next_due_s(self) -> float:
        return self.suite._next_due

    def __call__(self, sim: QuadrotorSim) -> None:
        self.suite.sample(sim, self.dropped, self.faults)
