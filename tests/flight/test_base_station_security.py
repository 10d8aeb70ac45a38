"""Base station security: the token exchanged once for a session cookie (or a Bearer header), never
in a URL or a log; a wrong token, a replayed cookie (after logout, after a restart), a token in
the URL; rate limits (HTTP 429, WebSocket error 429); TLS with a self-signed certificate."""

from __future__ import annotations

import asyncio
import http.client
import json
import shutil
import ssl
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("starlette", reason="base station needs the [base] extra (starlette, uvicorn)")
pytest.importorskip("uvicorn", reason="base station needs the [base] extra (starlette, uvicorn)")
websockets = pytest.importorskip("websockets", reason="the test client needs websockets ([base] extra)")

import uvicorn  # noqa: E402

from inspect_pipe.flight.base_station import build_station  # noqa: E402
from inspect_pipe.flight.base_station.app import SESSION_COOKIE, TokenBucket  # noqa: E402

TOKEN = "the-right-token-1234"


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    def __init__(self, station, port: int, certfile=None, keyfile=None) -> None:
        tls = {"ssl_certfile": str(certfile), "ssl_keyfile": str(keyfile)} if certfile else {}
        self.port, self.tls = port, bool(certfile)
        self.server = uvicorn.Server(uvicorn.Config(station.app(), host="127.0.0.1", port=port, log_level="warning", access_log=False, **tls))
        self.thread = threading.Thread(target=self.server.run, daemon=True)

    def __enter__(self) -> "Server":
        self.thread.start()
        t0 = time.monotonic()
        while not self.server.started:
            assert time.monotonic() - t0 < 10, "server did not start"
            time.sleep(0.02)
        return self

    def __exit__(self, *exc) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=5)


def request(port, method, path, body=None, headers=None, context=None):
    conn = (http.client.HTTPSConnection("127.0.0.1", port, context=context, timeout=5) if context
            else http.client.HTTPConnection("127.0.0.1", port, timeout=5))
    conn.request(method, path, body=body, headers=headers or {})
    r = conn.getresponse()
    out = (r.status, {k.lower(): v for k, v in r.getheaders()}, r.read().decode("utf-8", "replace"), r.headers.get_all("set-cookie") or [])
    conn.close()
    return out


def login(port, token=TOKEN, context=None, address_headers=None):
    return request(port, "POST", "/login", json.dumps({"token": token}), {"Content-Type": "application/json", **(address_headers or {})}, context)


def session_cookie(set_cookies: list[str]) -> str:
    for c in set_cookies:
        if c.startswith(SESSION_COOKIE + "="):
            return c.split(";", 1)[0]
    raise AssertionError(f"no session cookie in {set_cookies}")


async def ws_hello(url: str, headers: dict | None = None, ssl_ctx=None) -> dict:
    async with websockets.connect(url, additional_headers=headers or {}, ssl=ssl_ctx, open_timeout=5) as ws:
        while True:
            msg = json.loads(await asyncio.wait_for(ws.recv(), 5))
            if msg["type"] == "hello":
                return msg


def ws_refused(url: str, headers: dict | None = None) -> bool:
    try:
        asyncio.run(ws_hello(url, headers))
    except (websockets.exceptions.WebSocketException, OSError):
        return True
    return False


@pytest.fixture
def station(tmp_path):
    port = free_port()
    st = build_station(None, host="127.0.0.1", port=port, token=TOKEN, command_log=tmp_path / "commands.jsonl")
    with Server(st, port):
        yield st, port, tmp_path / "commands.jsonl"


def test_the_token_is_exchanged_once_for_an_httponly_strict_session_cookie(station):
    st, port, log = station
    status, _, body, _ = request(port, "GET", "/")
    assert status == 401 and 'action="/login"' in body and "app.js" not in body  # the login form, not the station
    status, _, _, cookies = login(port)
    assert status == 200
    raw = next(c for c in cookies if c.startswith(SESSION_COOKIE + "="))
    attrs = {a.strip().lower() for a in raw.split(";")[1:]}
    assert "httponly" in attrs and "samesite=strict" in attrs and "path=/" in attrs and "secure" not in attrs
    cookie = session_cookie(cookies)
    assert TOKEN not in cookie and len(cookie.split("=", 1)[1]) >= 40  # a random session id, not the token
    status, _, body, _ = request(port, "GET", "/", headers={"Cookie": cookie})
    assert status == 200 and "app.js" in body
    hello = asyncio.run(ws_hello(f"ws://127.0.0.1:{port}/ws", {"Cookie": cookie}))
    assert hello["role"] == "control"


def test_a_browser_form_login_redirects_with_the_cookie(station):
    _, port, _ = station
    status, headers, _, cookies = request(port, "POST", "/login", f"token={TOKEN}",
                                          {"Content-Type": "application/x-www-form-urlencoded", "Accept": "text/html"})
    assert status == 303 and headers["location"] == "/" and session_cookie(cookies)
    status, _, body, cookies = request(port, "POST", "/login", "token=nope-nope-nope",
                                       {"Content-Type": "application/x-www-form-urlencoded", "Accept": "text/html"})
    assert status == 403 and "wrong token" in body and not cookies


def test_a_wrong_token_gets_nothing(station):
    _, port, _ = station
    status, _, body, cookies = login(port, "the-wrong-token-1234")
    assert status == 403 and body == "wrong token" and not cookies
    status, _, _, cookies = login(port, "")
    assert status == 403 and not cookies
    assert request(port, "GET", "/", headers={"Authorization": "Bearer the-wrong-token-1234"})[0] == 401
    assert request(port, "GET", "/", headers={"Cookie": f"{SESSION_COOKIE}=made-up-session-id"})[0] == 401
    assert ws_refused(f"ws://127.0.0.1:{port}/ws")
    assert ws_refused(f"ws://127.0.0.1:{port}/ws", {"Cookie": f"{SESSION_COOKIE}=made-up-session-id"})


def test_the_token_never_goes_in_a_url(station):
    _, port, _ = station
    status, _, body, _ = request(port, "GET", f"/?token={TOKEN}")
    assert status == 400 and "never goes in a URL" in body
    assert request(port, "POST", f"/login?token={TOKEN}", b"", {"Content-Type": "application/json"})[0] == 400
    assert ws_refused(f"ws://127.0.0.1:{port}/ws?token={TOKEN}")
    from importlib import resources

    js = (resources.files("inspect_pipe.flight.base_station") / "static" / "app.js").read_text()
    assert "token" not in js.replace("No token here", "")  # the page never puts it anywhere


def test_scripts_may_send_a_bearer_header(station):
    _, port, _ = station
    assert request(port, "GET", "/", headers={"Authorization": f"Bearer {TOKEN}"})[0] == 200
    assert asyncio.run(ws_hello(f"ws://127.0.0.1:{port}/ws", {"Authorization": f"Bearer {TOKEN}"}))["type"] == "hello"


def test_a_cookie_replayed_after_logout_is_refused_and_its_connection_closed(station):
    _, port, _ = station
    cookie = session_cookie(login(port)[3])

    async def logout_while_connected() -> int | None:
        async with websockets.connect(f"ws://127.0.0.1:{port}/ws", additional_headers={"Cookie": cookie}, open_timeout=5) as ws:
            await ws.recv()
            status, _, _, set_cookies = await asyncio.to_thread(request, port, "POST", "/logout", b"", {"Cookie": cookie})
            assert status == 200 and any(c.startswith(SESSION_COOKIE + '=""') or "max-age=0" in c.lower() for c in set_cookies)
            with pytest.raises(websockets.exceptions.ConnectionClosed) as closed:
                while True:
                    await asyncio.wait_for(ws.recv(), 5)
            return closed.value.rcvd.code if closed.value.rcvd else None

    assert asyncio.run(logout_while_connected()) == 1008
    assert request(port, "GET", "/", headers={"Cookie": cookie})[0] == 401  # the replayed cookie
    assert ws_refused(f"ws://127.0.0.1:{port}/ws", {"Cookie": cookie})


def test_a_cookie_from_before_a_restart_is_refused(tmp_path):
    port = free_port()
    with Server(build_station(None, port=port, token=TOKEN, command_log=None), port):
        cookie = session_cookie(login(port)[3])
        assert request(port, "GET", "/", headers={"Cookie": cookie})[0] == 200
    port2 = free_port()
    with Server(build_station(None, port=port2, token=TOKEN, command_log=None), port2):  # restarted, same token
        assert request(port2, "GET", "/", headers={"Cookie": cookie})[0] == 401
        assert ws_refused(f"ws://127.0.0.1:{port2}/ws", {"Cookie": cookie})
        assert login(port2)[0] == 200  # the token itself still logs in


def test_logins_are_rate_limited_with_a_clear_429(station):
    _, port, _ = station
    codes = [login(port, f"guess-{k:04d}-abcdefgh")[0] for k in range(5)]
    assert codes == [403] * 5
    status, headers, body, _ = login(port)  # even the right token: the address is throttled
    assert status == 429 and int(headers["retry-after"]) >= 1 and "too many login attempts" in body


def test_commands_are_rate_limited_but_the_20_hz_stick_stream_is_not(station):
    _, port, _ = station
    cookie = session_cookie(login(port)[3])

    async def run() -> tuple[int, int, list[dict]]:
        async with websockets.connect(f"ws://127.0.0.1:{port}/ws", additional_headers={"Cookie": cookie}, open_timeout=5) as ws:
            errors: list[dict] = []

            async def reader():
                async for raw in ws:
                    m = json.loads(raw)
                    if m["type"] == "error":
                        errors.append(m)

            task = asyncio.create_task(reader())
            for _ in range(60):  # 3 s of sticks at 20 Hz: never limited
                await ws.send(json.dumps({"type": "stick", "vx": 0.0, "vy": 0.0, "vz": 0.0, "yaw_rate": 0.0}))
                await asyncio.sleep(0.05)
            stick_errors = len(errors)
            for _ in range(12):  # 12 buttons at once: 5 pass (the burst), the rest are refused with 429
                await ws.send(json.dumps({"type": "button", "button": "go_ahead"}))
            await asyncio.sleep(0.5)
            task.cancel()
            return stick_errors, len(errors), errors

    stick_errors, n, errors = asyncio.run(run())
    assert stick_errors == 0
    limited = [e for e in errors if e.get("code") == 429]
    assert 6 <= len(limited) <= 7 and "rate limited (429)" in limited[0]["message"] and "retry in" in limited[0]["message"]


def test_the_token_is_never_logged(station):
    st, port, log = station
    login(port, "the-wrong-token-1234")
    cookie = session_cookie(login(port)[3])
    request(port, "GET", f"/?token={TOKEN}")
    asyncio.run(ws_hello(f"ws://127.0.0.1:{port}/ws", {"Cookie": cookie}))
    time.sleep(0.2)
    text = log.read_text()
    assert '"login"' in text and "refused: wrong token" in text
    assert TOKEN not in text and "the-wrong-token-1234" not in text and cookie.split("=", 1)[1] not in text


def test_token_bucket():
    t = [0.0]
    b = TokenBucket(2.0, 3.0, clock=lambda: t[0])
    assert [b.take() for _ in range(3)] == [0.0, 0.0, 0.0]
    assert b.take() == pytest.approx(0.5)
    t[0] = 0.5
    assert b.take() == 0.0 and b.take() == pytest.approx(0.5)
    t[0] = 100.0
    assert [b.take() for _ in range(4)][:3] == [0.0, 0.0, 0.0]  # refilled to the burst, not beyond


@pytest.fixture
def self_signed(tmp_path):
    if shutil.which("openssl") is None:
        pytest.skip("openssl CLI not installed (needed to make a test certificate)")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key), "-out", str(cert), "-days", "1",
                    "-subj", "/CN=127.0.0.1", "-addext", "subjectAltName=IP:127.0.0.1"], check=True, capture_output=True, timeout=60)
    return cert, key


def test_tls_serves_https_and_wss_with_a_secure_cookie(self_signed):
    cert, key = self_signed
    port = free_port()
    ctx = ssl.create_default_context(cafile=str(cert))
    with Server(build_station(None, port=port, token=TOKEN, command_log=None, tls=True), port, cert, key):
        status, _, _, cookies = login(port, context=ctx)
        assert status == 200
        raw = next(c for c in cookies if c.startswith(SESSION_COOKIE + "="))
        assert "secure" in {a.strip().lower() for a in raw.split(";")[1:]}
        cookie = session_cookie(cookies)
        assert request(port, "GET", "/", headers={"Cookie": cookie}, context=ctx)[0] == 200
        assert asyncio.run(ws_hello(f"wss://127.0.0.1:{port}/ws", {"Cookie": cookie}, ssl_ctx=ctx))["type"] == "hello"
        with pytest.raises((http.client.HTTPException, OSError)):  # plain HTTP gets no page from the TLS port
            request(port, "GET", "/")
        with pytest.raises(ssl.SSLCertVerificationError):  # a client that does not trust the certificate
            request(port, "GET", "/", context=ssl.create_default_context())


@pytest.mark.parametrize("args, says", [
    (["--certfile", "{cert}"], "only one given"),
    (["--certfile", "{tmp}/missing.pem", "--keyfile", "{key}"], "missing.pem: not found"),
    (["--certfile", "{key}", "--keyfile", "{key}"], "not a PEM certificate and its key"),
])
def test_cli_tls_options_bad_input_is_one_line(self_signed, tmp_path, args, says):
    cert, key = self_signed
    args = [a.format(cert=cert, key=key, tmp=tmp_path) for a in args]
    r = subprocess.run([sys.executable, "-m", "cli.main", "base-station", "--port", str(free_port()), *args],
                       capture_output=True, text=True, timeout=60, cwd=Path(__file__).resolve().parents[2])
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and says in r.stderr, r.stderr
