"""waiting_for_connectivity: hover while the link with the base station is lost."""

from __future__ import annotations

from inspect_pipe.flight_stack.messages import HOVER, AxisVector, BehaviorInputs


class WaitingForConnectivity:
    name = "waiting_for_connectivity"

    def __init__(self, params=None) -> None:
        self.p = params

    def activate(self) -> None:
        pass

    def update(self, inputs: BehaviorInputs, dt: float) -> AxisVector | None:
        return None if inputs.link_ok else AxisVector.full(HOVER)
