"""Clocks: time is an input. The capture loop and sources take a :class:`Clock`, so tests and the
simulator step time by hand."""

from __future__ import annotations

import datetime as _dt
import threading
import time
from typing import Protocol

__all__ = ["Clock", "ManualClock", "MonotonicClock", "utc_iso"]


class Clock(Protocol):
    def now(self) -> float:
        """Seconds on a monotonic time base."""

    def sleep_until(self, t: float) -> None:
        """Return at ``t`` (or at once when ``t`` is past)."""

    def utc(self, t: float) -> str:
        """ISO 8601 UTC time of the monotonic instant ``t``."""


def utc_iso(epoch_s: float) -> str:
    return _dt.datetime.fromtimestamp(epoch_s, tz=_dt.timezone.utc).isoformat(timespec="microseconds").replace("+00:00", "Z")


class MonotonicClock:
    """Host monotonic clock; UTC from one wall-clock reading at construction (so an NTP step in
    the middle of a sweep does not bend its time base)."""

    def __init__(self, *, spin_s: float = 0.002) -> None:
        self._mono0 = time.monotonic()
        self._epoch0 = time.time()
        self.spin_s = spin_s  # the last ``spin_s`` before a deadline are busy-waited (sleep overshoots)

    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, t: float) -> None:
        while True:
            left = t - time.monotonic()
            if left <= 0:
                return
            if left > self.spin_s:
                time.sleep(left - self.spin_s)
            else:
                time.sleep(0)

    def utc(self, t: float) -> str:
        return utc_iso(self._epoch0 + (t - self._mono0))


class ManualClock:
    """A clock that moves only when told: ``sleep_until`` jumps to the deadline (simulated time),
    ``advance`` adds time (e.g. a grab that takes a while). Thread-safe."""

    def __init__(self, start_s: float = 0.0, epoch_s: float = 1_700_000_000.0) -> None:
        self._t = float(start_s)
        self._epoch = epoch_s
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            return self._t

    def sleep_until(self, t: float) -> None:
        with self._lock:
            self._t = max(self._t, float(t))

    def advance(self, dt: float) -> None:
        with self._lock:
            self._t += float(dt)

    def utc(self, t: float) -> str:
        return utc_iso(self._epoch + t)
