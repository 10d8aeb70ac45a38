"""``inspect-pipe fly``: fly a scenario in the embedded simulator, headless and faster than real
time, and write the flight log."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from cli._common import choices, one_line_errors
from inspect_pipe.errors import InputError

HELP = (
    "Fly a scenario (YAML, inspect_pipe.scenario/1) in the simulated cargo hold and write the "
    "flight log (JSONL, one line per control tick).\n\n"
    "Exit 0 when the flight ended landed or still flying with no collision, 1 on a collision, "
    "2 on a bad scenario.\n\nExamples:\n\n"
    "  inspect-pipe fly --scenario scenarios/fig6_top_attenuated_go.yaml --log out/fig6.jsonl\n\n"
    "  inspect-pipe fly --scenario scenarios/fig7_inspection_sweep.yaml --log out/fig7.jsonl\n\n"
    "  inspect-pipe fly --scenario scenarios/inspection_sweep_wall.yaml --log out/wall.jsonl --sweep out/wall_sweep\n\n"
    "  inspect-pipe fly --scenario scenarios/inspection_sweep_wall.yaml --log out/wall.jsonl --sweep out/wall_sweep --tlog out/wall.tlog\n\n"
    "  inspect-pipe fly --scenario scenarios/link_loss.yaml --log out/sim.jsonl --mavlink-sim udp:127.0.0.1:14540\n\n"
    "  inspect-pipe fly --scenario scenarios/link_loss.yaml --log out/companion.jsonl --vehicle mavlink:udpout:127.0.0.1:14540"
)

Autopilot = choices("Autopilot", ("px4", "ardupilot"))  # inspect_pipe.flight.mavlink_codec.Autopilot


@one_line_errors
def fly(
    scenario: Annotated[Path, typer.Option("--scenario", help="scenario file (YAML or JSON)")],
    log: Annotated[Path, typer.Option("--log", help="flight log to write (JSONL)")],
    sweep: Annotated[Optional[Path], typer.Option("--sweep", help="also write the camera's sweep (directory), each frame placed on a live mosaic as it is written (its coverage and gaps are printed)")] = None,
    mavlink_sim: Annotated[Optional[str], typer.Option("--mavlink-sim", help="expose the simulator as a MAVLink vehicle on URL (udp:HOST:PORT listens), in real time")] = None,
    autopilot: Annotated[Autopilot, typer.Option("--autopilot", help="with --mavlink-sim: px4 (offboard) or ardupilot (guided)")] = Autopilot.px4,
    vehicle: Annotated[Optional[str], typer.Option("--vehicle", help="mavlink:URL: fly a real autopilot with the scenario's operator script")] = None,
    tlog: Annotated[Optional[Path], typer.Option("--tlog", help="also write the MAVLink telemetry a real autopilot streams (.tlog, as a ground station records it; docs/import.md)")] = None,
    params: Annotated[Optional[Path], typer.Option("--params", help="stack parameter file {group: {name: value}} over the defaults; each value within its declared bounds (docs/flight.md)")] = None,
) -> None:
    """Fly a scenario in the simulated cargo hold and write the flight log."""
    # imported here: the simulator (MuJoCo) costs every other command 0.26 s at start-up
    from inspect_pipe.flight import ExitStatus, FlightLogWriter, load_scenario, run_scenario
    from inspect_pipe.flight_stack import StackParams
    from inspect_pipe.flight_stack.params import load_params

    sc = load_scenario(scenario)
    stack_params = load_params(params) if params is not None else None
    if params is not None and (mavlink_sim is not None or vehicle is not None):
        raise InputError("--params", "applies to headless flights only", "drop --params, or fly without --mavlink-sim/--vehicle")
    if tlog is not None and (mavlink_sim is not None or vehicle is not None):
        raise InputError("--tlog", "is written by headless flights only", "on a MAVLink link, record the telemetry with a ground station")
    if mavlink_sim is not None or vehicle is not None:  # real-time MAVLink flights (docs/base_station.md)
        from inspect_pipe.flight.mavlink_fly import fly_mavlink

        raise typer.Exit(fly_mavlink(sc, log, mavlink_sim=mavlink_sim, autopilot=autopilot.value, vehicle=vehicle, echo=typer.echo))
    if log.exists() and log.is_dir():
        raise InputError(str(log), "is a directory", "give a file path for the flight log")
    recorder = None
    if sweep is not None:
        from inspect_pipe.capture.sources.sim import TrajectoryRecorder

        if sweep.exists() and (not sweep.is_dir() or any(sweep.iterdir())):
            raise InputError(str(sweep), "exists and is not an empty directory", "give a new sweep directory")
        recorder = TrajectoryRecorder(sc)
    tlog_writer = None
    if tlog is not None:
        from inspect_pipe.flight.tlog import TlogWriter

        tlog_writer = TlogWriter(tlog, sc)
    callbacks = [cb for cb in (recorder, tlog_writer) if cb is not None]
    try:
        writer = FlightLogWriter(log, sc, tick_hz=(stack_params or StackParams()).control.tick_hz)
        with writer:
            if not callbacks:
                result = run_scenario(sc, on_tick=writer, params=stack_params)
            else:
                def on_tick(rec) -> None:
                    writer(rec)
                    for cb in callbacks:
                        cb(rec)

                result = run_scenario(sc, on_tick=on_tick, params=stack_params)
    except OSError as err:
        if tlog_writer is not None:
            tlog_writer.close(keep=False)
        raise InputError(str(log), f"cannot write the flight log ({err.strerror})", "choose a writable path") from None
    except BaseException:
        if tlog_writer is not None:
            tlog_writer.close(keep=False)
        raise
    if tlog_writer is not None:
        tlog_writer.close()
        typer.echo(f"tlog {tlog}: {tlog_writer.messages} MAVLink messages")
    typer.echo(
        f"{sc.name}: {result.status.value}, {result.final_fsm.value} after {result.sim_time_s:.1f} s "
        f"({result.speed_x_real_time:.0f}x real time); log {log}"
    )
    if recorder is not None and sweep is not None:
        from inspect_pipe.capture.sources.sim import capture_flight

        from inspect_pipe.mosaic import LiveFeed

        live = LiveFeed()
        try:
            cap = capture_flight(sc, recorder.feed, sweep, live=live)
        finally:
            final = live.close()
        typer.echo(f"sweep {sweep}: {cap.frames_written} frames at {sc.camera.fps:g} Hz ({cap.reason.value})")
        typer.echo(final.line())
        if cap.writer_error:
            raise InputError(str(sweep), cap.writer_error)
    if result.status is ExitStatus.COLLISION:
        typer.echo(f"collision at t={result.collided_at_s:.2f} s", err=True)
        raise typer.Exit(1)
