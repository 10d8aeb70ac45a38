"""attenuated_inspect: the user's intention in inspection mode.

Longitudinal and yaw commands are ignored (distance and orientation to the wall are kept for
image capture); lateral and vertical motion is either hover or the fixed inspection speed in the
stick's direction, attenuated near obstacles like attenuated_go.
"""

from __future__ import annotations

from inspect_pipe.flight_stack.behaviors._obstacle_math import quantize
from inspect_pipe.flight_stack.behaviors._user import attenuate
from inspect_pipe.flight_stack.messages import AxisVector, BehaviorInputs, SpeedCommand
from inspect_pipe.flight_stack.params import BehaviorParams


def inspection_command(stick: SpeedCommand, p: BehaviorParams) -> SpeedCommand:
    q = dict(speed_m_s=p.inspect_speed_m_s, deadband_m_s=p.stick_deadband_m_s)
    return SpeedCommand(0.0, quantize(stick.vy_m_s, **q), quantize(stick.vz_m_s, **q), 0.0)


class AttenuatedInspect:
    name = "attenuated_inspect"

    def __init__(self, params: BehaviorParams) -> None:
        self.p = params

    def activate(self) -> None:
        pass

    def update(self, inputs: BehaviorInputs, dt: float) -> AxisVector | None:
        return AxisVector.full(attenuate(inspection_command(inputs.stick, self.p), inputs, self.p))
