"""Pure speed-limit laws of the baseline shields (no state, no clock), re-derived from the
autopilots' code and documentation (docs/campaign.md)."""

from __future__ import annotations

import math


def px4_max_speed_from_distance(distance_m: float, *, accel_m_s2: float, jerk_m_s3: float, final_speed_m_s: float = 0.0) -> float:
    """PX4 ``math::trajectory::computeMaxSpeedFromDistance``: the largest speed that still slows
    to ``final_speed_m_s`` within ``distance_m`` at ``accel_m_s2``, allowing 2 a / j for the
    deceleration to build up: v_f^2 = v^2 - 2 a (x - v 2 a / j), solved for v (never below v_f)."""
    b = 4.0 * accel_m_s2 * accel_m_s2 / jerk_m_s3
    c = -2.0 * accel_m_s2 * distance_m - final_speed_m_s * final_speed_m_s
    return max(0.5 * (-b + math.sqrt(b * b - 4.0 * c)), final_speed_m_s)


def px4_cp_scale(distance_m: float, *, keep_m: float, scale_distance_m: float) -> float:
    """PX4 ``CollisionPrevention::_getScale``: ((d - keep) / scale distance)^2 up to 1 outside the
    keep distance; inside it the (negative) breach itself, which turns the setpoint around."""
    s = distance_m - keep_m
    if s > 0.0:
        s = (s / scale_distance_m) ** 2
    return min(s, 1.0)


def ardupilot_sqrt_controller(error: float, p: float, second_ord_lim: float, dt: float) -> float:
    """ArduPilot ``sqrt_controller`` (AP_Math/control.cpp): proportional (gain ``p``) within
    second_ord_lim / p^2 of zero, beyond it the square root that keeps the second derivative at
    ``second_ord_lim``; never more than closes the error within ``dt``."""
    if second_ord_lim <= 0.0:
        out = error * p
    elif p == 0.0:
        out = math.copysign(math.sqrt(2.0 * second_ord_lim * abs(error)), error)
    else:
        linear = second_ord_lim / (p * p)
        if error > linear:
            out = math.sqrt(2.0 * second_ord_lim * (error - 0.5 * linear))
        elif error < -linear:
            out = -math.sqrt(2.0 * second_ord_lim * (-error - 0.5 * linear))
        else:
            out = error * p
    if dt > 0.0:
        out = max(-abs(error) / dt, min(abs(error) / dt, out))
    return out
