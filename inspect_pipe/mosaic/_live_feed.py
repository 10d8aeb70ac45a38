"""The live mosaic beside a camera stream: a :class:`~inspect_pipe.mosaic.LiveMosaic` on its own
thread behind a bounded queue, with a status line and pictures for the capture's live line and the
base station's panel.

``submit(image, state)`` never waits (unless asked to, for simulated time): when the mosaicer is
behind and the queue is full, the frame is skipped and counted, so a slow mosaic never slows the
10 Hz writer. A stream that stops (no frame for ``stall_s`` while frames are expected) is one
problem line; everything placed so far stays.
"""

from __future__ import annotations

import queue
import threading
import time
from dataclasses import dataclass, replace
from typing import Callable

import cv2
import numpy as np

from ._live import LiveMosaic, LiveParams

__all__ = ["LiveFeed", "LiveStatus"]

_STOP = object()


@dataclass(frozen=True)
class LiveStatus:
    frames: int  # frames the mosaicer took up
    placed: int
    skipped: int  # frames dropped because the mosaicer was behind (queue full)
    queued: int  # frames waiting: the mosaicer is behind by this many
    covered_pct: float  # share of the swept area imaged at usable resolution and sharpness
    gaps: int  # gap regions (each at least ``min_gap`` of the swept area)
    gap_pct: float  # share of the swept area in gaps
    p95_ms: float  # wall time per frame (add_frame)
    p95_cpu_ms: float  # CPU time per frame of the mosaicer's thread
    problem: str  # one line, or ""
    version: int  # bumps with every frame placed (pictures change)
    not_inspecting: int = 0  # frames left out because the vehicle said inspection mode was off

    def line(self, problem: bool = True) -> str:
        """One line for a terminal or a page: what is covered, the gaps, how far behind (and the
        problem, if any and ``problem``)."""
        if not self.frames:
            text = "live mosaic: waiting for " + ("inspection mode" if self.not_inspecting else "frames")
        else:
            text = (f"live mosaic: {self.covered_pct:.0f} % covered, {self.gaps} gap{'s' if self.gaps != 1 else ''}"
                    + (f" ({self.gap_pct:.0f} % of the area)" if self.gaps else "")
                    + f", {self.placed}/{self.frames} frames placed")
        if self.queued:
            text += f", behind by {self.queued}"
        if self.skipped:
            text += f" ({self.skipped} skipped)"
        return text + (f"; {self.problem}" if self.problem and problem else "")

    def to_json(self) -> dict:
        return {"frames": self.frames, "placed": self.placed, "skipped": self.skipped, "queued": self.queued,
                "covered_pct": round(self.covered_pct, 1), "gaps": self.gaps, "gap_pct": round(self.gap_pct, 1),
                "p95_ms": round(self.p95_ms, 1), "p95_cpu_ms": round(self.p95_cpu_ms, 1), "problem": self.problem,
                "version": self.version, "not_inspecting": self.not_inspecting, "line": self.line(problem=False)}


def coverage_figures(covered: np.ndarray, gaps: np.ndarray, min_gap: float = 0.01) -> tuple[float, int, float]:
    """(covered %, gap regions, gap %) of the swept area (covered or gap). A gap region counts when it
    is at least ``min_gap`` of that area (slivers along the hull's edge do not)."""
    area = int(covered.sum()) + int(gaps.sum())
    if area == 0:
        return 0.0, 0, 0.0
    n, _, stats, _ = cv2.connectedComponentsWithStats(gaps.astype(np.uint8), connectivity=8)
    big = [s for s in stats[1:, cv2.CC_STAT_AREA] if s >= min_gap * area]
    return float(100.0 * covered.sum() / area), len(big), float(100.0 * sum(big) / area)


class LiveFeed:
    """A live mosaic fed from a capture loop (see the module docstring). ``clock`` is the stream's
    clock (the capture's: simulated time for a simulated camera), for stall detection.

    Only the mosaicer's thread touches the :class:`LiveMosaic`; it publishes a status (every
    ``refresh_s``) and, when ``pictures=True``, the two pictures (every ``picture_every_s``), so
    ``submit``, ``status`` and ``pictures`` never wait for a frame being placed."""

    def __init__(self, *, params: LiveParams | None = None, queue_frames: int = 8, stall_s: float = 3.0,
                 clock: Callable[[], float] = time.monotonic, m_per_px: float | None = None, pictures: bool = False,
                 picture_every_s: float = 1.0, refresh_s: float = 0.5, max_picture_px: int = 640) -> None:
        self.params = params or LiveParams()
        self.stall_s = stall_s
        self.clock = clock
        self.m_per_px = m_per_px
        self.want_pictures = pictures
        self.picture_every_s = picture_every_s
        self.refresh_s = refresh_s
        self.max_picture_px = max_picture_px
        self._q: queue.Queue = queue.Queue(maxsize=queue_frames)
        self._lock = threading.Lock()  # counters and the published status / pictures; held briefly
        self._live: LiveMosaic | None = None  # the mosaicer's thread's alone
        self._skipped = 0
        self._submitted = 0
        self._not_inspecting = 0  # frames the tap left out: inspection mode off
        self._version = 0
        self._last_frame_t: float | None = None
        self._expect_since: float | None = None  # frames are expected since this time (None: not expected)
        self._error = ""
        self._status = LiveStatus(0, 0, 0, 0, 0.0, 0, 0.0, 0.0, 0.0, "", 0)
        self._pictures: tuple[int, np.ndarray, np.ndarray] | None = None
        self._t_status = self._t_pictures = -np.inf
        self._thread = threading.Thread(target=self._run, daemon=True, name="live-mosaic")
        self._thread.start()

    # ----- the producer's side (the capture loop) -----

    def submit(self, image: np.ndarray, state: dict | None = None, *, block: bool = False) -> bool:
        """Hand one frame to the mosaicer; False when it was skipped (the mosaicer is behind).
        ``block``: wait for room instead (simulated time, where nothing is late)."""
        now = self.clock()
        with self._lock:
            self._last_frame_t = now
            if self._expect_since is None:
                self._expect_since = now
            self._submitted += 1
        try:
            self._q.put((image, dict(state or {})), block=block)
            return True
        except queue.Full:
            with self._lock:
                self._skipped += 1
            return False

    def tap(self, *, block: bool = False) -> Callable:
        """``run_capture(on_frame=...)``: each written frame with its capture time and the vehicle's
        position; the first frame with a distance to the wall sets the wall's metres per pixel
        (distance / focal length), so the mosaicer can place by odometry a frame that matches nothing.
        Frames whose vehicle state says inspection mode is off (take-off, landing, transit: the
        simulator's and a replayed sweep's states say so; an autopilot's do not) are not mosaicked,
        and not expected: the map is the inspection's."""

        def on_frame(image: np.ndarray, record: dict, camera) -> None:
            st = record.get("state") or {}
            if st.get("inspection_mode") is False:
                self.expect(False)
                with self._lock:
                    self._not_inspecting += 1
                return
            if self.m_per_px is None and st.get("dist_front_m") and camera is not None:
                self.m_per_px = float(st["dist_front_m"]) / float(camera.K[0, 0])
                if self._live is not None:  # created from an earlier frame (no distance then)
                    self._live.m_per_px = self.m_per_px
            self.submit(image, {"t_s": record.get("t_s"), "position_m": st.get("position_m"), "dist_front_m": st.get("dist_front_m")},
                        block=block)

        return on_frame

    def expect(self, on: bool) -> None:
        """Whether frames are expected now (a stall is reported only while they are); ``submit``
        starts expecting by itself. The base station turns this off outside inspection mode."""
        with self._lock:
            if not on:
                self._expect_since = None
            elif self._expect_since is None:
                self._expect_since = self.clock()

    def drain(self, timeout_s: float = 30.0) -> None:
        """Wait until every submitted frame was taken up and the status is up to date."""
        t0 = time.monotonic()
        while self._q.unfinished_tasks and time.monotonic() - t0 < timeout_s and self._thread.is_alive():
            time.sleep(0.005)
        if self._thread.is_alive():
            done = threading.Event()
            try:
                self._q.put((None, {"_refresh": done}), timeout=timeout_s)
                done.wait(timeout_s)
            except queue.Full:
                pass

    def close(self, timeout_s: float = 30.0) -> LiveStatus:
        """Take up what is queued, publish the final status (and pictures), stop the thread. No
        frames are expected after this (no stall is reported)."""
        self.expect(False)
        self.drain(timeout_s)
        try:
            self._q.put(_STOP, timeout=timeout_s)
        except queue.Full:
            pass
        self._thread.join(timeout=timeout_s)
        return self.status()

    # ----- the mosaicer's thread -----

    def _run(self) -> None:
        cv2.setNumThreads(1)  # one core: the capture and the flight loop keep the other
        dirty = False
        while True:
            try:
                item = self._q.get(timeout=self.refresh_s)
            except queue.Empty:  # idle: publish what the last frames changed
                if dirty:
                    self._publish(force=True)
                    dirty = False
                continue
            try:
                if item is _STOP:
                    return
                image, state = item
                if image is None:  # drain(): publish now
                    self._publish(force=True)
                    state["_refresh"].set()
                    continue
                if self._live is None:
                    h, w = image.shape[:2]
                    self._live = LiveMosaic((w, h), self.params, m_per_px=self.m_per_px)
                try:
                    p = self._live.add_frame(image, state)
                except Exception as err:  # a frame the mosaicer cannot take (another size, garbage): said, not fatal
                    with self._lock:
                        self._error = f"live mosaic: a frame was not placed ({err.__class__.__name__}: {err})"
                    continue
                if p.placed:
                    with self._lock:
                        self._version += 1
                dirty = not self._publish(force=False)
            finally:
                self._q.task_done()

    def _publish(self, force: bool) -> bool:
        """Publish the status (and pictures) if ``force`` or their time has come; True if published."""
        live = self._live
        if live is None:
            return True
        now = time.monotonic()
        if not (force or now - self._t_status >= self.refresh_s):
            return False
        self._t_status = now
        s = live.summary()
        cov, gaps, gap_pct = coverage_figures(live.covered(), live.gaps())
        st = LiveStatus(s["frames"], s["placed"], 0, 0, cov, gaps, gap_pct, s["p95_ms"], s["p95_cpu_ms"], s["problem"], self._version)
        with self._lock:
            self._status = st
        if self.want_pictures and (force or now - self._t_pictures >= self.picture_every_s):
            self._t_pictures = now
            pics = self._render_pictures(live)
            with self._lock:
                self._pictures = pics
        return not self.want_pictures or self._t_pictures == now

    def _render_pictures(self, live: LiveMosaic) -> tuple[int, np.ndarray, np.ndarray] | None:
        mosaic, cover = live.mosaic(), live.coverage()
        seen = mosaic.any(axis=2) | cover.any(axis=2)
        if not seen.any():
            return None
        ys, xs = np.nonzero(seen)  # crop to what was seen (the canvas keeps a margin to grow into)
        mosaic = mosaic[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1]
        cover = cover[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1]
        k = self.max_picture_px / max(mosaic.shape[:2])
        if k < 1:
            size = (max(1, round(mosaic.shape[1] * k)), max(1, round(mosaic.shape[0] * k)))
            mosaic = cv2.resize(mosaic, size, interpolation=cv2.INTER_AREA)
            cover = cv2.resize(cover, size, interpolation=cv2.INTER_NEAREST)
        return self._version, mosaic, cover

    # ----- what the live line and the panel read (never waits for the mosaicer) -----

    def stalled(self) -> str:
        """One line when frames are expected and none came for ``stall_s``, else ""."""
        with self._lock:
            if self._expect_since is None:
                return ""
            ref = max(self._expect_since, self._last_frame_t if self._last_frame_t is not None else self._expect_since)
            quiet = self.clock() - ref
            if quiet <= self.stall_s:
                return ""
            placed = self._status.placed
            return f"live stream stalled: no frame for {quiet:.1f} s ({self._submitted} frames so far); the {placed} placed are kept"

    def status(self) -> LiveStatus:
        stall = self.stalled()
        with self._lock:
            st, skipped, err, out = self._status, self._skipped, self._error, self._not_inspecting
        return replace(st, skipped=skipped, queued=self._q.qsize(), problem=stall or st.problem or err, not_inspecting=out)

    def pictures(self) -> tuple[int, np.ndarray, np.ndarray] | None:
        """(version, low-resolution mosaic, coverage map): BGR, cropped to what was seen, at most
        ``max_picture_px`` on the longer side; None before the first picture (``pictures=True``)."""
        with self._lock:
            return self._pictures

    def live_mosaic(self) -> LiveMosaic | None:
        """The mosaicer itself (read it only after :meth:`close`)."""
        return self._live
