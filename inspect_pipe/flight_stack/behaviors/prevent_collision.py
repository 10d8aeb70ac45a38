"""prevent_collision: a repulsive vector away from obstacles closer than the safe distance, and a
stop on any axis whose current speed would carry the vehicle inside it.

The stop is predicted from the distance brought to ``now`` (sensor age and latency), the speed
loop's response time and a braking deceleration, so the vehicle halts at the safe distance whether
it approaches at 0.4 m/s or 1 m/s; a distance-only rule would react a sensor period late.
"""

from __future__ import annotations

from inspect_pipe.flight_stack.behaviors._obstacle_math import must_stop, repulsion_m_s
from inspect_pipe.flight_stack.behaviors.attenuated_inspect import inspection_command
from inspect_pipe.flight_stack.messages import AxisVector, BehaviorInputs
from inspect_pipe.flight_stack.params import BehaviorParams


class PreventCollision:
    name = "prevent_collision"

    def __init__(self, params: BehaviorParams) -> None:
        self.p = params

    def activate(self) -> None:
        pass

    def _axis(self, distance_m: float | None, closing_m_s: float, deadband_m: float) -> float | None:
        """Speed along the direction towards the obstacle (negative: away), or None."""
        p = self.p
        if distance_m is None:
            return None
        if distance_m < p.safe_distance_m:
            return -repulsion_m_s(
                distance_m, safe_m=p.safe_distance_m, gain_1_s=p.position_gain_1_s,
                max_m_s=p.hold_speed_max_m_s, deadband_m=deadband_m,
            )
        if must_stop(
            distance_m, closing_m_s, safe_m=p.safe_distance_m,
            response_time_s=p.response_time_s, decel_m_s2=p.brake_decel_m_s2,
        ):
            return 0.0
        return None

    def _oblique(self, distance_m: float | None, axis_m_s: float, closing_m_s: float | None) -> bool:
        """The sector's own range closes faster than the speed along its axis explains (a surface
        oblique to the sensor, e.g. yawed at a wall, closed by motion along the other axis), fast
        enough that the stop would breach the safe distance: stop every horizontal axis."""
        p = self.p
        if distance_m is None or closing_m_s is None or closing_m_s <= max(axis_m_s, 0.0) + p.oblique_margin_m_s:
            return False
        return must_stop(
            distance_m, closing_m_s, safe_m=p.safe_distance_m,
            response_time_s=p.response_time_s, decel_m_s2=p.brake_decel_m_s2,
        )

    def update(self, inputs: BehaviorInputs, dt: float) -> AxisVector | None:
        if not inputs.flying:
            return None
        c, e, p = inputs.clearance, inputs.estimate, self.p
        # Link lost: waiting_for_connectivity holds station. A vehicle resting a little inside the
        # safe distance (the stop's tolerance, a gust) holds there rather than backing away: the
        # safety campaign found link-loss "hovers" 0.5-1.4 s late from 0.02-0.1 m/s repulsions
        # 5-12 cm inside the line. Deeper inside, the repulsion acts as always.
        # The hold band is for a vehicle at rest inside the line. One still moving in (a trim the
        # integrators kept from the approach, a gust's end) is pushed back from the line itself:
        # held at zero, it crept on at 0.05-0.1 m/s for 1-2 s and ended 0.10-0.11 m inside
        # (docs/campaign.md, session 20).
        link_band = max(p.repulsion_deadband_m, p.link_loss_deadband_m)

        def band(closing_m_s: float) -> float:
            if not inputs.link_ok:
                return link_band
            return p.repulsion_deadband_m if closing_m_s <= 0.0 else 0.0

        vx = self._axis(c.front_m, e.vx_m_s, band(e.vx_m_s))
        left = self._axis(c.left_m, e.vy_m_s, band(e.vy_m_s))
        right = self._axis(c.right_m, -e.vy_m_s, band(-e.vy_m_s))
        if left is None and right is None:
            vy = None
        else:
            vy = (left or 0.0) - (right or 0.0)
        # The stop and the repulsion bound the speed towards the obstacle; the operator may still
        # leave faster (per axis, this behaviour suppresses the user's: without this, an escape
        # from a wall crawled at the repulsion speed, or not at all once inside the dead band).
        # With the link lost, the station keeping stands in for the operator (waiting_for_connectivity).
        if inputs.station_keeping is not None:
            user = inputs.station_keeping
        else:
            user = inspection_command(inputs.stick, self.p) if inputs.inspection_mode else inputs.stick
        if vx is not None:
            vx = min(vx, user.vx_m_s)
        if left is not None and right is None:
            vy = min(vy, user.vy_m_s)  # type: ignore[type-var]
        elif right is not None and left is None:
            vy = max(vy, user.vy_m_s)  # type: ignore[type-var]
        if (
            self._oblique(c.front_m, e.vx_m_s, c.front_closing_m_s)
            or self._oblique(c.left_m, e.vy_m_s, c.left_closing_m_s)
            or self._oblique(c.right_m, -e.vy_m_s, c.right_closing_m_s)
        ):
            vx = 0.0 if vx is None else vx
            vy = 0.0 if vy is None else vy
        if vx is None and vy is None:
            return None
        return AxisVector(vx_m_s=vx, vy_m_s=vy)
