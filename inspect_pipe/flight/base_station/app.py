"""The base station: one web page (live state, camera, commands) over WebSockets (Starlette).

Security: the server binds 127.0.0.1 unless told otherwise; on any other address a token is
required. The token is exchanged once: ``POST /login`` with it (the page's form, or JSON
``{"token": ...}``) sets a session cookie (random, HttpOnly, SameSite=Strict, Secure under TLS)
that the page and its WebSocket then carry; scripts may send ``Authorization: Bearer TOKEN``
instead. The token never goes in a URL (a ``?token=`` is refused) and is never logged. ``POST
/logout`` revokes the session and closes its connections; sessions live in the server's memory,
so a cookie replayed after logout or after a restart is refused. Logins are rate-limited per
address and commands per client (token buckets; over the limit: HTTP 429 with Retry-After, or an
``error`` message with code 429 on the WebSocket). WebSocket upgrades from a page of another
origin are refused. TLS (``--certfile/--keyfile``) is served by uvicorn. One client controls at
a time (the first to connect, or the first to ask once control is free); the others watch and
their commands are refused with a message. Every command is logged (JSONL) with its client.

Messages from the page (JSON objects, at most 1 KiB):

* ``{"type": "stick", "vx", "vy", "vz", "yaw_rate", "t_ms"}`` at a steady 20 Hz (m/s, rad/s;
  ``t_ms``: the page's wall clock, for the command latency);
* ``{"type": "button", "button": "takeoff|land|go_ahead|inspection_mode_on|inspection_mode_off"}``;
* ``{"type": "take_control"}``, ``{"type": "release_control"}``.

To the page: ``hello``, ``state`` (20 Hz; with the live mosaic's status under ``mosaic``),
``image`` (5 Hz JPEG, base64), ``frame`` (captured thumbnails), ``mosaic`` (the live mosaic's
low-resolution picture, JPEG, and its coverage map, PNG, base64, when they changed, at most once
a second), ``role`` and ``error``.

The live mosaic: while inspection mode is on and the vehicle flies, a thread renders the camera at
``mosaic_hz`` (10 Hz) and hands each frame to a :class:`~inspect_pipe.mosaic.LiveFeed` (its own
thread, a bounded queue: it skips frames rather than slow anything); no frame for its
``stall_s`` while inspection mode is on (the camera turned away from the wall) is one problem line
on the panel, and what was placed stays.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import datetime as _dt
import itertools
import json
import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import IO, Any

from inspect_pipe.flight.base_station.realtime import OperatorInbox, RealTimeFlight
from inspect_pipe.flight_stack.messages import Button, SpeedCommand
from inspect_pipe.webauth import SESSION_COOKIE, TokenBucket, TokenSessions, is_loopback  # noqa: F401 (re-exported)
from inspect_pipe.webauth import login_page as login_page_html

__all__ = ["SESSION_COOKIE", "BaseStation", "StationConfig", "TokenBucket", "is_loopback", "parse_client_message"]

log = logging.getLogger(__name__)  # logins and refusals at info (-v); never a token

MAX_MESSAGE_BYTES = 1024
BUTTONS = {b.value: b for b in Button}
STICK_LIMITS = {"vx": 1.0, "vy": 1.0, "vz": 0.5, "yaw_rate": 0.8}  # what the page may ask for


@dataclass(frozen=True)
class StationConfig:
    host: str = "127.0.0.1"
    port: int = 8765
    token: str | None = None  # required when not on loopback
    state_hz: float = 20.0
    image_hz: float = 5.0
    capture_hz: float = 2.0  # frames kept while inspection mode is on
    mosaic_hz: float = 10.0  # frames rendered for the live mosaic while inspection mode is on
    mosaic_every_s: float = 1.0  # the panel's pictures are sent at most this often
    command_log: Path | None = None
    tls: bool = False  # served over TLS: the session cookie gets Secure
    # token buckets (rate per s, burst): the page's steady 20 Hz stick stream fits the first
    stick_rate: tuple[float, float] = (30.0, 40.0)
    command_rate: tuple[float, float] = (2.0, 5.0)  # buttons and control requests
    login_rate: tuple[float, float] = (0.2, 5.0)  # login attempts per client address


class MessageError(ValueError):
    pass


def parse_client_message(text: str | bytes) -> dict:
    """Validate one message from a page; raises :class:`MessageError` with a plain reason."""
    if isinstance(text, bytes):
        raise MessageError("binary messages are not accepted; send JSON text")
    if len(text) > MAX_MESSAGE_BYTES:
        raise MessageError(f"message longer than {MAX_MESSAGE_BYTES} bytes")
    try:
        msg = json.loads(text)
    except (ValueError, RecursionError):
        raise MessageError("not JSON") from None
    if not isinstance(msg, dict) or not isinstance(msg.get("type"), str):
        raise MessageError('expected an object with a "type"')
    kind = msg["type"]
    if kind == "stick":
        out: dict[str, Any] = {"type": "stick"}
        for k, lim in STICK_LIMITS.items():
            v = msg.get(k, 0.0)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise MessageError(f"stick.{k} must be a finite number")
            if abs(v) > 3.0:
                raise MessageError(f"stick.{k}={v} is out of range (|value| <= 3)")
            out[k] = max(-lim, min(lim, float(v)))
        t = msg.get("t_ms")
        out["t_ms"] = float(t) if isinstance(t, (int, float)) and not isinstance(t, bool) and math.isfinite(t) else None
        extra = set(msg) - {"type", "t_ms", "seq", *STICK_LIMITS}
        if extra:
            raise MessageError(f"unknown stick field(s): {', '.join(sorted(extra))}")
        return out
    if kind == "button":
        b = msg.get("button")
        if b not in BUTTONS:
            raise MessageError(f"unknown button {b!r}; one of {', '.join(BUTTONS)}")
        return {"type": "button", "button": b}
    if kind in ("take_control", "release_control"):
        return {"type": kind}
    raise MessageError(f"unknown message type {kind!r}")


def _pct(xs: list[float], q: float) -> float | None:
    if not xs:
        return None
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(round(q * (len(xs) - 1))))]


class _Client:
    ids = itertools.count(1)

    def __init__(self, ws: Any, session: str | None = None, rates: StationConfig = StationConfig()) -> None:
        self.id = next(self.ids)
        self.ws = ws
        self.session = session
        addr = ws.client
        self.address = f"{addr.host}:{addr.port}" if addr else "?"
        self.last_stick: tuple | None = None
        self.mosaic_version: int | None = None  # the live mosaic's pictures this client has
        self.stick_bucket = TokenBucket(*rates.stick_rate)
        self.command_bucket = TokenBucket(*rates.command_rate)

    @property
    def name(self) -> str:
        return f"client #{self.id} ({self.address})"


class BaseStation:
    """The flight (a :class:`RealTimeFlight` over a plant) behind a Starlette app."""

    def __init__(self, flight: RealTimeFlight, inbox: OperatorInbox, config: StationConfig, *,
                 camera: Any = None, vehicle_name: str = "simulator", live: Any = None) -> None:
        if not is_loopback(config.host) and not config.token:
            raise ValueError("a token is required to serve on a non-loopback address")
        self.flight = flight
        self.inbox = inbox
        self.cfg = config
        self.camera = camera
        self.live = live  # an inspect_pipe.mosaic.LiveFeed (pictures=True), or None: no panel
        self._mosaic_msg: tuple[int, str] | None = None  # (version, the "mosaic" message)
        self.vehicle_name = vehicle_name
        self.clients: dict[int, _Client] = {}
        self.controller: int | None = None
        self.frames: deque[str] = deque(maxlen=12)
        self.frames_captured = 0
        self.refused = 0
        self._log: IO[str] | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.command_count = 0
        self.rate_limited = 0
        # the token, sessions and login/logout handlers (inspect_pipe.webauth, shared with the review page)
        self.auth = TokenSessions(config.token, tls=config.tls, login_rate=config.login_rate,
                                  on_event=self._log_event, on_rate_limited=self._count_rate_limited)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        if self.cfg.command_log is not None:
            self.cfg.command_log.parent.mkdir(parents=True, exist_ok=True)
            self._log = self.cfg.command_log.open("a", buffering=1)
        self._thread = threading.Thread(target=self.flight.run, args=(self._stop,), daemon=True, name="flight")
        self._thread.start()
        self._camera_thread = None
        if self.live is not None and self.camera is not None:
            self._camera_thread = threading.Thread(target=self._feed_mosaic, daemon=True, name="mosaic-camera")
            self._camera_thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if getattr(self, "_camera_thread", None) is not None:
            self._camera_thread.join(timeout=2.0)
        if self.live is not None:
            self.live.close(timeout_s=2.0)
        close = getattr(self.flight.plant, "close", None)
        if close is not None:
            close()
        if self._log is not None:
            self._log.close()
            self._log = None

    def _log_event(self, address: str, what: str, outcome: str) -> None:
        log.info("%s from %s: %s", what, address, outcome)
        if self._log is not None:
            rec = {"t": _dt.datetime.now().isoformat(timespec="milliseconds"), "client": None, "address": address,
                   "command": {"type": what}, "outcome": outcome}
            self._log.write(json.dumps(rec) + "\n")

    def log_command(self, client: _Client, command: dict, outcome: str = "ok") -> None:
        self.command_count += 1
        if self._log is not None:
            rec = {"t": _dt.datetime.now().isoformat(timespec="milliseconds"), "client": client.id,
                   "address": client.address, "command": command, "outcome": outcome}
            self._log.write(json.dumps(rec) + "\n")

    # ------------------------------------------------------------------ security
    def _count_rate_limited(self) -> None:
        self.rate_limited += 1

    @property
    def sessions(self) -> dict[str, float]:
        return self.auth.sessions

    def token_ok(self, given: str | None) -> bool:
        return self.auth.token_ok(given)

    origin_ok = staticmethod(TokenSessions.origin_ok)

    def session_of(self, conn: Any) -> str | None:
        return self.auth.session_of(conn)

    def authorized(self, conn: Any) -> bool:
        return self.auth.authorized(conn)

    # ------------------------------------------------------------------ the app
    def app(self) -> Any:
        from starlette.applications import Starlette
        from starlette.responses import HTMLResponse, Response
        from starlette.routing import Route, WebSocketRoute
        from starlette.websockets import WebSocket, WebSocketDisconnect

        static = resources.files("inspect_pipe.flight.base_station") / "static"
        page = (static / "index.html").read_text()
        script = (static / "app.js").read_text()

        login_page = login_page_html("base station", "Surveyor base station")
        url_token = self.auth.url_token_response()

        async def index(request: Any) -> Response:
            if "token" in request.query_params:
                return url_token
            if not self.authorized(request):
                return HTMLResponse(login_page, 401, headers={"Cache-Control": "no-store"})
            return HTMLResponse(page, headers={"Cache-Control": "no-store"})

        async def app_js(request: Any) -> Response:
            return Response(script, media_type="application/javascript")

        async def login(request: Any) -> Response:
            return await self.auth.login(request, login_page)

        async def close_session(sid: str) -> None:
            for c in [c for c in self.clients.values() if c.session == sid]:
                with contextlib.suppress(Exception):
                    await c.ws.close(code=1008)

        async def logout(request: Any) -> Response:
            return await self.auth.logout(request, close_session)

        async def ws_endpoint(ws: WebSocket) -> None:
            if "token" in ws.query_params or not self.authorized(ws) or not self.auth.origin_ok(ws.headers):
                await ws.close(code=1008)  # policy violation: log in first (the page reloads to its login form)
                return
            await ws.accept()
            client = _Client(ws, self.session_of(ws), self.cfg)
            self.clients[client.id] = client
            if self.controller is None:
                self.controller = client.id
            self.log_command(client, {"type": "connect"}, self._role(client))
            await ws.send_text(json.dumps({
                "type": "hello", "client": client.id, "role": self._role(client), "vehicle": self.vehicle_name,
                "limits": STICK_LIMITS, "stick_hz": 20, "mosaic": self.live is not None,
            }))
            try:
                while True:
                    raw = await ws.receive()
                    if raw["type"] == "websocket.disconnect":
                        break
                    await self._on_message(client, raw.get("text") if raw.get("text") is not None else raw.get("bytes"))
            except WebSocketDisconnect:
                pass
            finally:
                self.clients.pop(client.id, None)
                self.log_command(client, {"type": "disconnect"})
                if self.controller == client.id:
                    # No more sticks: onboard, waiting_for_connectivity hovers after 0.25 s.
                    self.controller = None
                    await self._broadcast_roles()

        @contextlib.asynccontextmanager
        async def lifespan(app: Any):
            self.start()
            task = asyncio.create_task(self._broadcaster())
            try:
                yield
            finally:
                task.cancel()
                self.stop()

        return Starlette(routes=[Route("/", index), Route("/app.js", app_js), Route("/login", login, methods=["POST"]),
                                 Route("/logout", logout, methods=["POST"]), WebSocketRoute("/ws", ws_endpoint)], lifespan=lifespan)

    def _role(self, client: _Client) -> str:
        return "control" if self.controller == client.id else "watch"

    async def _send(self, client: _Client, msg: dict) -> None:
        try:
            await client.ws.send_text(json.dumps(msg))
        except Exception:  # a client gone mid-send: its handler cleans up
            pass

    async def _broadcast_roles(self) -> None:
        for c in list(self.clients.values()):
            await self._send(c, {"type": "role", "role": self._role(c), "controller": self.controller})

    async def _on_message(self, client: _Client, text: Any) -> None:
        try:
            msg = parse_client_message(text if text is not None else b"")
        except MessageError as err:
            self.refused += 1
            await self._send(client, {"type": "error", "message": f"ignored: {err}"})
            return
        kind = msg["type"]
        wait = (client.stick_bucket if kind == "stick" else client.command_bucket).take()
        if wait > 0:
            self.refused += 1
            self.rate_limited += 1
            rate, burst = self.cfg.stick_rate if kind == "stick" else self.cfg.command_rate
            if kind != "stick":
                self.log_command(client, msg, "refused: rate limited")
            await self._send(client, {"type": "error", "code": 429, "message":
                                      f"rate limited (429): at most {rate:g} {'stick messages' if kind == 'stick' else 'commands'} "
                                      f"per second, {burst:g} at once; this {kind} was ignored, retry in {wait:.1f} s"})
            return
        if kind == "take_control":
            if self.controller is None or self.controller == client.id:
                self.controller = client.id
                self.log_command(client, msg)
                await self._broadcast_roles()
            else:
                holder = self.clients.get(self.controller)
                self.log_command(client, msg, "refused")
                await self._send(client, {"type": "error", "message":
                                          f"refused: {holder.name if holder else 'another client'} is in control; "
                                          "it must release control or close its page"})
            return
        if kind == "release_control":
            if self.controller == client.id:
                self.controller = None
                self.log_command(client, msg)
                await self._broadcast_roles()
            return
        if self.controller != client.id:
            self.refused += 1
            if kind == "button":
                self.log_command(client, msg, "refused: watching")
            await self._send(client, {"type": "error", "message": "refused: you are watching; take control first"})
            return
        if kind == "stick":
            stick = SpeedCommand(msg["vx"], msg["vy"], msg["vz"], msg["yaw_rate"])
            t_ms = msg["t_ms"]
            wall = t_ms / 1000.0 if t_ms is not None and abs(t_ms / 1000.0 - time.time()) < 10.0 else None
            self.inbox.put_stick(stick, wall)
            key = (stick.vx_m_s, stick.vy_m_s, stick.vz_m_s, stick.yaw_rate_rad_s)
            if key != client.last_stick:  # the steady stream is not logged, its changes are
                client.last_stick = key
                self.log_command(client, {"type": "stick", "vx": key[0], "vy": key[1], "vz": key[2], "yaw_rate": key[3]})
        else:
            self.inbox.press(BUTTONS[msg["button"]])
            self.log_command(client, msg)

    # ------------------------------------------------------------------ the live mosaic
    def _feed_mosaic(self) -> None:
        """The camera at ``mosaic_hz`` while inspection mode is on and the vehicle flies, into the
        live mosaic (never waits for it). Frames are not expected otherwise."""
        period = 1.0 / self.cfg.mosaic_hz
        next_t = time.monotonic()
        while not self._stop.is_set():
            next_t += period
            snap = self.flight.snapshot()
            on = bool(snap.get("inspection_mode")) and snap.get("fsm") == "flying"
            self.live.expect(on)
            if on:
                pose = getattr(self.flight.plant, "pose", None)
                img = self.camera.render(*pose()) if pose is not None else None
                if img is not None:  # None: the camera does not face the wall (a stall, if it lasts)
                    self.live.submit(img)  # no t_s: the pauses outside inspection mode are not stalls
            late = time.monotonic() - next_t
            if late > period:
                next_t = time.monotonic()  # re-anchor rather than burst
            self._stop.wait(max(0.0, next_t - time.monotonic()))

    def mosaic_message(self) -> tuple[int, str] | None:
        """The panel's pictures as a ``mosaic`` message (encoded once per new version)."""
        import cv2

        pics = self.live.pictures() if self.live is not None else None
        if pics is None:
            return None
        version, mosaic, cover = pics
        if self._mosaic_msg is None or self._mosaic_msg[0] != version:
            ok1, jpg = cv2.imencode(".jpg", mosaic, [cv2.IMWRITE_JPEG_QUALITY, 75])
            ok2, png = cv2.imencode(".png", cover)
            if not (ok1 and ok2):
                return self._mosaic_msg
            self._mosaic_msg = (version, json.dumps({
                "type": "mosaic", "version": version, "size": [int(mosaic.shape[1]), int(mosaic.shape[0])],
                "mosaic_jpeg": base64.b64encode(jpg.tobytes()).decode(), "coverage_png": base64.b64encode(png.tobytes()).decode()}))
        return self._mosaic_msg

    # ------------------------------------------------------------------ outgoing
    def status(self) -> dict:
        lat = [x * 1000 for x in list(self.flight.latencies_s)[-1000:]]
        snap = dict(self.flight.snapshot())
        snap.update({
            "type": "state", "controller": self.controller, "clients": len(self.clients),
            "frames_captured": self.frames_captured,
            "latency_ms": {"p50": _r1(_pct(lat, 0.5)), "p99": _r1(_pct(lat, 0.99)), "n": len(lat)},
            "mosaic": self.live.status().to_json() if self.live is not None else None,
        })
        return snap

    async def _broadcaster(self) -> None:
        period = 1.0 / self.cfg.state_hz
        image_every = max(1, round(self.cfg.state_hz / self.cfg.image_hz))
        capture_every = max(1, round(self.cfg.state_hz / self.cfg.capture_hz))
        mosaic_every = max(1, round(self.cfg.state_hz * self.cfg.mosaic_every_s))
        loop = asyncio.get_running_loop()
        next_t = loop.time()
        k = 0
        while True:
            next_t += period
            k += 1
            frame_msg = None
            if self.clients:
                status = self.status()
                text = json.dumps(status)
                image = None
                if self.camera is not None and k % image_every == 0:
                    image = self._render()
                    if image is not None and status.get("inspection_mode") and status.get("fsm") == "flying" and k % capture_every == 0:
                        self.frames_captured += 1
                        self.frames.append(image)
                        frame_msg = json.dumps({"type": "frame", "index": self.frames_captured, "jpeg": image})
                mosaic = self.mosaic_message() if k % mosaic_every == 0 else None
                for c in list(self.clients.values()):
                    if mosaic is not None and c.mosaic_version != mosaic[0]:  # new pictures, or a client that has none yet
                        c.mosaic_version = mosaic[0]
                        await self._send_raw(c, mosaic[1])
                    await self._send_raw(c, text)
                    if image is not None:
                        await self._send_raw(c, json.dumps({"type": "image", "jpeg": image}))
                        if frame_msg is not None:
                            await self._send_raw(c, frame_msg)
            await asyncio.sleep(max(0.0, next_t - loop.time()))

    async def _send_raw(self, client: _Client, text: str) -> None:
        try:
            await client.ws.send_text(text)
        except Exception:
            pass

    def _render(self) -> str | None:
        import cv2

        pose = getattr(self.flight.plant, "pose", None)
        if pose is None:
            return None
        pos, yaw = pose()
        img = self.camera.render(pos, yaw)
        if img is None:
            return None
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 70])
        return base64.b64encode(buf.tobytes()).decode() if ok else None


def _r1(v: float | None) -> float | None:
    return None if v is None else round(v, 1)
