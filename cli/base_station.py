"""``inspect-pipe base-station``: the surveyor's web page in front of the simulator or an autopilot."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from cli._common import one_line_errors, web_server_token
from inspect_pipe.errors import InputError

HELP = (
    "Serve the surveyor's base station: one web page with the live camera, height, speeds, "
    "distances, estimation mode, flight state, battery, link, the behaviours acting and plain "
    "feedback, and the commands (take-off, land, inspection mode, go/inspect ahead, speeds from "
    "the keyboard or a gamepad). In inspection mode a live-mosaic panel shows the low-resolution mosaic "
    "of the sweep so far and its coverage map (gaps in red), and says when the camera stream stalls "
    "(embedded simulator; over MAVLink there is no camera stream).\n\n"
    "Binds 127.0.0.1 unless --host is given; on any other address a token is printed. The page asks for "
    "it once and exchanges it for a session cookie (scripts: 'Authorization: Bearer TOKEN'); it never goes "
    "in a URL or a log. --certfile/--keyfile serve HTTPS (give them whenever the network is not yours). "
    "Logins and commands are rate-limited. One client controls, the others watch. Every command is logged.\n\n"
    "Examples:\n\n"
    "  inspect-pipe base-station                      # embedded simulator, http://127.0.0.1:8765/\n\n"
    "  inspect-pipe base-station --vehicle sim:scenarios/fig7_inspection_sweep.yaml\n\n"
    "  inspect-pipe base-station --vehicle mavlink:udpout:127.0.0.1:14540\n\n"
    "  inspect-pipe base-station --host 0.0.0.0 --port 8080   # prints the token to give the tablet\n\n"
    "  inspect-pipe base-station --host 0.0.0.0 --certfile cert.pem --keyfile key.pem   # HTTPS"
)


@one_line_errors
def base_station(
    port: Annotated[int, typer.Option("--port", min=1, max=65535, help="TCP port")] = 8765,
    host: Annotated[str, typer.Option("--host", help="address to bind; not loopback: a token is required")] = "127.0.0.1",
    vehicle: Annotated[Optional[str], typer.Option("--vehicle", help="sim:SCENARIO.yaml or mavlink:URL (default: embedded simulator)")] = None,
    token: Annotated[Optional[str], typer.Option("--token", help="token to require (default: a new random one off loopback)")] = None,
    command_log: Annotated[Path, typer.Option("--command-log", help="JSONL log of every command with its client")] = Path("base_station_commands.jsonl"),
    certfile: Annotated[Optional[Path], typer.Option("--certfile", help="PEM certificate (chain): serve HTTPS/WSS")] = None,
    keyfile: Annotated[Optional[Path], typer.Option("--keyfile", help="PEM private key of --certfile")] = None,
) -> None:
    """Serve the surveyor's base station."""
    from inspect_pipe.flight.base_station import build_station, check_listen, is_loopback_host, serve

    token = web_server_token(host, token, certfile, keyfile)
    if command_log.exists() and command_log.is_dir():
        raise InputError(str(command_log), "is a directory", "give a file path for the command log")
    check_listen(host, port)  # before a vehicle is connected and the token printed
    station = build_station(vehicle, host=host, port=port, token=token, command_log=command_log, tls=certfile is not None)
    shown = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    typer.echo(f"base station for {station.vehicle_name}: {'https' if certfile else 'http'}://{shown}:{port}/")
    if token:
        typer.echo(f"token: {token}  (type it into the page once; requests without a session are refused)")
    if not is_loopback_host(host) and certfile is None:
        typer.echo("warning: plain HTTP off loopback: the token and the session cookie cross the network readable; "
                   "give --certfile/--keyfile", err=True)
    typer.echo(f"commands logged to {command_log}; Ctrl-C to stop")
    serve(station, host=host, port=port, certfile=certfile, keyfile=keyfile)
