"""USB/CSI cameras through OpenCV's V4L2 back-end (``cv2.CAP_V4L2``): pixel format, size, frame
rate, buffer count, manual exposure. V4L2 cameras free-run (no software trigger), so a grab takes
the first frame at or after the deadline; the driver's buffer timestamps reveal dropped frames.

The same class drives any OpenCV capture (``api=cv2.CAP_ANY`` and a video file): the tests use
that to exercise this code path where no ``/dev/video*`` exists.
"""

from __future__ import annotations

import glob
from pathlib import Path

import cv2

from inspect_pipe.capture._clock import Clock
from inspect_pipe.capture._geometry import CameraModel
from inspect_pipe.capture._source import Grab, SourceInfo, SourceLost, default_cam_to_body
from inspect_pipe.errors import InputError

__all__ = ["OpenCVSource", "V4L2Source", "list_v4l2_devices", "v4l2_backend_available"]


def list_v4l2_devices() -> list[str]:
    return sorted(glob.glob("/dev/video*"))


def v4l2_backend_available() -> bool:
    try:
        from cv2 import videoio_registry

        return any(b == cv2.CAP_V4L2 for b in videoio_registry.getCameraBackends())
    except Exception:  # older OpenCV without the registry
        return hasattr(cv2, "CAP_V4L2")


class OpenCVSource:
    """A ``cv2.VideoCapture`` as a :class:`FrameSource`.

    ``exposure_s`` None keeps the camera's auto exposure; a value sets manual exposure (V4L2
    ``exposure_absolute`` counts 100 us). ``fps`` is the camera's own rate (set it to the capture
    rate or a multiple). ``max_misses`` failed reads in a row mean the camera is gone."""

    def __init__(
        self,
        device: str | int,
        *,
        clock: Clock,
        api: int = cv2.CAP_ANY,
        width: int | None = None,
        height: int | None = None,
        fps: float | None = None,
        fourcc: str | None = None,
        buffers: int | None = 2,
        exposure_s: float | None = None,
        hfov_deg: float = 60.0,
        max_misses: int = 5,
        kind: str = "opencv",
    ) -> None:
        self.device, self.clock, self.api = device, clock, api
        self.width, self.height, self.fps, self.fourcc, self.buffers = width, height, fps, fourcc, buffers
        self.exposure_s, self.hfov_deg, self.max_misses, self.kind = exposure_s, hfov_deg, max_misses, kind
        self._cap: cv2.VideoCapture | None = None
        self._last_dev: float | None = None
        self._period: float | None = None
        self._count = 0

    def open(self) -> SourceInfo:
        cap = cv2.VideoCapture(self.device, self.api)
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
        if self.buffers:
            cap.set(cv2.CAP_PROP_BUFFERSIZE, self.buffers)
        if self.exposure_s is not None:
            cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1)  # V4L2: 1 = manual
            cap.set(cv2.CAP_PROP_EXPOSURE, self.exposure_s / 100e-6)
        self._cap = cap
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        fps = cap.get(cv2.CAP_PROP_FPS)
        self._period = 1.0 / fps if fps and fps > 0 else None
        cam = CameraModel.from_hfov(w, h, self.hfov_deg, name="uncalibrated")
        extra = {"device": str(self.device), "backend": cap.getBackendName(), "fps": fps, "buffers": self.buffers,
                 "fourcc": self.fourcc, "manual_exposure_s": self.exposure_s, "calibrated": False}
        return SourceInfo(self.kind, f"{self.kind} {self.device}", cam, default_cam_to_body(), triggered=False, extra=extra)

    def _read(self):
        assert self._cap is not None, "open() first"
        misses = 0
        while True:
            ok = self._cap.grab()
            if ok:
                ok, img = self._cap.retrieve()
                if ok and img is not None:
                    return img
            misses += 1
            if self.api != cv2.CAP_V4L2 and not isinstance(self.device, int) and Path(str(self.device)).is_file():
                raise StopIteration  # end of a file
            if misses >= self.max_misses:
                raise SourceLost(f"{self.device}: no frame after {misses} tries (unplugged?)")

    def grab(self, deadline_s: float) -> Grab:
        img = self._read()
        now = self.clock.now()
        assert self._cap is not None
        stamp_ms = self._cap.get(cv2.CAP_PROP_POS_MSEC)
        t_dev = stamp_ms / 1000.0 if stamp_ms and stamp_ms > 0 else None
        lost = 0
        if t_dev is not None and self._last_dev is not None and self._period:
            gap = t_dev - self._last_dev
            lost = max(0, round(gap / self._period) - 1)  # a gap of k periods: k-1 frames lost
        self._last_dev = t_dev if t_dev is not None else self._last_dev
        exp = self.exposure_s if self.exposure_s is not None else 0.0
        self._count += 1
        return Grab(image=img, t_exposure_start_s=now - exp, exposure_s=exp, t_host_s=now, frame_id=None,
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
