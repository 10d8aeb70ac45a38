"""Replay: a recorded sweep, a folder of images or a video file, played at its recorded timing on
the injected clock (a sweep: its frames' ``t_s``; a video: the container's frame times; a folder:
evenly at the capture rate, since plain files carry no timing)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from inspect_pipe._images import imread, truncation
from inspect_pipe.capture._clock import Clock
from inspect_pipe.capture._geometry import CameraModel
from inspect_pipe.capture._source import Grab, SourceInfo, default_cam_to_body
from inspect_pipe.capture._state import TrueState, VehicleState
from inspect_pipe.errors import InputError

__all__ = ["ReplaySource", "VIDEO_SUFFIXES", "IMAGE_SUFFIXES"]

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm", ".ppm"}
VIDEO_SUFFIXES = {".mp4", ".avi", ".mkv", ".mov", ".webm", ".mjpeg", ".mjpg", ".m4v"}


def _state_of(rec) -> VehicleState | None:
    if rec.position_m is None and rec.dist_front_m is None and rec.fsm is None:
        return None
    truth = None
    if rec.truth is not None:
        from inspect_pipe.capture._geometry import rotation_from_rpy

        truth = TrueState(rec.truth.position_m, rotation_from_rpy(*rec.truth.rpy_rad), rec.truth.velocity_m_s)
    st = rec.raw.get("state") or {}
    return VehicleState(
        t_s=float(st.get("t_s", rec.t_s)), position_m=rec.position_m, dist_front_m=rec.dist_front_m, height_m=rec.height_m,
        velocity_m_s=rec.velocity_m_s, est_mode=rec.est_mode, fsm=rec.fsm, inspection_mode=rec.inspection_mode, truth=truth,
    )


class ReplaySource:
    """:class:`FrameSource` over a recording. ``speed`` > 1 plays faster; ``rate_hz`` paces a
    plain image folder. The sweep's own problems (truncated manifest, missing image) are kept in
    ``problems`` after the readable frames are played."""

    def __init__(self, path: str | Path, *, clock: Clock, speed: float = 1.0, rate_hz: float = 10.0, hfov_deg: float = 60.0) -> None:
        self.path = Path(path)
        self.clock = clock
        self.speed = float(speed)
        self.rate_hz = float(rate_hz)
        self.hfov_deg = hfov_deg
        self.problems: tuple[InputError, ...] = ()
        self._i = 0
        self._t0_host: float | None = None
        self._t0_rec = 0.0
        self._cap = None
        self._items: list = []
        self.kind = ""

    # ------------------------------------------------------------------ open
    def open(self) -> SourceInfo:
        p = self.path
        if not p.exists():
            raise InputError(str(p), "not found", "replay a sweep directory, an image folder or a video file")
        if p.is_dir() and (p / "sweep.json").exists():
            return self._open_sweep()
        if p.is_dir():
            return self._open_folder()
        if p.suffix.lower() in VIDEO_SUFFIXES or p.is_file():
            return self._open_video()
        raise InputError(str(p), "not a sweep, image folder or video file")

    def _open_sweep(self) -> SourceInfo:
        from inspect_pipe.capture._sweep import read_sweep

        sw = read_sweep(self.path)
        self.problems = sw.problems
        if not sw.frames:
            raise InputError(str(self.path / "frames.jsonl"), "no readable frames", "nothing to replay")
        self.kind = "sweep"
        self._items = sorted(sw.frames, key=lambda r: r.t_s)
        self._t0_rec = self._items[0].t_s
        extra = {"replay_of": str(sw.path), "original_source": sw.meta.source, "original_time_base": sw.meta.time_base}
        self._sweep_meta = sw.meta
        return SourceInfo("replay", f"replay of sweep {sw.path.name}", sw.meta.camera, sw.meta.cam_to_body, paced=True, extra=extra)

    def _open_folder(self) -> SourceInfo:
        files = sorted(f for f in self.path.iterdir() if f.suffix.lower() in IMAGE_SUFFIXES and f.is_file())
        if not files:
            raise InputError(str(self.path), "no images found", f"expected files ending in {', '.join(sorted(IMAGE_SUFFIXES))}")
        if why := truncation(files[0]):
            raise InputError(str(files[0]), why)
        first = imread(str(files[0]), cv2.IMREAD_COLOR)
        if first is None:
            raise InputError(str(files[0]), "unreadable image")
        self.kind = "folder"
        self._items = files
        h, w = first.shape[:2]
        cam = CameraModel.from_hfov(w, h, self.hfov_deg, name="uncalibrated")
        return SourceInfo("replay", f"replay of image folder {self.path.name}", cam, default_cam_to_body(), paced=True,
                          extra={"replay_of": str(self.path.resolve()), "calibrated": False})

    def _open_video(self) -> SourceInfo:
        cap = cv2.VideoCapture(str(self.path))
        if not cap.isOpened():
            raise InputError(str(self.path), "cannot open the video file", "a video OpenCV can decode (mp4, avi, mkv...)")
        self._cap = cap
        self.kind = "video"
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        fps = cap.get(cv2.CAP_PROP_FPS) or self.rate_hz
        self._video_fps = fps if fps > 0 else self.rate_hz
        cam = CameraModel.from_hfov(w, h, self.hfov_deg, name="uncalibrated")
        return SourceInfo("replay", f"replay of video {self.path.name}", cam, default_cam_to_body(), paced=True,
                          extra={"replay_of": str(self.path.resolve()), "calibrated": False, "video_fps": self._video_fps})

    # ------------------------------------------------------------------ frames
    def _next(self) -> tuple[np.ndarray, float, float, object]:
        """(image, recorded mid-exposure time s, exposure s, record or None)"""
        if self.kind == "video":
            assert self._cap is not None
            ok, img = self._cap.read()
            if not ok or img is None:
                raise StopIteration
            pos_ms = self._cap.get(cv2.CAP_PROP_POS_MSEC)  # after read: the time of the frame just read
            t = pos_ms / 1000.0 if pos_ms and pos_ms > 0 else self._i / self._video_fps
            if self._i > 0 and t <= self._last_t:
                t = self._i / self._video_fps  # containers without usable stamps
            self._last_t = t
            return img, t, 0.0, None
        if self._i >= len(self._items):
            raise StopIteration
        item = self._items[self._i]
        if why := truncation(item.image_path if self.kind == "sweep" else item):
            raise InputError(str(item.image_path if self.kind == "sweep" else item), why)
        if self.kind == "sweep":
            img = imread(str(item.image_path), cv2.IMREAD_UNCHANGED)
            if img is None:
                raise InputError(str(item.image_path), f"frame {item.index}: unreadable image")
            return img, item.t_s, item.exposure_s, item
        img = imread(str(item), cv2.IMREAD_COLOR)
        if img is None:
            raise InputError(str(item), "unreadable image")
        return img, self._i / self.rate_hz, 0.0, None

    def grab(self, deadline_s: float) -> Grab:
        img, t_rec, exp, rec = self._next()
        if self._t0_host is None:
            self._t0_host = self.clock.now()
            self._t0_rec = t_rec
        target = self._t0_host + (t_rec - self._t0_rec) / self.speed
        self.clock.sleep_until(target)
        now = self.clock.now()
        self._i += 1
        state = _state_of(rec) if rec is not None else None
        truth = None
        if rec is not None and isinstance(rec.raw.get("truth"), dict):
            truth = dict(rec.raw["truth"])
        return Grab(
            image=img, t_exposure_start_s=now - exp / 2, exposure_s=exp, t_host_s=now,
            frame_id=getattr(rec, "frame_id", None), t_device_s=None, gain=getattr(rec, "gain", None),
            state=state, truth=truth, scheduled_mid_s=target,
        )

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None
