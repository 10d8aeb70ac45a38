"""The clearances the behaviours keep: each horizontal sonar's distance brought to ``now`` and
lowered to the nearest surface the obstacle memory remembers facing that sector."""

from __future__ import annotations

from inspect_pipe.flight_stack.messages import Clearance, EstimationMode, Measurements, RangeReading, StateEstimate
from inspect_pipe.flight_stack.obstacle_memory import ObstacleMemory, oblique_wall
from inspect_pipe.flight_stack.params import EstimationParams
from inspect_pipe.flight_stack.sensor_health import SONAR_LATENCY_S, ReadingLedger, fresh_range

__all__ = ["Clearances"]

_HALF_PI = 1.5707963267948966


class Clearances:
    """Obstacle distances brought to ``now``: a 10 Hz sonar reading is up to 0.15 s old."""

    def __init__(self, params: EstimationParams, memory: ObstacleMemory, ledger: ReadingLedger, *,
                 beam_half_rad: float, oblique_margin_m_s: float) -> None:
        self.p, self.memory, self.ledger = params, memory, ledger
        self._beam_half_rad, self._oblique_margin_m_s = beam_half_rad, oblique_margin_m_s

    def update(self, now: float, m: Measurements, est: StateEstimate, front_m: float | None,
               rates: dict[str, float | None], yaw: float | None) -> Clearance:
        """``front_m``: the front range observer's range; ``rates``: the sonars' range rates."""
        p = self.p

        def at_now(r: RangeReading | None, closing_m_s: float) -> float | None:
            if not fresh_range(r, now, p.sonar_timeout_s, p.sonar_max_range_m):
                return None
            age = now - r.stamp_s + SONAR_LATENCY_S  # type: ignore[union-attr]
            return r.range_m - closing_m_s * age  # type: ignore[union-attr,operator]

        def stale(r: RangeReading | None) -> bool:
            return r is None or now - r.stamp_s > p.sonar_timeout_s

        closing = {name: None if rate is None else -rate for name, rate in rates.items()}

        front = front_m if fresh_range(m.front_sonar, now, p.sonar_timeout_s, p.sonar_max_range_m) else None
        left, right = at_now(m.left_sonar, est.vy_m_s), at_now(m.right_sonar, -est.vy_m_s)
        if yaw is not None and p.memory_keep_s > 0.0:
            self._oblique_walls(m, est, closing, front, left, right, yaw)
            front, left, right = (
                self._remembered(now, name, axis, r, d, yaw)
                for name, axis, r, d in (
                    ("front", 0.0, m.front_sonar, front),
                    ("left", _HALF_PI, m.left_sonar, left),
                    ("right", -_HALF_PI, m.right_sonar, right),
                )
            )
        return Clearance(
            front_m=front,
            left_m=left,
            right_m=right,
            down_m=est.height_m if est.mode != EstimationMode.ALARM_NONE else None,
            front_stale=stale(m.front_sonar),
            left_stale=stale(m.left_sonar),
            right_stale=stale(m.right_sonar),
            front_closing_m_s=closing["front"],
            left_closing_m_s=closing["left"],
            right_closing_m_s=closing["right"],
        )

    def _oblique_walls(
        self, m: Measurements, est: StateEstimate, closing: dict[str, float | None],
        front: float | None, left: float | None, right: float | None, yaw: float,
    ) -> None:
        """Store the wall that the front sonar and a side sonar hear together at an angle
        (:func:`oblique_wall`), when either has a fresh echo: pushed while yawing, the vehicle
        otherwise stops on readings that overstate the perpendicular distance (safety campaign).

        Two readings alone cannot tell such a wall from an inside corner, and a wall across a
        corner blocked the escape along one of its walls (safety campaign). The wall is taken
        only with evidence of obliquity: one of the two ranges closes faster than the speed along
        its own sensor's axis explains (a corner's walls close at exactly those speeds), and it is
        kept only ``oblique_keep_s`` unless the evidence renews it (a pillar's end face heard
        obliquely on the way into a corner is such evidence once, and the wall fitted across
        that corner must not outlive it)."""
        if front is None or m.front_sonar is None:
            return
        h = self._beam_half_rad
        margin = self._oblique_margin_m_s

        def oblique(name: str, axis_speed: float) -> bool:
            c = closing.get(name)
            return c is not None and c > max(axis_speed, 0.0) + margin

        front_oblique = oblique("front", est.vx_m_s)
        for name, side, r, sign in (("left", left, m.left_sonar, 1.0), ("right", right, m.right_sonar, -1.0)):
            if side is None or r is None:
                continue
            if not (front_oblique or oblique(name, sign * est.vy_m_s)):
                continue
            stamp = max(m.front_sonar.stamp_s, r.stamp_s)
            if not self.ledger.new(f"{name}_wall", stamp):
                continue
            wall = oblique_wall(front, side, h)
            if wall is not None:
                phi, d = wall
                self.memory.add(stamp, sign * phi, d, yaw, keep_s=self.p.oblique_keep_s)

    def _remembered(self, now: float, name: str, axis_rad: float, r: RangeReading | None, d: float | None,
                    yaw: float) -> float | None:
        """The sector's clearance ``d`` (from its sonar, brought to now), after storing a fresh
        echo in the obstacle memory, lowered to the nearest remembered surface facing it."""
        if d is not None and r is not None and self.ledger.new(f"{name}_memory", r.stamp_s):
            self.memory.add(r.stamp_s, axis_rad, d, yaw)
        mem = self.memory.clearance(now, axis_rad, yaw)
        if mem is None:
            return d
        return mem if d is None else min(d, mem)
