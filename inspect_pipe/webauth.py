"""Token login for the project's local web pages (the base station, the register review).

The server binds 127.0.0.1 unless told otherwise; on any other address a token is required. The
token is exchanged once: ``POST /login`` with it (the page's form, or JSON ``{"token": ...}``)
sets a session cookie (random, HttpOnly, SameSite=Strict, Secure under TLS); scripts may send
``Authorization: Bearer TOKEN`` instead. The token never goes in a URL (a ``?token=`` is
refused) and is never logged. ``POST /logout`` revokes the session; sessions live in the
server's memory, so a cookie replayed after logout or a restart is refused. Logins are
rate-limited per address (HTTP 429 with Retry-After).
"""

from __future__ import annotations

import hmac
import json
import math
import secrets
import time
from typing import Any, Awaitable, Callable
from urllib.parse import parse_qs

__all__ = ["SESSION_COOKIE", "TokenBucket", "TokenSessions", "is_loopback"]

SESSION_COOKIE = "ip_session"
SESSION_TTL_S = 12 * 3600.0
MAX_SESSIONS = 64
URL_TOKEN = "the token never goes in a URL: enter it on the page (POST /login), or send 'Authorization: Bearer TOKEN'"


class TokenBucket:
    """``burst`` tokens, refilled at ``rate_per_s``; ``take()`` spends one and returns 0, or
    returns the seconds until one is there (and spends nothing)."""

    def __init__(self, rate_per_s: float, burst: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.rate, self.burst, self.clock = rate_per_s, burst, clock
        self.tokens = float(burst)
        self.t = clock()

    def take(self) -> float:
        now = self.clock()
        self.tokens = min(self.burst, self.tokens + (now - self.t) * self.rate)
        self.t = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return 0.0
        return (1.0 - self.tokens) / self.rate


def login_page(app: str, heading: str) -> str:
    """The login form every page server shows (``inspect_pipe/login.html``): the token is posted
    once to /login and exchanged for a session cookie. ``<!--error-->`` marks where a refusal goes."""
    from importlib import resources
    from string import Template

    return Template((resources.files("inspect_pipe") / "login.html").read_text()).substitute(app=app, heading=heading)


def is_loopback(host: str) -> bool:
    return host in ("127.0.0.1", "localhost", "::1") or host.startswith("127.")


class TokenSessions:
    """The token, the live sessions and the login/logout handlers of one server.

    ``on_event(address, what, outcome)`` is told of logins and logouts (never the token);
    ``on_rate_limited()`` of a refused login."""

    def __init__(self, token: str | None, *, tls: bool = False, login_rate: tuple[float, float] = (0.2, 5.0),
                 on_event: Callable[[str, str, str], None] | None = None,
                 on_rate_limited: Callable[[], None] | None = None) -> None:
        self.token = token
        self.tls = tls
        self.login_rate = login_rate
        self.on_event = on_event or (lambda address, what, outcome: None)
        self.on_rate_limited = on_rate_limited or (lambda: None)
        self.sessions: dict[str, float] = {}  # session id -> issued (monotonic); in memory only
        self.login_buckets: dict[str, TokenBucket] = {}

    def token_ok(self, given: str | None) -> bool:
        if self.token is None:
            return True
        return given is not None and hmac.compare_digest(given.encode(), self.token.encode())

    def new_session(self) -> str:
        now = time.monotonic()
        for sid, t in list(self.sessions.items()):
            if now - t > SESSION_TTL_S:
                del self.sessions[sid]
        while len(self.sessions) >= MAX_SESSIONS:
            del self.sessions[min(self.sessions, key=self.sessions.get)]
        sid = secrets.token_urlsafe(32)
        self.sessions[sid] = now
        return sid

    def session_of(self, conn: Any) -> str | None:
        """The live session id in ``conn``'s cookie, if any."""
        sid = conn.cookies.get(SESSION_COOKIE)
        if sid and sid in self.sessions and time.monotonic() - self.sessions[sid] <= SESSION_TTL_S:
            return sid
        return None

    def authorized(self, conn: Any) -> bool:
        """No token configured (loopback), a live session cookie, or ``Authorization: Bearer TOKEN``."""
        if self.token is None:
            return True
        if self.session_of(conn) is not None:
            return True
        scheme, _, given = conn.headers.get("authorization", "").partition(" ")
        return scheme.lower() == "bearer" and self.token_ok(given.strip())

    def login_wait(self, address: str) -> float:
        bucket = self.login_buckets.setdefault(address, TokenBucket(*self.login_rate))
        return bucket.take()

    @staticmethod
    def origin_ok(headers: Any) -> bool:
        """No Origin (not a browser: scripts, tests) or the page's own origin."""
        origin = headers.get("origin")
        if origin is None:
            return True
        host = headers.get("host", "")
        return origin.split("://", 1)[-1] == host

    @staticmethod
    def url_token_response() -> Any:
        from starlette.responses import PlainTextResponse

        return PlainTextResponse(URL_TOKEN, 400)

    def cookie(self, response: Any, sid: str | None) -> Any:
        if sid is None:
            response.delete_cookie(SESSION_COOKIE, path="/", secure=self.tls, httponly=True, samesite="strict")
        else:
            response.set_cookie(SESSION_COOKIE, sid, path="/", secure=self.tls, httponly=True, samesite="strict")
        return response

    async def login(self, request: Any, login_page: str) -> Any:
        """``POST /login``: form, JSON or bearer; a browser is sent back to ``/`` with its cookie."""
        from starlette.responses import HTMLResponse, JSONResponse, PlainTextResponse, RedirectResponse

        if "token" in request.query_params:
            return self.url_token_response()
        addr = request.client.host if request.client else "?"
        wait = self.login_wait(addr)
        if wait > 0:
            self.on_rate_limited()
            return PlainTextResponse(f"too many login attempts from {addr}: retry in {wait:.0f} s", 429,
                                     headers={"Retry-After": str(max(1, math.ceil(wait)))})
        body = (await request.body())[:4096]
        ctype = request.headers.get("content-type", "")
        given = None
        if ctype.startswith("application/json"):
            try:
                doc = json.loads(body)
                given = doc.get("token") if isinstance(doc, dict) and isinstance(doc.get("token"), str) else None
            except ValueError:
                given = None
        elif ctype.startswith("application/x-www-form-urlencoded"):
            given = (parse_qs(body.decode("utf-8", "replace")).get("token") or [None])[0]
        if given is None:
            scheme, _, value = request.headers.get("authorization", "").partition(" ")
            given = value.strip() if scheme.lower() == "bearer" else None
        browser = "text/html" in request.headers.get("accept", "")
        if self.token is None or not self.token_ok(given):
            self.on_event(addr, "login", "refused: wrong token")  # the attempt, never what was typed
            if browser:
                return HTMLResponse(login_page.replace("<!--error-->", "wrong token"), 403)
            return PlainTextResponse("wrong token", 403)
        sid = self.new_session()
        self.on_event(addr, "login", "ok")
        return self.cookie(RedirectResponse("/", 303) if browser else JSONResponse({"ok": True}), sid)

    async def logout(self, request: Any, on_revoke: Callable[[str], Awaitable[None]] | None = None) -> Any:
        """``POST /logout``: revoke the session (``on_revoke(sid)`` closes what it holds) and the cookie."""
        from starlette.responses import JSONResponse, RedirectResponse

        sid = self.session_of(request)
        if sid is not None:
            del self.sessions[sid]
            if on_revoke is not None:
                await on_revoke(sid)
        self.on_event(request.client.host if request.client else "?", "logout", "ok" if sid else "no session")
        browser = "text/html" in request.headers.get("accept", "")
        return self.cookie(RedirectResponse("/", 303) if browser else JSONResponse({"ok": True}), None)
