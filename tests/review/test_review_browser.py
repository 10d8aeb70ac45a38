"""The review page in headless Chromium (Debian's /usr/bin/chromium, driven by Playwright): 100
keyboard edits (j/k, c, r, s, t, n), a server restart, and the decisions in the audit log, the
register and the re-rendered PDF (pdftotext, and pages rendered with pdftoppm to
``out/test_screenshots/review_pdf-*.png`` with the page itself as ``review_page.png``; override:
INSPECT_PIPE_SCREENSHOTS)."""

from __future__ import annotations

import json
import os
import random
import re
import shutil
import socket
import subprocess
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("starlette", reason="review needs the [base] extra")
uvicorn = pytest.importorskip("uvicorn", reason="review needs the [base] extra")
sync_api = pytest.importorskip("playwright.sync_api", reason="browser test needs the [browser-test] extra (playwright)")

CHROMIUM = os.environ.get("INSPECT_PIPE_CHROMIUM", "/usr/bin/chromium")
if not Path(CHROMIUM).exists() and not shutil.which(CHROMIUM):
    pytest.skip(f"no Chromium at {CHROMIUM} (apt-get install chromium; `make test` does it where apt works)", allow_module_level=True)

from inspect_pipe.report import read_register  # noqa: E402
from inspect_pipe.review_app import ReviewConfig, ReviewServer, open_review  # noqa: E402

SHOTS = Path(os.environ.get("INSPECT_PIPE_SCREENSHOTS", Path(__file__).resolve().parents[2] / "out" / "test_screenshots"))
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--disable-dev-shm-usage"]
ROW = re.compile(r"^\s*(D\d{3}) (corrosion|crack)\s+(suggested|confirmed|rejected)\b", re.M)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Served:
    """``inspect-pipe review RUN`` as the command builds it, served by uvicorn in a thread."""

    def __init__(self, run: Path, port: int, token: str | None = None) -> None:
        rv, store, cfg = open_review(run, "J. Smith")
        self.server = ReviewServer(rv, store, cfg, ReviewConfig(port=port, render_after_s=None, token=token))
        self.uv = uvicorn.Server(uvicorn.Config(self.server.app(), host="127.0.0.1", port=port, log_level="warning"))
        self.thread = threading.Thread(target=self.uv.run, daemon=True)

    def __enter__(self) -> "Served":
        self.thread.start()
        t0 = time.monotonic()
        while not self.uv.started:
            assert time.monotonic() - t0 < 10, "server did not start"
            time.sleep(0.02)
        return self

    def __exit__(self, *exc) -> None:
        self.uv.should_exit = True
        self.thread.join(timeout=120)  # stopping re-renders the report
        assert not self.thread.is_alive()


def _plan(entries: list[dict], n: int, seed: int = 20) -> tuple[list[tuple[str, str | None]], dict]:
    """n keyboard edits that each change something: (keys, note text) and the register they leave."""
    rng = random.Random(seed)
    state = {e["id"]: {"status": e["status"], "class": e["class"], "note": e["note"]} for e in entries}
    ids = [e["id"] for e in entries]
    sel, steps = 0, []
    for k in range(n):
        move = rng.choice([0, 1, 1, 2, -1])
        for _ in range(abs(move)):
            steps.append(("j" if move > 0 else "k", None))
        sel = max(0, min(len(ids) - 1, sel + move))
        s = state[ids[sel]]
        key = rng.choice([x for x in ("c", "r", "s", "t", "n") if (x, s["status"]) not in (("c", "confirmed"), ("r", "rejected"), ("s", "suggested"))])
        if key == "n":
            text = f"note {k}: pitting, re-check"
            steps.append(("n", text))
            s["note"] = text
        else:
            steps.append((key, None))
            if key == "t":
                s["class"] = "corrosion" if s["class"] == "crack" else "crack"
            else:
                s["status"] = {"c": "confirmed", "r": "rejected", "s": "suggested"}[key]
    return steps, state


def test_100_keyboard_edits_survive_a_restart_and_reach_the_pdf(review_run) -> None:
    _, run = review_run
    rep = run / "report"
    SHOTS.mkdir(parents=True, exist_ok=True)
    pdf_before = (rep / "report.pdf").stat().st_mtime_ns
    port = free_port()
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            with Served(run, port):
                page = browser.new_page(viewport={"width": 1280, "height": 860})
                page.goto(f"http://127.0.0.1:{port}/")
                page.wait_for_function("window.review.entries.length === 14", timeout=10_000)
                entries = page.evaluate("window.review.entries")
                steps, expected = _plan(entries, 100)
                t0 = time.monotonic()
                for key, text in steps:
                    page.keyboard.press(key)
                    if text is not None:
                        page.wait_for_selector("#note", state="visible")
                        page.keyboard.type(text)
                        page.keyboard.press("Enter")
                try:
                    page.wait_for_function("window.review.pending === 0 && window.review.saved === 100", timeout=60_000)
                except sync_api.TimeoutError:
                    pytest.fail(f"not all saved: {page.evaluate('[window.review.saved, window.review.pending, window.review.errors, window.review.lastError]')}")
                seconds = time.monotonic() - t0
                assert page.evaluate("window.review.errors") == 0, page.evaluate("window.review.lastError")
                assert page.inner_text("#audit") == "100"
                page.keyboard.press("k")
                page.wait_for_timeout(300)
                page.screenshot(path=str(SHOTS / "review_page.png"))
                print(f"100 keyboard edits saved in {seconds:.1f} s")
            # the server stopped: it re-rendered the report on the way out
            assert (rep / "report.pdf").stat().st_mtime_ns > pdf_before
            # WHEN the review is started again THEN all 100 edits are there
            with Served(run, port):
                page = browser.new_page(viewport={"width": 1280, "height": 860})
                page.goto(f"http://127.0.0.1:{port}/")
                page.wait_for_function("window.review.entries.length === 14", timeout=10_000)
                shown = {e["id"]: {"status": e["status"], "class": e["class"], "note": e["note"]} for e in page.evaluate("window.review.entries")}
                assert shown == expected
                assert page.inner_text("#audit") == "100"
        finally:
            browser.close()
    audit = [json.loads(x) for x in (rep / "audit.jsonl").read_text().splitlines()]
    assert len(audit) == 100 and {a["reviewer"] for a in audit} == {"J. Smith"}
    assert sum(a["field"] == "note" for a in audit) == sum(k == "n" for k, _ in steps)
    reg = {d.id: {"status": d.status, "class": d.cls, "note": d.note} for d in read_register(rep / "defects.json", rep / "defects.csv")}
    assert reg == expected
    # the re-rendered PDF's register table shows each entry's class and status
    text = subprocess.run(["pdftotext", "-layout", str(rep / "report.pdf"), "-"], capture_output=True, text=True, check=True).stdout
    rows = {m.group(1): (m.group(2), m.group(3)) for m in ROW.finditer(text)}
    assert rows == {i: (s["class"], s["status"]) for i, s in expected.items()}
    assert "Reviewed by J. Smith: 100 changes to the register" in " ".join(text.split())
    assert text.count("reclassified") >= sum(1 for i, s in expected.items() if s["class"] != next(e["class"] for e in entries if e["id"] == i))
    for old in SHOTS.glob("review_pdf-*.png"):
        old.unlink()
    subprocess.run(["pdftoppm", "-png", "-r", "60", str(rep / "report.pdf"), str(SHOTS / "review_pdf")], check=True)
    assert list(SHOTS.glob("review_pdf-*.png"))


def test_with_a_token_the_page_logs_in_once_and_edits_on_the_session_cookie(review_run) -> None:
    _, run = review_run
    port = free_port()
    with Served(run, port, token="surveyor-token-0123"), sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1100, "height": 800})
            page.goto(f"http://127.0.0.1:{port}/")
            assert page.locator("form#login").count() == 1
            page.fill("#token", "not-the-token-00000")
            page.click("button[type=submit]")
            assert "wrong token" in page.content()
            page.goto(f"http://127.0.0.1:{port}/")
            page.fill("#token", "surveyor-token-0123")
            page.click("button[type=submit]")
            page.wait_for_function("window.review && window.review.entries.length === 14", timeout=10_000)
            assert "token" not in page.url and page.evaluate("document.cookie") == ""
            page.keyboard.press("j")
            page.keyboard.press("c")
            page.wait_for_function("window.review.pending === 0 && window.review.saved === 1", timeout=10_000)
            page.click("#btn-logout")
            page.wait_for_selector("form#login", timeout=10_000)
        finally:
            browser.close()
    rec = json.loads((run / "report" / "audit.jsonl").read_text())
    assert (rec["id"], rec["after"]) == ("D002", "confirmed")
