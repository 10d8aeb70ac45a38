"""Base station: WebSocket protocol, one controlling client, bad messages, security, command log,
page update rate, and link loss when the page goes away (hover within 0.3 s)."""

from __future__ import annotations

import asyncio
import json
import socket
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("starlette", reason="base station needs the [base] extra (starlette, uvicorn)")
pytest.importorskip("uvicorn", reason="base station needs the [base] extra (starlette, uvicorn)")
websockets = pytest.importorskip("websockets", reason="the test client needs websockets (installed with uvicorn[standard] or [base])")

import uvicorn  # noqa: E402

from inspect_pipe.flight.base_station import build_station  # noqa: E402
from inspect_pipe.flight.base_station.app import BaseStation, MessageError, StationConfig, parse_client_message  # noqa: E402


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Served:
    """A base station served by uvicorn in a thread, for one test."""

    def __init__(self, station, port: int) -> None:
        self.station, self.port = station, port
        self.server = uvicorn.Server(uvicorn.Config(station.app(), host="127.0.0.1", port=port, log_level="warning"))
        self.thread = threading.Thread(target=self.server.run, daemon=True)
        self.ticks: list[tuple[float, object, bool]] = []  # (monotonic, command, operator link ok)
        station.flight.on_tick = lambda out, snap: self.ticks.append((time.monotonic(), out.command, snap["link_ok"], snap["fsm"]))

    def __enter__(self) -> "Served":
        self.thread.start()
        t0 = time.monotonic()
        while not self.server.started:
            assert time.monotonic() - t0 < 10, "server did not start"
            time.sleep(0.02)
        return self

    def __exit__(self, *exc) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=5)

    @property
    def ws_url(self) -> str:
        return f"ws://127.0.0.1:{self.port}/ws"


@pytest.fixture
def served(tmp_path: Path):
    port = free_port()
    station = build_station(None, port=port, command_log=tmp_path / "commands.jsonl")
    with Served(station, port) as s:
        yield s


async def recv_type(ws, kind: str, timeout: float = 3.0) -> dict:
    end = time.monotonic() + timeout
    while True:
        msg = json.loads(await asyncio.wait_for(ws.recv(), timeout=max(0.01, end - time.monotonic())))
        if msg["type"] == kind:
            return msg


async def state_where(ws, pred, timeout: float) -> dict:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        msg = json.loads(await asyncio.wait_for(ws.recv(), timeout=2.0))
        if msg["type"] == "state" and pred(msg):
            return msg
    raise AssertionError("state not reached in time")


# --------------------------------------------------------------------------- message validation


@pytest.mark.parametrize(
    "text, reason",
    [
        ("not json", "not JSON"),
        ("[1, 2]", '"type"'),
        ('{"type": "fly_to_the_moon"}', "unknown message type"),
        ('{"type": "button", "button": "self_destruct"}', "unknown button"),
        ('{"type": "stick", "vx": "fast"}', "finite number"),
        ('{"type": "stick", "vx": 1e9}', "out of range"),
        ('{"type": "stick", "vx": NaN}', "finite number"),
        ('{"type": "stick", "vx": 0.1, "thrust": 1}', "unknown stick field"),
        ('{"type": "stick", "vx": true}', "finite number"),
        ("x" * 2000, "longer than"),
        (b"\x00\x01", "binary"),
    ],
)
def test_bad_messages_are_refused_with_a_reason(text, reason) -> None:
    with pytest.raises(MessageError, match=reason):
        parse_client_message(text)


def test_stick_is_clamped_to_the_page_limits() -> None:
    msg = parse_client_message('{"type": "stick", "vx": 2.5, "vy": -0.2, "vz": -2, "yaw_rate": 0, "t_ms": 5}')
    assert msg["vx"] == 1.0 and msg["vy"] == -0.2 and msg["vz"] == -0.5


def test_non_loopback_needs_a_token() -> None:
    with pytest.raises(ValueError, match="token"):
        BaseStation(None, None, StationConfig(host="0.0.0.0"))  # type: ignore[arg-type]
    st = BaseStation(None, None, StationConfig(host="0.0.0.0", token="s3cret-token-123"))  # type: ignore[arg-type]
    assert st.token_ok("s3cret-token-123") and not st.token_ok("wrong") and not st.token_ok(None)
    assert BaseStation.origin_ok({"origin": "http://127.0.0.1:8765", "host": "127.0.0.1:8765"})
    assert not BaseStation.origin_ok({"origin": "http://evil.example", "host": "127.0.0.1:8765"})


# --------------------------------------------------------------------------- served


def test_one_client_controls_others_watch_and_bad_messages_do_not_break_it(served: Served, tmp_path: Path) -> None:
    async def scenario() -> None:
        async with websockets.connect(served.ws_url) as a, websockets.connect(served.ws_url) as b:
            ha, hb = await recv_type(a, "hello"), await recv_type(b, "hello")
            assert ha["role"] == "control" and hb["role"] == "watch"
            # GIVEN a watcher WHEN it presses take-off or asks for control THEN it is refused.
            await b.send(json.dumps({"type": "button", "button": "takeoff"}))
            err = await recv_type(b, "error")
            assert "watching" in err["message"]
            await b.send(json.dumps({"type": "take_control"}))
            err = await recv_type(b, "error")
            assert "client #" in err["message"] and "in control" in err["message"]
            # Bad shapes: an error each, and the connection still serves state.
            for bad in ("{", '{"type": "stick", "vx": "x"}', '{"type": 5}', "[]"):
                await a.send(bad)
                assert (await recv_type(a, "error"))["message"].startswith("ignored")
            await a.send(b"\xff\xfe")
            assert "binary" in (await recv_type(a, "error"))["message"]
            state = await recv_type(a, "state")
            assert state["fsm"] == "landed" and state["controller"] == ha["client"]
            # WHEN the controller leaves THEN the watcher may take control.
            await a.close()
            role = await recv_type(b, "role")
            assert role["controller"] is None
            await b.send(json.dumps({"type": "take_control"}))
            assert (await recv_type(b, "role"))["role"] == "control"

    asyncio.run(scenario())
    log = [json.loads(line) for line in (tmp_path / "commands.jsonl").read_text().splitlines()]
    refused = [r for r in log if r["outcome"].startswith("refused")]
    assert {r["command"]["type"] for r in refused} == {"button", "take_control"}
    assert all("client" in r and "address" in r for r in log)
    assert any(r["command"] == {"type": "take_control"} and r["outcome"] == "ok" for r in log)


def test_closing_the_page_makes_the_vehicle_hover_within_0_3_s(served: Served) -> None:
    async def scenario() -> float:
        async with websockets.connect(served.ws_url) as ws:
            await recv_type(ws, "hello")
            stop = asyncio.Event()

            async def sticks(vx: float) -> None:
                while not stop.is_set():
                    await ws.send(json.dumps({"type": "stick", "vx": vx, "vy": 0, "vz": 0, "yaw_rate": 0, "t_ms": time.time() * 1000}))
                    await asyncio.sleep(0.05)

            task = asyncio.create_task(sticks(0.0))
            await ws.send(json.dumps({"type": "button", "button": "takeoff"}))
            await state_where(ws, lambda s: s["fsm"] == "flying", 8.0)
            stop.set()
            await task
            stop.clear()
            task = asyncio.create_task(sticks(0.3))
            await state_where(ws, lambda s: s["cmd"]["vx"] > 0.25, 3.0)
            # Page update rate while flying.
            t0, n = time.monotonic(), 0
            while time.monotonic() - t0 < 1.5:
                n += json.loads(await ws.recv())["type"] == "state"
            rate = n / (time.monotonic() - t0)
            stop.set()
            await task
            closed_at = time.monotonic()
        return closed_at, rate

    closed_at, rate = asyncio.run(scenario())
    time.sleep(0.6)
    assert rate >= 10.0, f"page update {rate:.1f} Hz"
    after = [(t, cmd, ok) for t, cmd, ok, fsm in served.ticks if t >= closed_at]
    hover = next(t for t, cmd, ok in after if not ok and cmd.vx_m_s == 0.0)
    assert hover - closed_at <= 0.3, f"hover command {hover - closed_at:.3f} s after the page closed"
    lat = sorted(served.station.flight.latencies_s)
    assert lat and lat[int(0.99 * (len(lat) - 1))] < 0.05


def test_token_protected_station_refuses_requests_without_it(tmp_path: Path) -> None:
    import urllib.error
    import urllib.request

    port = free_port()
    station = build_station(None, port=port, token="a-long-enough-token", command_log=None)
    with Served(station, port) as s:
        with pytest.raises(urllib.error.HTTPError) as err:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/")
        assert err.value.code == 401  # the login form (tests/flight/test_base_station_security.py: the exchange)
        with pytest.raises(urllib.error.HTTPError) as err:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/?token=a-long-enough-token")
        assert err.value.code == 400  # never in a URL
        bearer = {"Authorization": "Bearer a-long-enough-token"}
        assert urllib.request.urlopen(urllib.request.Request(f"http://127.0.0.1:{port}/", headers=bearer)).status == 200

        async def ws_without_token() -> None:
            async with websockets.connect(s.ws_url) as ws:
                await ws.recv()

        with pytest.raises(websockets.exceptions.WebSocketException):
            asyncio.run(ws_without_token())

        async def ws_foreign_origin() -> None:
            async with websockets.connect(s.ws_url, additional_headers=bearer, origin="http://evil.example") as ws:
                await ws.recv()

        with pytest.raises(websockets.exceptions.WebSocketException):
            asyncio.run(ws_foreign_origin())


def test_cli_refuses_an_unknown_vehicle_in_one_line() -> None:
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "cli.main", "base-station", "--vehicle", "boat:1"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "unknown vehicle" in r.stderr
