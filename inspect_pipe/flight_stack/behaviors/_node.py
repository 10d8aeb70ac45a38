"""The MAV_behaviors node: the paper's Fig. 3 wired with the arbitration composites."""

from __future__ import annotations

from dataclasses import replace

from inspect_pipe.flight_stack.arbitration import MotorSchema, Multiplexer, Subsumption
from inspect_pipe.flight_stack.behaviors._obstacle_math import clamp
from inspect_pipe.flight_stack.behaviors.attenuated_go import AttenuatedGo
from inspect_pipe.flight_stack.behaviors.attenuated_inspect import AttenuatedInspect
from inspect_pipe.flight_stack.behaviors.ensure_reference_surface_detection import EnsureReferenceSurfaceDetection
from inspect_pipe.flight_stack.behaviors.go_ahead import GoAhead
from inspect_pipe.flight_stack.behaviors.inspect_ahead import InspectAhead
from inspect_pipe.flight_stack.behaviors.limit_max_height import LimitMaxHeight
from inspect_pipe.flight_stack.behaviors.low_battery_land import LowBatteryLand
from inspect_pipe.flight_stack.behaviors.prevent_collision import PreventCollision
from inspect_pipe.flight_stack.behaviors.waiting_for_connectivity import WaitingForConnectivity
from inspect_pipe.flight_stack.messages import (
    HOVER,
    AxisVector,
    BehaviorInputs,
    Button,
    Clearance,
    OperatorInput,
    SpeedCommand,
    StateEstimate,
    message,
)
from inspect_pipe.flight_stack.params import BehaviorParams


@message
class BehaviorsOutput:
    """The safe speed set-point, who shaped it, and whether flight is still viable."""

    command: SpeedCommand
    behaviors: tuple[str, ...]
    land_request: bool


def _inspection(inputs: BehaviorInputs) -> bool:
    return inputs.inspection_mode


class MAVBehaviors:
    """Combines the user's desired speed with the sensor data into a safe speed command.

    Priority (highest first), per axis: B safety (motor schema of prevent_collision,
    limit_max_height, ensure_reference_surface_detection) > C autonomy (go_ahead | inspect_ahead,
    multiplexed by inspection mode) > A user intention (waiting_for_connectivity >
    attenuated_go | attenuated_inspect). D (low_battery_land) only decides whether to land.
    """

    def __init__(self, params: BehaviorParams | None = None) -> None:
        p = self.p = params or BehaviorParams()
        self.inspection_mode = False
        self.low_battery_land = LowBatteryLand(p)
        safety = MotorSchema(
            [(PreventCollision(p), 1.0), (LimitMaxHeight(p), 1.0), (EnsureReferenceSurfaceDetection(p), 1.0)]
        )
        autonomy = Multiplexer(_inspection, {False: GoAhead(p), True: InspectAhead(p)})
        self.waiting_for_connectivity = WaitingForConnectivity(p)
        user = Subsumption(
            [self.waiting_for_connectivity, Multiplexer(_inspection, {False: AttenuatedGo(p), True: AttenuatedInspect(p)})]
        )
        self.root = Subsumption([safety, autonomy, user])

    def update(
        self,
        now_s: float,
        estimate: StateEstimate,
        clearance: Clearance,
        operator: OperatorInput,
        *,
        battery_percent: float,
        flying: bool,
        dt: float,
    ) -> BehaviorsOutput:
        buttons = operator.buttons if operator.link_ok else frozenset()
        if Button.INSPECTION_MODE_ON in buttons:
            self.inspection_mode = True
        if Button.INSPECTION_MODE_OFF in buttons:
            self.inspection_mode = False
        inputs = BehaviorInputs(
            now_s=now_s,
            estimate=estimate,
            clearance=clearance,
            # In the alarm modes (-1, -2) no sensor measures the horizontal speed: the vehicle
            # descends to land, and the operator's horizontal and vertical commands are not obeyed
            # (safety campaign: bottom flow lost with the front wall out of sonar range, the operator
            # kept pushing at 0.6 m/s on an IMU-carried speed and the descent met a coaming's edge).
            # Yaw stays the operator's.
            stick=_alarm_stick(operator.stick) if estimate.mode < 0 else (operator.stick if operator.link_ok else HOVER),
            link_ok=operator.link_ok,
            inspection_mode=self.inspection_mode,
            go_ahead_pressed=Button.GO_AHEAD in buttons,
            battery_percent=battery_percent,
            flying=flying,
        )
        if not operator.link_ok and estimate.mode >= 0:
            # The station keeping takes the operator's place: prevent_collision bounds it as it bounds the stick
            # (bounding the absent operator's zero instead cancelled the hold on any axis near a wall, and a
            # 1 m/s gust carried the vehicle 0.41 m off its rest point).
            # (the tree below calls it again this tick: same inputs, same answer; it only picks its hold point once)
            hold = self.waiting_for_connectivity.update(inputs, dt)
            if hold is not None and hold != AxisVector.full(HOVER):
                inputs = replace(inputs, station_keeping=hold.to_command())
        out = self.root.evaluate(inputs, dt)
        names = list(out.sources) if out is not None else []
        cmd = out.vector.to_command() if out is not None else HOVER
        p = self.p
        cmd = SpeedCommand(
            clamp(cmd.vx_m_s, p.max_speed_m_s),
            clamp(cmd.vy_m_s, p.max_speed_m_s),
            clamp(cmd.vz_m_s, p.max_vertical_speed_m_s),
            cmd.yaw_rate_rad_s,
        )
        viable = self.low_battery_land.viable(inputs)
        if not viable:
            names.append(self.low_battery_land.name)
        return BehaviorsOutput(cmd, tuple(names), land_request=not viable)


def _alarm_stick(stick: SpeedCommand) -> SpeedCommand:
    return SpeedCommand(0.0, 0.0, 0.0, stick.yaw_rate_rad_s)
