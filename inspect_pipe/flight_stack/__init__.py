"""Onboard software of the MAV (the paper's Section III), pure and tick-based.

``OnboardStack.tick(now, measurements, operator, battery)`` runs state estimation
(``MAVStateUpdater``, the paper's MAV_state_updater), the behaviours (``MAVBehaviors``), the flight
state machine and the speed/height controllers, and returns the attitude set-point for the
autopilot firmware.
"""

from inspect_pipe.flight_stack.behaviors import MAVBehaviors
from inspect_pipe.flight_stack.control import PID, FlightController
from inspect_pipe.flight_stack.estimation import MAVStateUpdater, select_mode
from inspect_pipe.flight_stack.flight_machine import FlightMachine, FlightState
from inspect_pipe.flight_stack.messages import (
    AttitudeSetpoint,
    AxisVector,
    BehaviorInputs,
    BottomFlow,
    Button,
    Clearance,
    EstimationMode,
    FrontFlow,
    Measurements,
    OperatorInput,
    RangeReading,
    SpeedCommand,
    StateEstimate,
)
from inspect_pipe.flight_stack.onboard import OnboardStack, TickOutput
from inspect_pipe.flight_stack.params import StackParams

__all__ = [
    "AttitudeSetpoint",
    "AxisVector",
    "BehaviorInputs",
    "BottomFlow",
    "Button",
    "Clearance",
    "EstimationMode",
    "FlightController",
    "FlightMachine",
    "FlightState",
    "FrontFlow",
    "MAVBehaviors",
    "MAVStateUpdater",
    "Measurements",
    "OnboardStack",
    "OperatorInput",
    "PID",
    "RangeReading",
    "SpeedCommand",
    "StackParams",
    "StateEstimate",
    "TickOutput",
    "select_mode",
]
