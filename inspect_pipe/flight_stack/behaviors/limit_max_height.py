"""limit_max_height: an attraction towards the ground when approaching the maximum height."""

from __future__ import annotations

from inspect_pipe.flight_stack.messages import AxisVector, BehaviorInputs
from inspect_pipe.flight_stack.params import BehaviorParams


class LimitMaxHeight:
    name = "limit_max_height"

    def __init__(self, params: BehaviorParams) -> None:
        self.p = params

    def activate(self) -> None:
        pass

    def update(self, inputs: BehaviorInputs, dt: float) -> AxisVector | None:
        p, e = self.p, inputs.estimate
        if not inputs.flying or e.mode < 0:
            return None
        ceiling = p.max_height_m - p.max_height_margin_m
        # Predict where a climb would take the vehicle before the speed loop reacts.
        ahead = e.altitude_m + max(e.vz_m_s, 0.0) * p.response_time_s
        if ahead < ceiling:
            return None
        return AxisVector(vz_m_s=-min(p.position_gain_1_s * max(e.altitude_m - ceiling, 0.0), p.max_vertical_speed_m_s))
