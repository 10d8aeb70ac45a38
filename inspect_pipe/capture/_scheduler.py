"""The capture rate: deadlines ``t0 + k / rate`` on an injected clock, never drifting; a deadline
missed by a whole period is skipped and counted, not made up with a burst."""

from __future__ import annotations

import math
from dataclasses import dataclass

from inspect_pipe.capture._clock import Clock

__all__ = ["RateScheduler", "Tick"]


@dataclass(frozen=True, slots=True)
class Tick:
    k: int  # deadline number since the start
    deadline_s: float
    late_s: float  # how late the caller got control back (>= 0)
    skipped: int  # deadlines skipped before this one because we were late by >= 1 period


class RateScheduler:
    def __init__(self, rate_hz: float, clock: Clock, *, start_s: float | None = None) -> None:
        if not (rate_hz > 0 and math.isfinite(rate_hz)):
            raise ValueError(f"rate must be > 0 Hz, got {rate_hz}")
        self.rate_hz = float(rate_hz)
        self.period_s = 1.0 / self.rate_hz
        self.clock = clock
        self.t0 = clock.now() if start_s is None else float(start_s)
        self._k = 0
        self.skipped_total = 0

    def deadline(self, k: int) -> float:
        return self.t0 + k * self.period_s

    @property
    def next_deadline_s(self) -> float:
        return self.deadline(self._k)

    def wait(self) -> Tick:
        """Sleep until the next deadline and return it."""
        now = self.clock.now()
        skipped = 0
        while self.deadline(self._k) + self.period_s <= now:  # a whole period late: skip it
            self._k += 1
            skipped += 1
        self.clock.sleep_until(self.deadline(self._k))
        k = self._k
        self._k += 1
        self.skipped_total += skipped
        return Tick(k, self.deadline(k), max(0.0, self.clock.now() - self.deadline(k)), skipped)
