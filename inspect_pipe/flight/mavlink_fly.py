"""Real-time MAVLink flights of ``inspect-pipe fly``: the simulator as a MAVLink vehicle
(``--mavlink-sim URL``), or the onboard stack flying an autopilot with the scenario's operator
script (``--vehicle mavlink:URL``). Returns the command's exit code."""

from __future__ import annotations

import json
import signal
import threading
from pathlib import Path
from typing import Callable

from inspect_pipe.errors import InputError
from inspect_pipe.flight import mavlink_codec as mc
from inspect_pipe.flight.runner import ExitStatus
from inspect_pipe.flight.scenario import Scenario

__all__ = ["fly_mavlink"]


def _stop_on_signals(stop: threading.Event) -> None:
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: stop.set())


def fly_mavlink(sc: Scenario, log: Path, *, mavlink_sim: str | None, autopilot: str, vehicle: str | None,
                echo: Callable[[str], None] = print) -> int:
    if mavlink_sim is not None and vehicle is not None:
        raise InputError("--mavlink-sim/--vehicle", "give one of them", "the simulator side or the companion side")
    if log.exists() and log.is_dir():
        raise InputError(str(log), "is a directory", "give a file path for the flight log")
    stop = threading.Event()
    _stop_on_signals(stop)
    if mavlink_sim is not None:
        from inspect_pipe.flight.mavlink_sim import AutopilotSpec, SimulatedAutopilot, open_sim_log

        try:
            flavour = mc.Autopilot(autopilot)
        except ValueError:
            raise InputError("--autopilot", f"unknown autopilot {autopilot!r}", "px4 or ardupilot") from None
        fh = open_sim_log(log)
        ap = SimulatedAutopilot(sc, mavlink_sim, spec=AutopilotSpec(flavour=flavour), log=fh)
        echo(f"{sc.name}: simulated {flavour.value} vehicle on {mavlink_sim}, real time for {sc.duration_s:.0f} s; log {log}")
        try:
            status = ap.run(stop=stop)
        finally:
            ap.close()
            if fh is not None:
                fh.close()
        s = ap.ep.stats
        echo(f"{sc.name}: {status.value} after {ap.t:.1f} s; packets in {s.packets_in}, bad {s.bad_packets}, "
             f"foreign {s.foreign_packets}, set-points refused {ap.st.rejected_setpoints}")
        if status is ExitStatus.COLLISION:
            echo(f"collision at t={ap.collided_at:.2f} s")
            return 1
        return 0

    from inspect_pipe.flight.base_station.realtime import RealTimeFlight, ScriptedOperator
    from inspect_pipe.flight.mavlink_vehicle import MavlinkLink, MavlinkPlant, parse_vehicle_url

    link = MavlinkLink(parse_vehicle_url(vehicle or "")).connect()
    plant = MavlinkPlant(link)
    log.parent.mkdir(parents=True, exist_ok=True)
    with log.open("w", buffering=1) as fh:
        fh.write(json.dumps({"format": "inspect_pipe.companion_log/1", "scenario": sc.name, "vehicle": vehicle,
                             "autopilot": link.flavour.value if link.flavour else None}) + "\n")
        t0: list[float] = []

        def write(out, snap) -> None:
            if not t0:
                t0.append(snap["t"])
            rec = dict(snap)
            rec["t"] = round(snap["t"] - t0[0], 3)
            fh.write(json.dumps(rec, separators=(",", ":")) + "\n")

        flight = RealTimeFlight(plant, ScriptedOperator(sc), scenario=sc, on_tick=write)
        echo(f"{sc.name}: flying {link.flavour.value if link.flavour else 'autopilot'} over {link.url} for {sc.duration_s:.0f} s")
        try:
            flight.run(stop, duration_s=sc.duration_s)
        finally:
            plant.close()
    state = flight.snapshot()
    echo(f"{sc.name}: {state.get('fsm')} after {sc.duration_s:.1f} s; autopilot events: {', '.join(plant.events) or 'none'}; log {log}")
    return 0
