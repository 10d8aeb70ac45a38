"""Battery: drains linearly while the motors spin, faster with thrust above hover."""

from __future__ import annotations

from inspect_pipe.flight.scenario import Battery as BatterySpec


class Battery:
    def __init__(self, spec: BatterySpec) -> None:
        self.spec = spec
        self.percent = spec.start_percent

    def drain(self, dt: float, thrust_over_hover: float) -> None:
        """``thrust_over_hover``: collective thrust relative to hover (0 when the motors are off)."""
        if thrust_over_hover <= 0.0:
            return
        rate = self.spec.drain_percent_per_min / 60.0 * max(thrust_over_hover, 0.3)
        self.percent = max(0.0, self.percent - rate * dt)
