"""The review server: a Starlette app over a :class:`~inspect_pipe.report._review.Review`.

Routes (every one but ``/login`` needs the session when a token is set, as the base station):

* ``GET /``: the page (or the login form); ``GET /review.js``;
* ``GET /api/register``: the entries, the reviewer, the audit count and the last render;
* ``POST /api/edit`` ``{"id", "field": "status|class|note", "value"}``: one edit, logged and
  saved before the answer; ``{"ok": true, "entry", "record"}``, or 4xx ``{"error": "one line"}``
  (400 malformed, 404 no such entry, 413 too long, 415 not JSON) with nothing written;
* ``POST /api/render``: re-render the report now (it re-renders by itself ``render_after_s``
  after the last edit, and when the server stops);
* ``GET /assets/...``: the report's crops and overlay.
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from inspect_pipe.errors import InputError
from inspect_pipe.report._review import Review, ReviewError, utc_now
from inspect_pipe.webauth import TokenSessions, is_loopback
from inspect_pipe.webauth import login_page as login_page_html

log = logging.getLogger(__name__)

MAX_BODY = 4096


@dataclass(frozen=True)
class ReviewConfig:
    host: str = "127.0.0.1"
    port: int = 8766
    token: str | None = None  # required when not on loopback
    tls: bool = False
    render_after_s: float | None = 10.0  # re-render this long after the last edit (a render holds edits back for its seconds); None: only when asked (and at stop)
    login_rate: tuple[float, float] = (0.2, 5.0)


def render_config(store) -> Any:
    """The run's report options as recorded in run.json (``steps.report.options``), as a RunConfig."""
    from inspect_pipe.pipeline._steps import RunConfig

    opts = ((store.load_run().get("steps") or {}).get("report") or {}).get("options") or {}
    return RunConfig(report=dict(opts.get("report") or {}), report_out=opts.get("report_out"), survey_plan=opts.get("survey_plan"))


def open_review(run_dir: Path, reviewer: str | None) -> tuple[Review, Any, Any]:
    """(review, store, run config) of a run directory; one-line InputError when it has no register."""
    from inspect_pipe.pipeline import RunStore
    from inspect_pipe.pipeline._steps import report_out

    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise InputError(str(run_dir), "not found" if not run_dir.exists() else "not a directory", "give a run directory written by inspect-pipe run")
    store = RunStore(run_dir)
    cfg = render_config(store)
    rdir = report_out(store, cfg)
    if reviewer is None:
        reviewer = _surveyor(rdir)
        if not reviewer:
            # a missing or damaged register is said first: a name would not make it reviewable
            from inspect_pipe.report._register import read_register

            reg = rdir / "defects.json"
            if not reg.is_file():
                raise InputError(str(reg), "not found: the run has no register", "run inspect-pipe run (or report) on it first")
            read_register(reg, rdir / "defects.csv")
            raise InputError("--reviewer", "missing and the survey plan names no surveyor", "give --reviewer 'NAME'")
    return Review.open(rdir, reviewer), store, cfg


def _surveyor(report_dir: Path) -> str | None:
    try:
        doc = json.loads((report_dir / "defects.json").read_text())
    except (OSError, ValueError):
        return None
    plan = ((doc.get("traceability") or {}).get("survey_plan") or {}) if isinstance(doc, dict) else {}
    s = plan.get("surveyor") if isinstance(plan, dict) else None
    return s if isinstance(s, str) and s.strip() else None


class ReviewServer:
    """The review behind a Starlette app; re-renders the report in a background thread."""

    def __init__(self, review: Review, store: Any, run_cfg: Any, config: ReviewConfig = ReviewConfig()) -> None:
        if not is_loopback(config.host) and not config.token:
            raise ValueError("a token is required to serve on a non-loopback address")
        self.review = review
        self.store = store
        self.run_cfg = run_cfg
        self.cfg = config
        self.auth = TokenSessions(config.token, tls=config.tls, login_rate=config.login_rate,
                                  on_event=lambda addr, what, outcome: log.info("%s from %s: %s", what, addr, outcome))
        self.dirty = False
        self.last_edit = 0.0
        self.rendered: dict = {"at": None, "seconds": None, "pdf": None, "error": None, "renders": 0}
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._mosaic_wh: tuple[int, int] | None = None

    # ------------------------------------------------------------------ rendering
    def render(self) -> dict:
        """Re-render the report from the run (report_from_run with the edited register as the
        previous one) under the review's lock, then reload the register it wrote."""
        from inspect_pipe.pipeline._steps import run_report_step

        with self.review.lock:
            t0 = time.perf_counter()
            notes: list[str] = []
            try:
                written = run_report_step(self.store, self.run_cfg, None, log=notes.append)
                err = None
            except InputError as e:
                written, err = {}, str(e)
            self.review.reload_if_changed()  # the register the report step wrote (same ids, statuses and notes)
            self.dirty = False
            if err is None and not written.get("pdf") and self.run_cfg.report_params().pdf and notes:
                err = notes[-1]  # the HTML is written; why the PDF is not (WeasyPrint missing ...)
            self.rendered = {"at": utc_now(), "seconds": round(time.perf_counter() - t0, 2), "pdf": bool(written.get("pdf")),
                             "error": err, "renders": self.rendered["renders"] + 1}
            return self.rendered

    def _renderer(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(0.5)
            self._wake.clear()
            if self.dirty and self.cfg.render_after_s is not None and time.monotonic() - self.last_edit >= self.cfg.render_after_s:
                try:
                    self.render()
                except Exception as e:  # noqa: BLE001 - the page shows it; the register is already saved
                    self.rendered = {**self.rendered, "error": f"{e.__class__.__name__}: {e}"}
                    self.dirty = False

    def start(self) -> None:
        self._thread = threading.Thread(target=self._renderer, daemon=True, name="review-render")
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=60)
        if self.dirty:
            try:
                r = self.render()
            except Exception as e:  # noqa: BLE001 - the register and the audit log are saved; say why the report is not
                r = {"error": f"{e.__class__.__name__}: {e}"}
            if r.get("error"):
                log.warning("report not re-rendered: %s; the register and %s are saved (inspect-pipe run --rerun-from report)",
                            r["error"], self.review.audit_path.name)

    # ------------------------------------------------------------------ helpers
    def mosaic_wh(self) -> tuple[int, int] | None:
        if self._mosaic_wh is None:
            try:
                from PIL import Image

                with Image.open(self.store.mosaic_dir / "mosaic.png") as im:
                    self._mosaic_wh = im.size
            except (OSError, ImportError):
                return None
        return self._mosaic_wh

    def state(self) -> dict:
        r = self.review
        audit = r.audit_path
        return {"reviewer": r.reviewer, "run": str(self.store.root), "register": str(r.json_path), "audit": str(audit),
                "audit_lines": _count_lines(audit), "edits": r.edits, "entries": r.entries(), "mosaic_wh": self.mosaic_wh(),
                "overlay": "assets/overlay.png" if (r.dir / "assets" / "overlay.png").is_file() else None,
                "rendered": self.rendered, "dirty": self.dirty}

    # ------------------------------------------------------------------ the app
    def app(self) -> Any:
        from starlette.applications import Starlette
        from starlette.responses import FileResponse, HTMLResponse, JSONResponse, Response
        from starlette.routing import Route

        static = resources.files("inspect_pipe.review_app") / "static"
        page = (static / "index.html").read_text()
        script = (static / "review.js").read_text()
        login_page = login_page_html("review", "Register review")
        no_store = {"Cache-Control": "no-store"}

        def error(status: int, message: str) -> Response:
            return JSONResponse({"error": message}, status, headers=no_store)

        def refused(request: Any) -> Response | None:
            if "token" in request.query_params:
                return self.auth.url_token_response()
            if not self.auth.authorized(request):
                return error(401, "log in first (POST /login with the token)")
            return None

        async def index(request: Any) -> Response:
            if "token" in request.query_params:
                return self.auth.url_token_response()
            if not self.auth.authorized(request):
                return HTMLResponse(login_page, 401, headers=no_store)
            return HTMLResponse(page, headers=no_store)

        async def review_js(request: Any) -> Response:
            return Response(script, media_type="application/javascript", headers=no_store)

        async def login(request: Any) -> Response:
            return await self.auth.login(request, login_page)

        async def logout(request: Any) -> Response:
            return await self.auth.logout(request)

        async def register(request: Any) -> Response:
            return refused(request) or JSONResponse(self.state(), headers=no_store)

        async def edit(request: Any) -> Response:
            if (r := refused(request)) is not None:
                return r
            if not self.auth.origin_ok(request.headers):
                return error(403, "edit from a page of another origin refused")
            if not request.headers.get("content-type", "").startswith("application/json"):
                return error(415, "edit request: send JSON (Content-Type: application/json)")
            body = await request.body()
            if len(body) > MAX_BODY:
                return error(413, f"edit request: {len(body)} bytes, at most {MAX_BODY}")
            try:
                doc = json.loads(body)
            except (ValueError, UnicodeDecodeError):
                return error(400, "edit request: not valid JSON")
            from starlette.concurrency import run_in_threadpool

            try:
                rec = await run_in_threadpool(self.review.apply, doc)
            except ReviewError as e:
                return error(e.http, str(e))
            except InputError as e:
                return error(400, str(e))
            if rec is not None:
                self.dirty = True
                self.last_edit = time.monotonic()
                self._wake.set()
            entry = next((e for e in self.review.entries() if e["id"] == doc.get("id")), None)
            return JSONResponse({"ok": True, "changed": rec is not None, "record": rec, "entry": entry,
                                 "audit_lines": _count_lines(self.review.audit_path)}, headers=no_store)

        async def render(request: Any) -> Response:
            if (r := refused(request)) is not None:
                return r
            if not self.auth.origin_ok(request.headers):
                return error(403, "request from a page of another origin refused")
            from starlette.concurrency import run_in_threadpool

            out = await run_in_threadpool(self.render)
            return JSONResponse(out, headers=no_store)

        async def asset(request: Any) -> Response:
            if (r := refused(request)) is not None:
                return r
            base = (self.review.dir / "assets").resolve()
            p = (base / request.path_params["path"]).resolve()
            if base not in p.parents or not p.is_file() or p.suffix.lower() not in (".png", ".jpg", ".jpeg"):
                return error(404, f"assets/{request.path_params['path']}: not found")
            return FileResponse(p, headers=no_store)

        @contextlib.asynccontextmanager
        async def lifespan(app: Any):
            self.start()
            try:
                yield
            finally:
                self.stop()

        return Starlette(routes=[
            Route("/", index), Route("/review.js", review_js), Route("/login", login, methods=["POST"]),
            Route("/logout", logout, methods=["POST"]), Route("/api/register", register),
            Route("/api/edit", edit, methods=["POST"]), Route("/api/render", render, methods=["POST"]),
            Route("/assets/{path:path}", asset),
        ], lifespan=lifespan)


def _count_lines(path: Path) -> int:
    try:
        return path.read_bytes().count(b"\n")
    except FileNotFoundError:
        return 0
