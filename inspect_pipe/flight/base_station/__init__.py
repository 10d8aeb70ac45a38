"""The surveyor's base station: a local web page with the live state of the vehicle and the
commands of the paper's joystick, in front of the embedded simulator (real time) or an autopilot
over MAVLink. Needs the ``base`` extra (Starlette, uvicorn); see ``docs/base_station.md``."""

from __future__ import annotations

import secrets
import socket
from pathlib import Path
from typing import Any

from inspect_pipe.errors import InputError
from inspect_pipe.flight.base_station.realtime import OperatorInbox, RealTimeFlight, SimPlant, feedback
from inspect_pipe.flight.scenario import Scenario, load_scenario, parse_scenario

__all__ = [
    "DEFAULT_SCENARIO",
    "OperatorInbox",
    "RealTimeFlight",
    "SimPlant",
    "build_station",
    "check_tls",
    "feedback",
    "is_loopback_host",
    "new_token",
    "require_web",
    "serve",
]

# The embedded default: the Fig. 6 hold, starting 3.5 m from the front wall.
DEFAULT_SCENARIO = {
    "format": "inspect_pipe.scenario/1",
    "name": "base_station_default",
    "duration_s": 3600,
    "seed": 1,
    "world": {"hold": {"length_m": 12, "width_m": 10, "height_m": 16}},
    "vehicle": {"start": {"position": [8.5, 0, 0], "yaw": 0}, "battery": {"start_percent": 100, "drain_percent_per_min": 2}},
}


def require_web() -> None:
    """One-line error when the web extra is missing."""
    try:
        import starlette  # noqa: F401
        import uvicorn  # noqa: F401
    except ImportError:
        raise InputError("base-station", "the web server is not installed", "pip install 'inspect-pipe[base]'") from None


def is_loopback_host(host: str) -> bool:
    return host in ("127.0.0.1", "localhost", "::1") or host.startswith("127.")


def new_token() -> str:
    return secrets.token_urlsafe(18)


def build_station(vehicle: str | None, *, host: str = "127.0.0.1", port: int = 8765, token: str | None = None,
                  command_log: Path | None = None, heartbeat_timeout_s: float = 5.0, tls: bool = False) -> Any:
    """``vehicle``: None (embedded default), ``sim:SCENARIO`` or ``mavlink:URL``."""
    from inspect_pipe.flight.base_station.app import BaseStation, StationConfig
    from inspect_pipe.flight.base_station.camera import WallCamera

    cfg = StationConfig(host=host, port=port, token=token, command_log=command_log, tls=tls)
    inbox = OperatorInbox()
    if vehicle is None or vehicle.startswith("sim:"):
        sc: Scenario = parse_scenario(DEFAULT_SCENARIO, source="<default>") if vehicle is None else load_scenario(vehicle[4:])
        plant = SimPlant(sc)
        flight = RealTimeFlight(plant, inbox, scenario=sc)
        return BaseStation(flight, inbox, cfg, camera=WallCamera(sc), vehicle_name=f"simulator ({sc.name})", live=live_feed())
    if vehicle.startswith("mavlink:"):
        from inspect_pipe.flight.mavlink_vehicle import MavlinkLink, MavlinkPlant, parse_vehicle_url

        link = MavlinkLink(parse_vehicle_url(vehicle), heartbeat_timeout_s=heartbeat_timeout_s).connect()
        plant = MavlinkPlant(link)
        flight = RealTimeFlight(plant, inbox)
        return BaseStation(flight, inbox, cfg, vehicle_name=f"{link.flavour.value if link.flavour else 'autopilot'} over {link.url}")
    raise InputError(vehicle, "unknown vehicle", "sim:SCENARIO.yaml or mavlink:URL (e.g. mavlink:udpout:127.0.0.1:14540)")


def live_feed() -> Any:
    """The panel's live mosaic: the page's camera (320 px wide) at 0.5 mosaic px per frame px, its
    pictures published once a second; 3 s without a frame in inspection mode is a stall."""
    from inspect_pipe.mosaic import LiveFeed, LiveParams

    return LiveFeed(params=LiveParams(mosaic_scale=0.5), pictures=True, stall_s=3.0, queue_frames=4)


def check_tls(certfile: Path | None, keyfile: Path | None) -> None:
    """Both or neither, and a certificate chain with its key that Python's ssl loads: else one line."""
    if (certfile is None) != (keyfile is None):
        raise InputError("--certfile/--keyfile", "only one given", "give both (PEM certificate chain and its private key) or neither")
    if certfile is None or keyfile is None:
        return
    import ssl

    for opt, path in (("--certfile", certfile), ("--keyfile", keyfile)):
        if not path.is_file():
            raise InputError(str(path), "not found" if not path.exists() else "not a file", f"give the PEM file for {opt}")
    try:
        ssl.create_default_context(ssl.Purpose.CLIENT_AUTH).load_cert_chain(str(certfile), str(keyfile))
    except (ssl.SSLError, OSError) as err:
        raise InputError(f"{certfile} + {keyfile}", f"not a PEM certificate and its key ({getattr(err, 'reason', None) or err.__class__.__name__})",
                         "e.g. openssl req -x509 -newkey rsa:2048 -nodes -keyout key.pem -out cert.pem -days 365") from None


def check_listen(host: str, port: int) -> None:
    """One-line InputError when ``host:port`` cannot be bound (an address not of this machine, a port in use):
    called before the banner and the token are printed, and again by :func:`serve`."""
    try:
        with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind((host, port))
    except (OSError, OverflowError) as err:
        why = getattr(err, "strerror", None) or str(err)
        raise InputError(f"{host}:{port}", f"cannot listen ({why})", "choose another --port or --host") from None


def serve(station: Any, *, host: str, port: int, certfile: Path | None = None, keyfile: Path | None = None) -> None:
    """Blocking; Ctrl-C stops it. With ``certfile``/``keyfile``: HTTPS and WSS (uvicorn's TLS)."""
    import uvicorn

    check_tls(certfile, keyfile)
    check_listen(host, port)
    tls = {"ssl_certfile": str(certfile), "ssl_keyfile": str(keyfile)} if certfile else {}
    # no access log: nothing a request carries ends up in a log
    uvicorn.Server(uvicorn.Config(station.app(), host=host, port=port, log_level="warning", access_log=False, ws_max_size=65536, **tls)).run()
