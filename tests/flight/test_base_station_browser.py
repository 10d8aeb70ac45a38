"""The page in headless Chromium (Debian's /usr/bin/chromium, driven by Playwright): take off,
push forward with the keyboard towards the wall, read the attenuation message, stop at the stop
line, land. Screenshots go to ``out/test_screenshots/`` (override: INSPECT_PIPE_SCREENSHOTS)."""

from __future__ import annotations

import contextlib
import os
import shutil
import time
from pathlib import Path

import pytest

pytest.importorskip("starlette", reason="base station needs the [base] extra")
pytest.importorskip("uvicorn", reason="base station needs the [base] extra")
sync_api = pytest.importorskip("playwright.sync_api", reason="browser test needs the [browser-test] extra (playwright)")

CHROMIUM = os.environ.get("INSPECT_PIPE_CHROMIUM", "/usr/bin/chromium")
if not Path(CHROMIUM).exists() and not shutil.which(CHROMIUM):
    pytest.skip(f"no Chromium at {CHROMIUM} (apt-get install chromium; `make test` does it where apt works)", allow_module_level=True)

from inspect_pipe.flight.base_station import build_station  # noqa: E402

from test_base_station import Served, free_port  # noqa: E402  (tests/flight is on sys.path)

SHOTS = Path(os.environ.get("INSPECT_PIPE_SCREENSHOTS", Path(__file__).resolve().parents[2] / "out" / "test_screenshots"))
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--disable-dev-shm-usage"]


@contextlib.contextmanager
def _flying(tmp_path: Path, height: int):
    """A station on loopback with its page in control, after T took the vehicle off."""
    port = free_port()
    station = build_station(None, port=port, command_log=tmp_path / "commands.jsonl")
    SHOTS.mkdir(parents=True, exist_ok=True)
    with Served(station, port), sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1100, "height": height})
            page.goto(f"http://127.0.0.1:{port}/")
            page.wait_for_function("document.getElementById('role').textContent === 'in control'", timeout=10_000)
            page.keyboard.press("t")
            page.wait_for_function("window.basestation.lastState && window.basestation.lastState.fsm === 'flying'", timeout=10_000)
            yield page
        finally:
            browser.close()


def test_fly_to_the_wall_from_the_browser(tmp_path: Path) -> None:
    # GIVEN the vehicle landed WHEN the surveyor presses T THEN it takes off.
    with _flying(tmp_path, 800) as page:
        state = lambda: page.evaluate("window.basestation.lastState")  # noqa: E731
        page.screenshot(path=str(SHOTS / "1_flying.png"))
        # WHEN W is held towards the wall THEN the page says the speed is attenuated...
        page.keyboard.down("w")
        page.wait_for_function("document.getElementById('feedback').textContent.includes('speed attenuated')", timeout=15_000)
        page.screenshot(path=str(SHOTS / "2_attenuated.png"))
        # ...and the vehicle stops at the stop line while the key is still held.
        page.wait_for_function("document.getElementById('feedback').textContent.includes('stop line')", timeout=10_000)
        time.sleep(1.5)
        s = state()
        page.screenshot(path=str(SHOTS / "3_stop_line.png"))
        page.keyboard.up("w")
        assert s["user_cmd"]["vx"] == pytest.approx(0.5) and abs(s["cmd"]["vx"]) < 0.1
        front = s["vehicle"]["dist_true_front"]
        assert 0.9 <= front <= 1.1, f"stopped {front:.2f} m from the wall"
        assert s["vehicle"]["collisions"] == 0
        assert page.evaluate("window.basestation.rateHz") >= 10.0
        assert page.evaluate("document.getElementById('camera').src").startswith("data:image/jpeg")
        # WHEN L is pressed THEN it lands.
        page.keyboard.press("l")
        page.wait_for_function("window.basestation.lastState.fsm === 'landed'", timeout=15_000)
        page.screenshot(path=str(SHOTS / "4_landed.png"))
    log = (tmp_path / "commands.jsonl").read_text()
    assert '"takeoff"' in log and '"land"' in log


def test_the_token_is_typed_once_and_the_page_runs_on_the_session_cookie(tmp_path: Path) -> None:
    port = free_port()
    station = build_station(None, port=port, token="tablet-token-0123456", command_log=tmp_path / "commands.jsonl")
    with Served(station, port), sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1100, "height": 800})
            page.goto(f"http://127.0.0.1:{port}/")
            # GIVEN a token-protected station THEN the page is a login form
            assert page.locator("form#login").count() == 1
            page.fill("#token", "not-the-token-00000")
            page.click("button[type=submit]")
            assert "wrong token" in page.content()
            # WHEN the surveyor types the token THEN the station runs, with the token in no URL and no script-visible cookie
            page.goto(f"http://127.0.0.1:{port}/")
            page.fill("#token", "tablet-token-0123456")
            page.click("button[type=submit]")
            page.wait_for_function("document.getElementById('role').textContent === 'in control'", timeout=10_000)
            assert "token" not in page.url and page.evaluate("document.cookie") == ""
            cookies = page.context.cookies()
            assert [(c["name"], c["httpOnly"], c["sameSite"]) for c in cookies] == [("ip_session", True, "Strict")]
            assert cookies[0]["value"] != "tablet-token-0123456"
            page.wait_for_function("window.basestation.states > 5", timeout=10_000)
            # WHEN the surveyor logs out THEN the login form is back and the old cookie opens nothing
            page.click("#btn-logout")
            page.wait_for_selector("form#login", timeout=10_000)
        finally:
            browser.close()
    log = (tmp_path / "commands.jsonl").read_text()
    assert "refused: wrong token" in log and '"logout"' in log and "tablet-token-0123456" not in log


def test_the_live_mosaic_panel_grows_with_the_sweep_and_says_when_the_stream_stalls(tmp_path: Path) -> None:
    # GIVEN the vehicle flying, before inspection mode THEN the panel has no pictures
    with _flying(tmp_path, 900) as page:
        assert page.evaluate("document.getElementById('mosaic').getAttribute('src')") is None
        # WHEN inspection mode is on and the vehicle sweeps sideways THEN the mosaic and its coverage map arrive...
        page.keyboard.press("i")
        page.wait_for_function("window.basestation.mosaicVersion > 0", timeout=15_000)
        first = page.evaluate("[window.basestation.mosaicVersion, document.getElementById('mosaic').src, document.getElementById('coverage').src]")
        assert first[1].startswith("data:image/jpeg") and first[2].startswith("data:image/png")
        page.keyboard.down("d")
        page.wait_for_function(f"window.basestation.mosaicVersion > {first[0]} + 15", timeout=20_000)
        page.keyboard.up("d")
        # ...and change as it grows, with the share covered in words
        later = page.evaluate("[document.getElementById('mosaic').src, document.getElementById('coverage').src]")
        assert later[0] != first[1] and later[1] != first[2]
        page.wait_for_function("/\\d+ % covered/.test(document.getElementById('mosaic-line').textContent)", timeout=10_000)
        status = page.evaluate("window.basestation.lastState.mosaic")
        assert status["placed"] >= 15 and status["covered_pct"] > 50 and not status["problem"], status
        size = page.evaluate("[document.getElementById('mosaic').naturalWidth, document.getElementById('mosaic').naturalHeight]")
        assert size[0] > size[1] > 0, size  # a sideways sweep: wider than tall
        page.locator("#mosaic-panel").screenshot(path=str(SHOTS / "5_mosaic_panel.png"))
        # WHEN the camera is turned away from the wall (inspection mode off: it holds the heading) and inspection
        # mode goes on again THEN the panel says the stream stalled, and what was placed stays
        placed = status["placed"]
        page.keyboard.press("o")
        page.wait_for_function("window.basestation.lastState.inspection_mode === false", timeout=5_000)
        page.keyboard.down("e")
        page.wait_for_function("Math.cos(window.basestation.lastState.vehicle.yaw_true) < 0.2", timeout=15_000)
        page.keyboard.up("e")
        assert not page.evaluate("document.getElementById('mosaic-problem').textContent")  # not expected, not stalled
        page.keyboard.press("i")
        page.wait_for_function("document.getElementById('mosaic-problem').textContent.includes('stalled')", timeout=15_000)
        problem = page.evaluate("document.getElementById('mosaic-problem').textContent")
        assert "no frame for" in problem and "\n" not in problem
        assert page.evaluate("window.basestation.lastState.mosaic.placed") >= placed
        assert page.evaluate("document.getElementById('mosaic').src").startswith("data:image/jpeg")
        page.locator("#mosaic-panel").screenshot(path=str(SHOTS / "6_mosaic_stalled.png"))
