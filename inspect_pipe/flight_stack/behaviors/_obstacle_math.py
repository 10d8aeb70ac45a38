"""Pure obstacle math shared by the behaviours (no state, no clock)."""

from __future__ import annotations

import math


def attenuation(distance_m: float | None, *, start_m: float, stop_m: float) -> float:
    """Factor 1 at ``start_m`` and beyond, falling linearly to 0 at ``stop_m`` (Fig. 6 A -> B)."""
    if distance_m is None:
        return 1.0
    if distance_m <= stop_m:
        return 0.0
    if distance_m >= start_m:
        return 1.0
    return (distance_m - stop_m) / (start_m - stop_m)


def stop_point_m(distance_m: float, closing_m_s: float, *, response_time_s: float, decel_m_s2: float) -> float:
    """Where the vehicle would come to rest if it started braking now.

    ``distance_m`` is already brought to ``now`` (sensor age and latency removed); the speed loop
    still needs ``response_time_s`` before braking takes hold, then decelerates at ``decel_m_s2``.
    """
    v = max(closing_m_s, 0.0)
    return distance_m - v * response_time_s - v * v / (2.0 * decel_m_s2)


def must_stop(
    distance_m: float | None, closing_m_s: float, *, safe_m: float, response_time_s: float, decel_m_s2: float
) -> bool:
    """True when continuing would put the vehicle inside the safe distance."""
    if distance_m is None:
        return False
    return stop_point_m(distance_m, closing_m_s, response_time_s=response_time_s, decel_m_s2=decel_m_s2) < safe_m


def repulsion_m_s(
    distance_m: float, *, safe_m: float, gain_1_s: float, max_m_s: float, deadband_m: float = 0.0
) -> float:
    """Speed away from an obstacle closer than ``safe_m - deadband_m``; grows with proximity.

    Within ``deadband_m`` inside the safe distance the answer is 0 (hold): without the band a
    vehicle resting a few centimetres inside the line (sonar noise, the stop's own tolerance)
    gets a small, never-ending backward command, so it never hovers (the safety campaign found
    link losses at a wall where "hover" started 1-2 s late, and dithering at the wall)."""
    return min(gain_1_s * max(safe_m - deadband_m - distance_m, 0.0), max_m_s)


def quantize(stick_m_s: float, *, speed_m_s: float, deadband_m_s: float) -> float:
    """Inspection mode: hover, or move at the fixed speed in the stick's direction."""
    if abs(stick_m_s) <= deadband_m_s:
        return 0.0
    return math.copysign(speed_m_s, stick_m_s)


def clamp(x: float, limit: float) -> float:
    return max(-limit, min(limit, x))
