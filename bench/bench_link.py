"""Base station and vehicle link benchmark.

    python -m bench --only link

* Command latency: a stick message stamped by the client (wall clock) to the set-point leaving
  the onboard side (the simulator's attitude set-point, or the SET_POSITION_TARGET_LOCAL_NED
  datagram over MAVLink), on loopback. Goal: p99 <= 50 ms.
* Page update rate: state messages a WebSocket client receives per second. Goal: >= 10 Hz.

Both with the embedded simulator and with the simulator as a PX4 vehicle in a second process.
"""

from __future__ import annotations

import asyncio
import io
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _free(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _pct(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(round(q * (len(xs) - 1))))]


def _measure(vehicle: str | None, seconds: float) -> tuple[list[float], float, int]:
    import uvicorn
    import websockets

    from inspect_pipe.flight.base_station import build_station

    port = _free(socket.SOCK_STREAM)
    station = build_station(vehicle, port=port, command_log=None)
    server = uvicorn.Server(uvicorn.Config(station.app(), host="127.0.0.1", port=port, log_level="warning"))
    th = threading.Thread(target=server.run, daemon=True)
    th.start()
    while not server.started:
        time.sleep(0.02)

    async def client() -> tuple[float, int]:
        async with websockets.connect(f"ws://127.0.0.1:{port}/ws") as ws:
            stop = asyncio.Event()

            async def sticks() -> None:
                k = 0
                while not stop.is_set():
                    vx = 0.2 if (k // 10) % 2 else -0.2  # a key pressed and released every 0.5 s
                    await ws.send(json.dumps({"type": "stick", "vx": vx, "vy": 0, "vz": 0, "yaw_rate": 0, "t_ms": time.time() * 1000}))
                    k += 1
                    await asyncio.sleep(0.05)

            task = asyncio.create_task(sticks())
            await ws.send(json.dumps({"type": "button", "button": "takeoff"}))
            t_end = time.monotonic() + 15
            while time.monotonic() < t_end:
                m = json.loads(await ws.recv())
                if m["type"] == "state" and m.get("fsm") == "flying":
                    break
            station.flight.latencies_s.clear()
            t0, n = time.monotonic(), 0
            while time.monotonic() - t0 < seconds:
                n += json.loads(await ws.recv())["type"] == "state"
            rate = n / (time.monotonic() - t0)
            stop.set()
            await task
            return rate, len(station.flight.latencies_s)

    try:
        rate, n = asyncio.run(client())
        lat = [x * 1000 for x in station.flight.latencies_s]
    finally:
        server.should_exit = True
        th.join(timeout=5)
    return lat, rate, n


def run(data: Path) -> str:  # data: unused
    out = io.StringIO()
    w = out.write
    w("## Base station and MAVLink link\n\n")
    w("Loopback, `python -m bench --only link`. Latency: stick message stamped by the WebSocket client -> "
      "set-point leaving the onboard side. Page: state messages received per second by a client.\n\n")
    w("| vehicle | samples | latency p50 | p99 | max | page update | goals (p99 <= 50 ms, >= 10 Hz) |\n")
    w("|---|---:|---:|---:|---:|---:|---|\n")
    rows = []
    lat, rate, n = _measure(None, 10.0)
    rows.append(("embedded simulator (real time)", lat, rate))
    port = _free(socket.SOCK_DGRAM)
    with tempfile.TemporaryDirectory() as tmp:
        sc = Path(tmp) / "hover.yaml"
        sc.write_text(json.dumps({
            "format": "inspect_pipe.scenario/1", "name": "bench_link", "duration_s": 40, "seed": 1,
            "world": {"hold": {"length_m": 12, "width_m": 10, "height_m": 16}}, "vehicle": {"start": {"position": [6, 0, 0]}},
        }))
        sim = subprocess.Popen([sys.executable, "-m", "cli.main", "fly", "--scenario", str(sc), "--log", str(Path(tmp) / "sim.jsonl"),
                                "--mavlink-sim", f"udp:127.0.0.1:{port}"], cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            time.sleep(1.0)
            lat_m, rate_m, _ = _measure(f"mavlink:udpout:127.0.0.1:{port}", 10.0)
            rows.append(("simulated PX4 over MAVLink (2 processes)", lat_m, rate_m))
        finally:
            sim.terminate()
            sim.wait(timeout=10)
    for name, lat, rate in rows:
        p99 = _pct(lat, 0.99)
        ok = "met" if p99 <= 50 and rate >= 10 else "NOT met"
        w(f"| {name} | {len(lat)} | {_pct(lat, 0.5):.1f} ms | {p99:.1f} ms | {max(lat):.1f} ms | {rate:.1f} Hz | {ok} |\n")
    w("\nThe onboard side ticks at 50 Hz, so a stick waits up to 20 ms for its tick; the page is sent "
      "state at 20 Hz and camera images at 5 Hz. Two cores shared with the rest of the machine.\n")
    return out.getvalue()
