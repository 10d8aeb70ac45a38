"""inspect_ahead: go_ahead in inspection mode; keeps the fixed-speed lateral/vertical sweep."""

from __future__ import annotations

from inspect_pipe.flight_stack.behaviors.attenuated_inspect import inspection_command
from inspect_pipe.flight_stack.behaviors.go_ahead import GoAhead
from inspect_pipe.flight_stack.messages import SpeedCommand


class InspectAhead(GoAhead):
    name = "inspect_ahead"

    def command_from(self, stick: SpeedCommand) -> SpeedCommand:
        return inspection_command(stick, self.p)
