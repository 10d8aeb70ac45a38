"""The horizontal sonars' range rates: beyond Table I, the horizontal speed measurements of the
alarm modes (-1, -2), and the closing speeds the clearances are brought to ``now`` with.

Where nothing in Table I measures the horizontal speed, the speed observers carry it on with the
IMU, which drifts with whatever accelerometer bias is left, so a station-keeping loop lets the
vehicle creep away (bottom flow quality 0 during a link loss: 0.55 m in 4 s beside walls the side
sonars heard 2.6-3.9 m away). A horizontal sonar's range rate measures the speed along its axis
(a wall ahead closing at 1 m/s: vx = +1) and corrects the observer of that axis.
"""

from __future__ import annotations

import math
from collections import deque

from inspect_pipe.flight_stack.messages import Measurements
from inspect_pipe.flight_stack.observers import RangeSlope, SpeedObserver
from inspect_pipe.flight_stack.params import EstimationParams
from inspect_pipe.flight_stack.sensor_health import SONAR_LATENCY_S, ReadingLedger

__all__ = ["SonarRangeRates"]

_SONARS = ("front", "left", "right")


class SonarRangeRates:
    """Each horizontal sonar's range rate (a least-squares slope of its last samples), the
    heading and the speeds over the slope window, and the corrections of the alarm modes."""

    def __init__(self, params: EstimationParams, ledger: ReadingLedger) -> None:
        self.p, self.ledger = params, ledger
        self.slopes = {name: RangeSlope() for name in _SONARS}
        self.window_s = self.slopes["front"].window_s
        #: this tick's range rate of each sonar (m/s, the range's change), None when unknown
        self.rates: dict[str, float | None] = {name: None for name in _SONARS}
        self._v_hist: deque[tuple[float, float, float]] = deque()  # (t, observed vx, vy) over the last slope window
        self._yaw_hist: list[tuple[float, float]] = []  # (t, heading) over the last slope window

    def feed(self, now: float, m: Measurements) -> None:
        """Take each sonar's new sample; the rates of the sonars heard within their timeout."""
        p = self.p
        for name, r in (("front", m.front_sonar), ("left", m.left_sonar), ("right", m.right_sonar)):
            slope = self.slopes[name]
            if r is not None and self.ledger.new(f"{name}_samples", r.stamp_s):
                if r.range_m is None:
                    slope.miss(r.stamp_s)
                elif r.range_m <= p.sonar_max_range_m:
                    slope.add(r.stamp_s, r.range_m)
            fresh = r is not None and now - r.stamp_s <= p.sonar_timeout_s
            self.rates[name] = slope.rate(now) if fresh else None

    def note_heading(self, now: float, yaw: float) -> None:
        hist = self._yaw_hist
        hist.append((now, yaw))
        while now - hist[0][0] > self.window_s:
            hist.pop(0)

    def note_speed(self, now: float, vx: float, vy: float) -> None:
        hist = self._v_hist
        hist.append((now, vx, vy))
        while now - hist[0][0] > self.window_s + SONAR_LATENCY_S + 0.5:
            hist.popleft()

    def turning(self, now: float, yaw: float | None) -> bool:
        """The heading turned more than ``alarm_slope_max_turn_rad`` over the last slope window
        (or no heading is known, or none recently): a range then changes without any translation."""
        hist = self._yaw_hist
        if yaw is None or not hist or now - hist[-1][0] > self.p.sonar_timeout_s:
            return True
        return abs(math.remainder(hist[-1][1] - hist[0][1], math.tau)) > self.p.alarm_slope_max_turn_rad

    def correct(self, now: float, yaw: float | None, obs: tuple[SpeedObserver, ...], axes: tuple[int, ...] = (0, 1)) -> None:
        """The alarm modes' horizontal speed measurements, into the x and y observers.

        A range rate is the slope of the last ``window_s`` of samples: the speed at their mean
        stamp less the sonar's latency, not now; its innovation is taken against the estimate of
        that moment and applied now (compared with the speed now, a vehicle braking as every range
        sensor went silent took the lagging rate for its speed and coasted at 0.14 m/s for 2.5 s).
        A new surface entering the beam fails the observer's gate; the left and right sonars
        disagreeing by more than the gate's width (one of them hears a box sliding into its beam)
        say nothing. Not used while turning. Only a slope whose samples span the window with no
        echo missed among them counts (``RangeSlope.full``, the slope whose noise ``speed_noise_m_s``
        states): the samples a sonar gave between missed echoes at a shallow incidence came
        from whichever rays heard the surface and read 0.63 m/s against the vehicle's 0.07, and
        taken with a full window's noise they steered a link-loss hold 0.37 m off its point
        (docs/flight.md, Session 37)."""
        p = self.p
        if self.turning(now, yaw):
            return
        noise = p.speed_noise_m_s
        for axis, sensors in ((0, (("front", -1.0),)), (1, (("left", -1.0), ("right", 1.0)))):
            if axis not in axes:
                continue
            ob, found = obs[axis], []
            for name, sign in sensors:
                slope = self.slopes[name]
                rate, t_mid = self.rates[name], slope.t_mid
                if rate is None or t_mid is None or not slope.full or not self.ledger.new(f"{name}_slope", t_mid):
                    continue
                then = self._speed_at(t_mid - SONAR_LATENCY_S)
                found.append((sign * rate, None if then is None else then[axis]))
            # One slope's own noise is half of speed_noise_m_s (doubled there for the overlap
            # of consecutive slopes); the difference of two sensors' has sqrt(2) times that.
            if len(found) == 2 and abs(found[0][0] - found[1][0]) > p.observer_gate_sigma * noise / math.sqrt(2.0):
                continue
            for z, then in found:
                ob.correct(z, noise, then=then)

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
