"""Pure speed-limit laws of the baseline shields (no state, no clock)."""

from __future__ import annotations

import math


def jerk_limited_max_speed_m_s(distance_m: float, *, accel_m_s2: float, jerk_m_s3: float) -> float:
    """Largest speed from which a stop within ``distance_m`` is possible when the deceleration
    ramps up at ``jerk_m_s3`` to at most ``accel_m_s2``.

    Stopping distance from speed v: v^2/(2a) + v*a/(2j) (the ramp costs a/j seconds at about v);
    solved for v. 0 for a distance <= 0.
    """
    if distance_m <= 0.0:
        return 0.0
    a, j = accel_m_s2, jerk_m_s3
    b = a * a / (2.0 * j)
    return -b + math.sqrt(b * b + 2.0 * a * distance_m)


def quadratic_scale(distance_m: float, *, keep_m: float, band_m: float) -> float:
    """1 at ``keep_m + band_m`` and beyond, falling quadratically to 0 at ``keep_m``."""
    r = (distance_m - keep_m) / band_m
    r = min(max(r, 0.0), 1.0)
    return r * r


def sqrt_brake_speed_m_s(distance_m: float, *, margin_m: float, accel_m_s2: float) -> float:
    """Square-root braking law: the speed that stops at ``margin_m`` decelerating at ``accel_m_s2``."""
    return math.sqrt(2.0 * accel_m_s2 * max(distance_m - margin_m, 0.0))
