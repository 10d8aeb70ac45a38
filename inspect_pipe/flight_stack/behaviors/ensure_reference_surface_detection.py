"""ensure_reference_surface_detection: keep the floor or the front wall within the PX4Flow range.

With neither surface within ``reference_range_m``, optical flow has no metric scale and the state
estimate would fall into an alarm mode. Above the reference range the behaviour pulls the vehicle
down towards the floor, or towards the front wall when that is the only reference left.
"""

from __future__ import annotations

from inspect_pipe.flight_stack.messages import AxisVector, BehaviorInputs
from inspect_pipe.flight_stack.params import BehaviorParams


class EnsureReferenceSurfaceDetection:
    name = "ensure_reference_surface_detection"

    def __init__(self, params: BehaviorParams) -> None:
        self.p = params

    def activate(self) -> None:
        pass

    def update(self, inputs: BehaviorInputs, dt: float) -> AxisVector | None:
        p, e, c = self.p, inputs.estimate, inputs.clearance
        if not inputs.flying or e.mode < 0:
            return None  # the alarm modes already make the vehicle descend
        ref = p.reference_range_m
        height = c.down_m if c.down_m is not None else e.height_m
        floor_ok = height <= ref
        front_ok = c.front_m is not None and c.front_m <= ref
        if floor_ok:
            return None
        if front_ok:
            # Only the wall is left: do not let the vehicle drift out of its range.
            margin = ref - 0.5
            if c.front_m > margin:  # type: ignore[operator]
                return AxisVector(vx_m_s=min(p.position_gain_1_s * (c.front_m - margin), p.max_speed_m_s))  # type: ignore[operator]
            return None
        return AxisVector(vz_m_s=-min(p.position_gain_1_s * (height - ref) + 0.1, p.max_vertical_speed_m_s))
