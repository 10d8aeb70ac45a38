"""Everything around a flight: the simulated vehicle in its cargo hold, its sensors, battery and
operator link, scenario files, the scenario runner and the flight log."""

from inspect_pipe.flight.flight_log import FlightLogWriter, record_to_json
from inspect_pipe.flight.runner import ExitStatus, FlightResult, SimParts, TickRecord, run_scenario
from inspect_pipe.flight.scenario import Scenario, load_scenario, parse_scenario

__all__ = [
    "ExitStatus",
    "FlightLogWriter",
    "FlightResult",
    "Scenario",
    "SimParts",
    "TickRecord",
    "load_scenario",
    "parse_scenario",
    "record_to_json",
    "run_scenario",
]
