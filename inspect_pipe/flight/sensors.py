"""Simulated sensors with their real rates, ranges, noise and latency.

* PX4Flow (bottom and front): metric flow at 100 Hz, 20 ms latency, noise growing with distance,
  a small per-unit bias, quality 0..255 (0 without a sonar echo: no metric scale); its MaxBotix
  HRLV-EZ4 sonar at 10 Hz, 0.3..5 m, 50 ms latency.
* Side HRLV-EZ4 sonars (left, right): 10 Hz, 5 m.
* Every horizontal sonar has a beam, not a ray: an ultrasonic ranger reports its first echo, the
  nearest surface inside its beam. The beam is a horizontal fan of ``sonar_beam_rays`` rays over
  +-``sonar_half_beam_deg`` (15 deg: MaxBotix's narrow-beam HRLV-EZ4 against the large flat plates
  of a hold); the nearest hit is the reading. A single ray along the axis missed the edge of a
  pillar or coaming that a real sonar hears (safety campaign: slides along a wall into a pillar's
  side). The fan is horizontal only: the downward PX4Flow sonar and the ToF stay single rays.
* TeraRanger One (bottom): 100 Hz, 0.2..14 m, 10 ms latency, +-2 cm.
* The autopilot's IMU: mean acceleration per control tick, with noise and a residual bias.

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
from inspect_pipe.flight_stack.messages import BottomFlow, FrontFlow, ImuReading, Measurements, RangeReading

__all__ = ["FlowSpec", "RangeSpec", "SensorFaults", "SensorSuite", "SensorSpecs"]


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
    noise_m_s: float = 0.015
    noise_per_m: float = 0.01  # flow noise grows with the distance to the textured surface
    bias_m_s: float = 0.002  # std of the per-unit bias (gyro compensation, lens)
    quality: int = 200


@dataclass(frozen=True)
class ImuSpec:
    noise_m_s2: float = 0.05
    bias_m_s2: float = 0.03  # std of the residual accelerometer bias after calibration
    yaw_drift_rad_s: float = 0.002  # std of the heading estimate's drift rate (0.1 deg/s)


@dataclass(frozen=True)
class SensorSpecs:
    flow: FlowSpec = FlowSpec()
    imu: ImuSpec = ImuSpec()
    sonar: RangeSpec = RangeSpec(10.0, 0.05, 0.3, 5.0, 0.005, 0.002)
    tof: RangeSpec = RangeSpec(100.0, 0.01, 0.2, 14.0, 0.02)
    grazing_deg: float = 35.0  # incidence from the surface normal beyond which a sonar may miss its echo
    sonar_half_beam_deg: float = 15.0  # horizontal sonars: half-width of the beam
    sonar_beam_rays: int = 5  # rays across the beam (odd: one on the axis)


@dataclass(frozen=True)
class SensorFaults:
    """Sensor faults active during one physics step (besides ``dropped`` sensors)."""

    packet_loss: dict = field(default_factory=dict)  # SensorName -> probability a sample is lost
    stuck: frozenset = frozenset()  # SensorName: repeats its last reading
    spurious_max_range: dict = field(default_factory=dict)  # SensorName -> probability at grazing incidence
    range_loss: bool = False  # every range sensor silent
    flow_quality_zero: frozenset = frozenset()  # SensorName (bottom_flow, front_flow)

    def any(self) -> bool:
        return bool(self.packet_loss or self.stuck or self.spurious_max_range or self.range_loss or self.flow_quality_zero)


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


def _heading_velocity(sim: QuadrotorSim) -> tuple[float, float, float]:
    """The vehicle's velocity (m/s) in the heading frame (rotated by the yaw only)."""
    vx, vy, vz = sim.velocity
    _, _, yaw = sim.euler()
    c, sn = math.cos(yaw), math.sin(yaw)
    return c * vx + sn * vy, -sn * vx + c * vy, vz


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
        self.noise = _NormalStream(seed * 104729 + 11)  # per-sample measurement noise
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
            "bottom_sonar": ((0.0, 0.0, -1.0),), "bottom_tof": ((0.0, 0.0, -1.0),),
            "front_sonar": _fan(0.0, self.s), "left_sonar": _fan(math.pi / 2, self.s), "right_sonar": _fan(-math.pi / 2, self.s),
        }
        # (name, channel, owning unit, beam directions or None for a flow output) in sampling
        # order (the order the noise is drawn in).
        self._channels = tuple((name, ch, self._owner[name], self._dirs.get(name)) for name, ch in self.ch.items())

    def _imu(self, now: float, sim: QuadrotorSim) -> ImuReading | None:
        v = sim.velocity
        prev, self._imu_prev = self._imu_prev, (now, v)
        if prev is None or now <= prev[0]:
            return None
        t0, (vx0, vy0, vz0) = prev
        dt = now - t0
        ax, ay, az = (v[0] - vx0) / dt, (v[1] - vy0) / dt, (v[2] - vz0) / dt
        _, _, yaw = sim.euler()
        c, sn = math.cos(yaw), math.sin(yaw)
        g, sigma = self.noise.gauss, self.s.imu.noise_m_s2
        b = self._imu_bias
        return ImuReading(
            now,
            c * ax + sn * ay + b[0] + g(0.0, sigma),
            -sn * ax + c * ay + b[1] + g(0.0, sigma),
            az + b[2] + g(0.0, sigma),
            yaw + self._yaw_drift_rad_s * now,  # the autopilot's gyro-integrated heading
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
        pos = v_heading = None  # the vehicle's state, read once per sample
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
                continue
            stamp = t + ch.latency  # delivery time: what the onboard clock stamps
            if faulty:
                if owner in faults.packet_loss and self.fault_rng.random() < faults.packet_loss[owner]:
                    continue
                if owner in faults.stuck and ch.last_value is not None:
                    ch.queue.append((stamp, dataclasses.replace(ch.last_value, stamp_s=stamp)))
                    continue
            if dirs is None:
                if v_heading is None:
                    v_heading = _heading_velocity(sim)
                value = self._measure_flow(name, owner, v_heading, stamp)
            else:
                if pos is None:
                    pos = sim.position
                value = self._measure_range(name, owner, dirs, sim, pos, stamp)
            ch.last_value = value
            ch.queue.append((stamp, value))
        self._next_due = next_due

    def _measure_range(self, name: str, owner: SensorName, dirs, sim: QuadrotorSim, pos, stamp: float) -> RangeReading:
        """The nearest echo over the sensor's rays, with noise."""
        s = self.s
        if name == "bottom_tof":
            spec, spurious = s.tof, None
        else:
            spurious_faults = self._faults.spurious_max_range
            spec, spurious = s.sonar, spurious_faults.get(owner) if spurious_faults else None
        rng = self._range(spec, sim.first_echo(pos, dirs))
        # A reading implies an echo: the incidence is that of the ray that made it.
        if spurious and rng is not None and sim.incidence_rad() > math.radians(s.grazing_deg):
            if self.fault_rng.random() < spurious:
                rng = spec.max_range_m  # the echo skidded off: the sonar reports open space
        if name == "bottom_sonar":
            self._px_range["bottom_flow"] = rng
        elif name == "front_sonar":
            self._px_range["front_flow"] = rng
        return RangeReading(stamp, rng)

    def _measure_flow(self, name: str, owner: SensorName, v_heading, stamp: float) -> BottomFlow | FrontFlow:
        """Optical flow, in the heading frame (gyro-compensated), scaled by the unit's sonar;
        ``v_heading``: the vehicle's velocity in the heading frame."""
        hx, hy, vz = v_heading
        fl = self.s.flow
        scale_range = self._px_range[name]
        bx, by = self.bias[name]
        g = self.noise.gauss
        if scale_range is None:
            sigma, quality = 0.0, 0
        else:
            sigma, quality = fl.noise_m_s + fl.noise_per_m * scale_range, fl.quality + int(g(0.0, 15.0))
        quality = 0 if quality < 0 else 255 if quality > 255 else quality  # 0..255
        if self._faults.flow_quality_zero and owner in self._faults.flow_quality_zero:
            quality = 0
        if sigma == 0.0:
            a = b = 0.0  # no metric scale without an echo
        elif name == "bottom_flow":
            a, b = hx + bx + g(0.0, sigma), hy + by + g(0.0, sigma)
        else:
            a, b = hy + bx + g(0.0, sigma), vz + by + g(0.0, sigma)
        return (BottomFlow if name == "bottom_flow" else FrontFlow)(stamp, a, b, quality)

    def read(self, now: float, sim: QuadrotorSim) -> Measurements:
        """Latest reading each sensor has delivered by ``now``, and the IMU's mean acceleration
        since the previous read (heading frame, gravity removed)."""
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
