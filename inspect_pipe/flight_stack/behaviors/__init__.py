"""MAV_behaviors: one module per behaviour of the paper's Fig. 3, and the node that arbitrates them."""

from inspect_pipe.flight_stack.behaviors._node import BehaviorsOutput, MAVBehaviors
from inspect_pipe.flight_stack.behaviors.attenuated_go import AttenuatedGo
from inspect_pipe.flight_stack.behaviors.attenuated_inspect import AttenuatedInspect
from inspect_pipe.flight_stack.behaviors.ensure_reference_surface_detection import EnsureReferenceSurfaceDetection
from inspect_pipe.flight_stack.behaviors.go_ahead import GoAhead
from inspect_pipe.flight_stack.behaviors.inspect_ahead import InspectAhead
from inspect_pipe.flight_stack.behaviors.limit_max_height import LimitMaxHeight
from inspect_pipe.flight_stack.behaviors.low_battery_land import LowBatteryLand
from inspect_pipe.flight_stack.behaviors.prevent_collision import PreventCollision
from inspect_pipe.flight_stack.behaviors.waiting_for_connectivity import WaitingForConnectivity

__all__ = [
    "AttenuatedGo",
    "AttenuatedInspect",
    "BehaviorsOutput",
    "EnsureReferenceSurfaceDetection",
    "GoAhead",
    "InspectAhead",
    "LimitMaxHeight",
    "LowBatteryLand",
    "MAVBehaviors",
    "PreventCollision",
    "WaitingForConnectivity",
]
