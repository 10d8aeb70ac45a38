"""``inspect-pipe fly``: fly a scenario in the embedded simulator, headless and faster than real
time, and write the flight log."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cli._common import one_line_errors
from inspect_pipe.errors import InputError
from inspect_pipe.flight import ExitStatus, FlightLogWriter, load_scenario, run_scenario
from inspect_pipe.flight_stack import StackParams

HELP = (
    "Fly a scenario (YAML, inspect_pipe.scenario/1) in the simulated cargo hold and write the "
    "flight log (JSONL, one line per control tick).\n\n"
    "Exit 0 when the flight ended landed or still flying with no collision, 1 on a collision, "
    "2 on a bad scenario.\n\nExamples:\n\n"
    "  inspect-pipe fly --scenario scenarios/fig6_top_attenuated_go.yaml --log out/fig6.jsonl\n\n"
    "  inspect-pipe fly --scenario scenarios/fig7_inspection_sweep.yaml --log out/fig7.jsonl"
)


@one_line_errors
def fly(
    scenario: Annotated[Path, typer.Option("--scenario", help="scenario file (YAML or JSON)")],
    log: Annotated[Path, typer.Option("--log", help="flight log to write (JSONL)")],
) -> None:
    """Fly a scenario in the simulated cargo hold and write the flight log."""
    sc = load_scenario(scenario)
    if log.exists() and log.is_dir():
        raise InputError(str(log), "is a directory", "give a file path for the flight log")
    try:
        writer = FlightLogWriter(log, sc, tick_hz=StackParams().control.tick_hz)
        with writer:
            result = run_scenario(sc, on_tick=writer)
    except OSError as err:
        raise InputError(str(log), f"cannot write the flight log ({err.strerror})", "choose a writable path") from None
    typer.echo(
        f"{sc.name}: {result.status.value}, {result.final_fsm.value} after {result.sim_time_s:.1f} s "
        f"({result.speed_x_real_time:.0f}x real time); log {log}"
    )
    if result.status is ExitStatus.COLLISION:
        typer.echo(f"collision at t={result.collided_at_s:.2f} s", err=True)
        raise typer.Exit(1)
