"""USB/CSI cameras through OpenCV's V4L2 back-end (``cv2.CAP_V4L2``): pixel format, size, buffer
count, manual exposure. V4L2 cameras free-run (no software trigger): the camera runs at its own
rate, and each grab drains the driver's queue and keeps the frame whose driver timestamp is
nearest the deadline (decimation); the timestamps are the capture times and their gaps the true
drops. ``camera_modes`` lists what a camera offers (``doctor``).

The same class drives any OpenCV capture (``api=cv2.CAP_ANY`` and a video file): the tests use
that to exercise this code path where no ``/dev/video*`` exists.
"""

from __future__ import annotations

import glob
import logging
import math
import re
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import cv2

from inspect_pipe.capture._clock import Clock
from inspect_pipe.capture._geometry import CameraModel
from inspect_pipe.capture._source import Grab, SourceInfo, SourceLost, default_cam_to_body
from inspect_pipe.errors import InputError

log = logging.getLogger(__name__)  # -v shows its debug lines

__all__ = ["CameraMode", "DriverClock", "OpenCVSource", "V4L2Source", "camera_modes", "device_name", "list_v4l2_devices",
           "parse_list_formats_ext", "probe_modes", "v4l2_backend_available"]


def list_v4l2_devices() -> list[str]:
    return sorted(glob.glob("/dev/video*"))


def v4l2_backend_available() -> bool:
    try:
        from cv2 import videoio_registry

        return any(b == cv2.CAP_V4L2 for b in videoio_registry.getCameraBackends())
    except Exception:  # older OpenCV without the registry
        return hasattr(cv2, "CAP_V4L2")


class DriverClock:
    """Maps the driver's frame timestamps to the host clock.

    V4L2 stamps each buffer on ``CLOCK_MONOTONIC`` (uvcvideo: at the start of the frame), the
    clock ``MonotonicClock`` reads, so on a camera the offset is zero. Any other stamp (a video
    file's position, a driver on another clock) is mapped with ``offset = min(host arrival -
    stamp)`` over the frames seen so far: a frame can only arrive after it was stamped, and the
    least-delayed one bounds the offset most tightly."""

    SAME_CLOCK_WITHIN_S = 1.0

    def __init__(self) -> None:
        self.offset_s: float | None = None
        self.same_clock: bool | None = None

    def to_host(self, stamp_s: float, arrival_s: float) -> float:
        if self.same_clock is None:
            self.same_clock = abs(arrival_s - stamp_s) < self.SAME_CLOCK_WITHIN_S
            log.debug("driver stamps %s", "on the host's monotonic clock: used as they are" if self.same_clock
                      else f"{arrival_s - stamp_s:+.3f} s from the host clock: mapped by the least arrival delay")
        if self.same_clock:
            return stamp_s
        d = arrival_s - stamp_s
        self.offset_s = d if self.offset_s is None else min(self.offset_s, d)
        return stamp_s + self.offset_s


class OpenCVSource:
    """A ``cv2.VideoCapture`` (or anything with its ``grab/retrieve/get/set/isOpened/release``,
    given as ``capture_factory``) as a free-running :class:`FrameSource`.

    The camera runs at its own rate (``fps`` None: its default mode) and the source decimates to
    the capture's deadlines: ``grab(deadline)`` dequeues every frame the driver has queued and
    returns the one whose capture time is nearest the deadline (it waits at most half a camera
    period for a frame after the deadline). Frames passed over are not drops; a drop is a gap in
    the driver's timestamps (``lost_before``: a gap of k camera periods = k-1 frames lost). The
    driver keeps ``buffers`` frames (by default enough for one capture period plus one, so that
    it never runs out between two deadlines; ``rate_hz`` sets that).

    The capture time is the driver's timestamp mapped to the host clock (:class:`DriverClock`),
    not the moment the frame reached Python. ``exposure_s`` None keeps the camera's auto exposure;
    a value sets manual exposure (V4L2 ``exposure_absolute`` counts 100 us). ``max_misses``
    failed reads in a row mean the camera is gone."""

    def __init__(
        self,
        device: str | int,
        *,
        clock: Clock,
        api: int = cv2.CAP_ANY,
        width: int | None = None,
        height: int | None = None,
        fps: float | None = None,
        rate_hz: float | None = None,
        fourcc: str | None = None,
        buffers: int | None = None,
        exposure_s: float | None = None,
        hfov_deg: float = 60.0,
        max_misses: int = 5,
        kind: str = "opencv",
        capture_factory: Callable[[str | int, int], Any] = cv2.VideoCapture,
    ) -> None:
        self.device, self.clock, self.api = device, clock, api
        self.width, self.height, self.fps, self.rate_hz, self.fourcc, self.buffers = width, height, fps, rate_hz, fourcc, buffers
        self.exposure_s, self.hfov_deg, self.max_misses, self.kind = exposure_s, hfov_deg, max_misses, kind
        self.capture_factory = capture_factory
        self._cap: Any = None
        self._last_dev: float | None = None
        self._period: float | None = None
        self._stamps = DriverClock()
        self._lost_pending = 0  # lost before the frame grab() returns next
        self.frames_seen = 0  # every frame dequeued from the driver
        self.frames_passed_over = 0  # decimated away (not drops)
        self.frames_lost = 0  # gaps in the driver's timestamps

    def open(self) -> SourceInfo:
        cap = self.capture_factory(self.device, self.api)
        if not cap.isOpened():
            raise InputError(str(self.device), "cannot open the camera", "check the device path, that no other program holds it, and permissions (group video)")
        if self.fourcc:
            cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*self.fourcc[:4].ljust(4)))
        if self.width:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
        if self.height:
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        if self.fps:
            cap.set(cv2.CAP_PROP_FPS, self.fps)
        if self.exposure_s is not None:
            cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1)  # V4L2: 1 = manual
            cap.set(cv2.CAP_PROP_EXPOSURE, self.exposure_s / 100e-6)
        fps = cap.get(cv2.CAP_PROP_FPS)
        self._period = 1.0 / fps if fps and fps > 0 else None
        if self.buffers is None:  # one capture period's frames plus one: the driver never runs dry of buffers
            per = fps / self.rate_hz if fps and fps > 0 and self.rate_hz else 1.0
            self.buffers = int(min(8, max(2, math.ceil(per - 1e-9) + 1)))
        cap.set(cv2.CAP_PROP_BUFFERSIZE, self.buffers)  # before the first grab starts the stream
        log.debug("%s: camera at %s fps (its own rate), %d driver buffers, decimated to %s Hz", self.device,
                  f"{fps:g}" if fps else "an unreported", self.buffers, self.rate_hz or "every frame")
        if fps and self.rate_hz and fps < self.rate_hz:
            log.warning("%s: the camera gives %g fps, fewer than the %g Hz asked: deadlines without a new frame are skipped",
                        self.device, fps, self.rate_hz)
        self._cap = cap
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        cam = CameraModel.from_hfov(w, h, self.hfov_deg, name="uncalibrated")
        extra = {"device": str(self.device), "backend": cap.getBackendName(), "fps": fps, "camera_fps": fps,
                 "decimated_to_hz": self.rate_hz, "buffers": self.buffers, "fourcc": self.fourcc,
                 "manual_exposure_s": self.exposure_s, "calibrated": False,
                 "capture_time": "driver timestamp mapped to the host clock"}
        return SourceInfo(self.kind, f"{self.kind} {self.device}", cam, default_cam_to_body(), triggered=False, extra=extra)

    def _read(self):
        """The next frame the driver has (blocking until one arrives): (image, capture time on the
        host clock, driver stamp in s or None, arrival time)."""
        assert self._cap is not None, "open() first"
        misses = 0
        while True:
            ok = self._cap.grab()
            if ok:
                arrival = self.clock.now()
                ok, img = self._cap.retrieve()
                if ok and img is not None:
                    stamp_ms = self._cap.get(cv2.CAP_PROP_POS_MSEC)
                    t_dev = stamp_ms / 1000.0 if stamp_ms and stamp_ms > 0 else None  # 0: the back-end has no stamps
                    t = self._stamps.to_host(t_dev, arrival) if t_dev is not None else arrival
                    self.frames_seen += 1
                    self._count_gap(t_dev)
                    return img, t, t_dev, arrival
            misses += 1
            if self.api != cv2.CAP_V4L2 and not isinstance(self.device, int) and Path(str(self.device)).is_file():
                raise StopIteration  # end of a file
            if misses >= self.max_misses:
                raise SourceLost(f"{self.device}: no frame after {misses} tries (unplugged?)")

    def _count_gap(self, t_dev: float | None) -> None:
        if t_dev is not None and self._last_dev is not None and self._period is None and t_dev > self._last_dev:
            self._period = t_dev - self._last_dev  # no rate reported: the first stamp interval
        if t_dev is not None and self._last_dev is not None and self._period:
            gap = t_dev - self._last_dev
            self._lost_pending += max(0, round(gap / self._period) - 1)  # a gap of k periods: k-1 frames lost
        if t_dev is not None:
            self._last_dev = t_dev

    def grab(self, deadline_s: float) -> Grab:
        frame = self._read()
        half = (self._period or 0.0) / 2.0
        # Dequeue while the next frame (one camera period later) would be nearer the deadline:
        # the queue is drained of stale frames, and at most half a period is waited past it.
        while self._period and frame[1] + half < deadline_s:
            try:
                nxt = self._read()
            except (StopIteration, SourceLost):
                break  # return what we have; the next grab meets the end or the loss
            self.frames_passed_over += 1
            frame = nxt
        img, t, t_dev, arrival = frame
        lost, self._lost_pending = self._lost_pending, 0
        self.frames_lost += lost
        exp = self.exposure_s if self.exposure_s is not None else 0.0
        return Grab(image=img, t_exposure_start_s=t, exposure_s=exp, t_host_s=arrival, frame_id=None,
                    t_device_s=t_dev, lost_before=lost)

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


class V4L2Source(OpenCVSource):
    def __init__(self, device: str, *, clock: Clock, **kw) -> None:
        if not str(device).startswith("/dev/video") and not str(device).isdigit():
            raise InputError(str(device), "not a V4L2 device", "give /dev/videoN")
        dev = int(device) if str(device).isdigit() else device
        if isinstance(dev, str) and not Path(dev).exists():
            have = ", ".join(list_v4l2_devices()) or "none on this machine"
            raise InputError(dev, "no such device", f"V4L2 devices here: {have}")
        super().__init__(dev, clock=clock, api=cv2.CAP_V4L2, kind="v4l2", **kw)


# --------------------------------------------------------------------------- what a camera offers


@dataclass(frozen=True)
class CameraMode:
    """One pixel format and frame size a camera offers, with its frame rates."""

    fourcc: str  # "MJPG", "YUYV" ...
    description: str  # the driver's words ("Motion-JPEG, compressed")
    size: str  # "1280x720", or "16x16-1920x1080" for a stepwise range
    rates: tuple[str, ...]  # "30", "15" ..., or "1-30" for a stepwise range

    def line(self) -> str:
        return f"{self.fourcc} {self.size} @ {', '.join(self.rates) or '?'} fps"


_FMT = re.compile(r"^\s*\[\d+\]:\s*'([^']*)'\s*(?:\((.*)\))?\s*$")
_SIZE_DISCRETE = re.compile(r"^\s*Size:\s*Discrete\s+(\d+x\d+)")
_SIZE_RANGE = re.compile(r"^\s*Size:\s*(?:Stepwise|Continuous)\s+(\d+x\d+)\s*-\s*(\d+x\d+)")
_RATE_DISCRETE = re.compile(r"^\s*Interval:\s*Discrete\s+[\d.]+s\s*\(([\d.]+)\s*fps\)")
_RATE_RANGE = re.compile(r"^\s*Interval:\s*(?:Stepwise|Continuous).*\(([\d.]+)-([\d.]+)\s*fps\)")


def _fps(text: str) -> str:
    return f"{float(text):g}"


def parse_list_formats_ext(text: str) -> list[CameraMode]:
    """``v4l2-ctl --list-formats-ext`` output -> the modes it lists."""
    modes: list[CameraMode] = []
    fourcc = desc = size = None
    rates: list[str] = []

    def flush() -> None:
        if fourcc is not None and size is not None:
            modes.append(CameraMode(fourcc, desc or "", size, tuple(rates)))

    for line in text.splitlines():
        if m := _FMT.match(line):
            flush()
            fourcc, desc, size, rates = m.group(1).strip(), (m.group(2) or "").strip(), None, []
        elif (m := _SIZE_DISCRETE.match(line)) or (m := _SIZE_RANGE.match(line)):
            flush()
            size, rates = "-".join(m.groups()), []
        elif m := _RATE_DISCRETE.match(line):
            rates.append(_fps(m.group(1)))
        elif m := _RATE_RANGE.match(line):
            rates.append(f"{_fps(m.group(1))}-{_fps(m.group(2))}")
    flush()
    return modes


def device_name(device: str, sys_root: str = "/sys/class/video4linux") -> str:
    """The driver's name for /dev/videoN (``/sys/class/video4linux/videoN/name``), or ''."""
    try:
        return (Path(sys_root) / Path(device).name / "name").read_text().strip()
    except OSError:
        return ""


_PROBE_FOURCCS = ("MJPG", "YUYV", "GREY", "Y16 ", "NV12", "BGR3")
_PROBE_SIZES = ((320, 240), (640, 480), (752, 480), (800, 600), (1280, 720), (1280, 1024), (1920, 1080), (2592, 1944))


def probe_modes(device: str, capture_factory: Callable[[str | int, int], Any] = cv2.VideoCapture) -> list[CameraMode]:
    """Without v4l2-ctl: ask the camera through OpenCV for each common format and size and keep
    what it accepts (the rate it reports at that size; V4L2 through OpenCV cannot list them all)."""
    cap = capture_factory(device, cv2.CAP_V4L2)
    if not cap.isOpened():
        return []
    seen: dict[tuple[str, str], set[str]] = {}
    try:
        for fcc in _PROBE_FOURCCS:
            for w, h in _PROBE_SIZES:
                cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*fcc))
                cap.set(cv2.CAP_PROP_FRAME_WIDTH, w)
                cap.set(cv2.CAP_PROP_FRAME_HEIGHT, h)
                cap.set(cv2.CAP_PROP_FPS, 240)  # the driver clamps to the fastest it has at this size
                code = int(cap.get(cv2.CAP_PROP_FOURCC))
                got = "".join(chr((code >> 8 * i) & 0xFF) for i in range(4)).strip() if code > 0 else ""
                gw, gh, fps = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)), cap.get(cv2.CAP_PROP_FPS)
                if got == fcc.strip() and (gw, gh) == (w, h):
                    seen.setdefault((got, f"{gw}x{gh}"), set()).add(f"{fps:g}" if fps and fps > 0 else "?")
    finally:
        cap.release()
    return [CameraMode(f, "", s, tuple(sorted(r, key=lambda x: -float(x) if x != "?" else 0))) for (f, s), r in seen.items()]


def camera_modes(device: str, *, which: Callable[[str], str | None] = shutil.which,
                 run: Callable[..., Any] = subprocess.run,
                 capture_factory: Callable[[str | int, int], Any] = cv2.VideoCapture) -> tuple[str, list[CameraMode]]:
    """(how it was found, the modes) for ``device``: ``v4l2-ctl --list-formats-ext`` when
    installed (every format, size and rate the driver lists), else probing through OpenCV."""
    tool = which("v4l2-ctl")
    if tool:
        try:
            out = run([tool, "-d", device, "--list-formats-ext"], capture_output=True, text=True, timeout=5)
            if out.returncode == 0:
                return "v4l2-ctl", parse_list_formats_ext(out.stdout)
        except (OSError, subprocess.TimeoutExpired):
            pass
    return "probed with OpenCV (install v4l-utils for the full list)", probe_modes(device, capture_factory)
