"""low_battery_land: flight viability. Contributes no speed; asks the flight machine to land."""

from __future__ import annotations

from inspect_pipe.flight_stack.messages import BehaviorInputs
from inspect_pipe.flight_stack.params import BehaviorParams


class LowBatteryLand:
    name = "low_battery_land"

    def __init__(self, params: BehaviorParams) -> None:
        self.p = params
        self.triggered = False

    def activate(self) -> None:
        self.triggered = False

    def viable(self, inputs: BehaviorInputs) -> bool:
        """False (land now) once the battery is almost exhausted; stays False."""
        if inputs.battery_percent <= self.p.low_battery_percent:
            self.triggered = True
        return not self.triggered
