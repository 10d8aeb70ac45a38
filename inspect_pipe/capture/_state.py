"""The vehicle state at a frame's mid-exposure, interpolated from a time-stamped state feed (the
simulator now, MAVLink telemetry later)."""

from __future__ import annotations

import bisect
from dataclasses import dataclass, replace
from typing import Protocol, Sequence

import numpy as np

from inspect_pipe.capture._geometry import slerp

__all__ = ["StateFeed", "StateSample", "TrajectoryFeed", "VehicleState", "TrueState"]


@dataclass(frozen=True, slots=True)
class TrueState:
    """Simulator ground truth."""

    position_m: tuple[float, float, float]
    R_world_body: np.ndarray  # 3x3
    velocity_m_s: tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class VehicleState:
    """What the vehicle believed at an instant (SPEC.md: position estimate, distance to the front
    wall, height, velocity, estimation mode, fsm, inspection mode); ``truth`` only in simulation."""

    t_s: float
    position_m: tuple[float, float, float] | None
    dist_front_m: float | None
    height_m: float | None
    velocity_m_s: tuple[float, float, float] | None
    est_mode: int | None
    fsm: str | None
    inspection_mode: bool | None
    truth: TrueState | None = None


StateSample = VehicleState


class StateFeed(Protocol):
    def state_at(self, t_s: float) -> VehicleState | None:
        """The state at ``t_s``, or None when the feed does not cover it."""


def _lerp(a, b, w: float):
    if a is None or b is None:
        return a if w < 0.5 else b
    if isinstance(a, tuple):
        return tuple(x + w * (y - x) for x, y in zip(a, b))
    return a + w * (b - a)


def interpolate(s0: VehicleState, s1: VehicleState, t_s: float) -> VehicleState:
    """Linear in position/velocity/distances, slerp in attitude; discrete fields from the nearer sample."""
    dt = s1.t_s - s0.t_s
    w = 0.0 if dt <= 0 else min(1.0, max(0.0, (t_s - s0.t_s) / dt))
    near = s0 if w < 0.5 else s1
    truth = None
    if s0.truth is not None and s1.truth is not None:
        truth = TrueState(
            _lerp(s0.truth.position_m, s1.truth.position_m, w),
            slerp(s0.truth.R_world_body, s1.truth.R_world_body, w),
            _lerp(s0.truth.velocity_m_s, s1.truth.velocity_m_s, w),
        )
    return VehicleState(
        t_s=t_s,
        position_m=_lerp(s0.position_m, s1.position_m, w),
        dist_front_m=_lerp(s0.dist_front_m, s1.dist_front_m, w),
        height_m=_lerp(s0.height_m, s1.height_m, w),
        velocity_m_s=_lerp(s0.velocity_m_s, s1.velocity_m_s, w),
        est_mode=near.est_mode,
        fsm=near.fsm,
        inspection_mode=near.inspection_mode,
        truth=truth,
    )


class TrajectoryFeed:
    """A feed over a growing list of samples in time order (appended by the producer)."""

    def __init__(self, samples: Sequence[VehicleState] = (), *, max_gap_s: float = 0.5) -> None:
        self.samples: list[VehicleState] = list(samples)
        self._t: list[float] = [s.t_s for s in self.samples]
        self.max_gap_s = max_gap_s

    def append(self, s: VehicleState) -> None:
        if self._t and s.t_s < self._t[-1]:
            raise ValueError("state samples must come in time order")
        self.samples.append(s)
        self._t.append(s.t_s)

    @property
    def end_s(self) -> float:
        return self._t[-1] if self._t else float("-inf")

    def state_at(self, t_s: float) -> VehicleState | None:
        if not self._t or t_s < self._t[0] or t_s > self._t[-1]:
            return None
        i = bisect.bisect_right(self._t, t_s)
        if i >= len(self._t):
            return replace(self.samples[-1], t_s=t_s)
        s0, s1 = self.samples[i - 1], self.samples[i]
        if s1.t_s - s0.t_s > self.max_gap_s:
            return None  # telemetry gap: do not invent a state
        return interpolate(s0, s1, t_s)
