"""attenuated_go: propagate the user's speed vector, attenuated towards zero near obstacles."""

from __future__ import annotations

from inspect_pipe.flight_stack.behaviors._user import attenuate
from inspect_pipe.flight_stack.messages import AxisVector, BehaviorInputs
from inspect_pipe.flight_stack.params import BehaviorParams


class AttenuatedGo:
    name = "attenuated_go"

    def __init__(self, params: BehaviorParams) -> None:
        self.p = params

    def activate(self) -> None:
        pass

    def update(self, inputs: BehaviorInputs, dt: float) -> AxisVector | None:
        # Always commands every axis: no stick means hover, which is also a user intention.
        return AxisVector.full(attenuate(inputs.stick, inputs, self.p))
