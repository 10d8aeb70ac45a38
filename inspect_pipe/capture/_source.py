"""The one protocol every camera implements, and what a grab returns."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from inspect_pipe.capture._geometry import CameraModel, Pose, R_BODY_CAM_FORWARD
from inspect_pipe.capture._state import VehicleState

__all__ = ["FrameSource", "Grab", "SourceInfo", "SourceLost", "default_cam_to_body"]


class SourceLost(Exception):
    """The camera went away mid-sweep (unplugged, end of a replay): the service stops cleanly."""


def default_cam_to_body() -> Pose:
    """Forward-looking camera 0.1 m ahead of the body centre, 3 cm below it."""
    return Pose(R_BODY_CAM_FORWARD.copy(), np.array([0.10, 0.0, -0.03]))


@dataclass(frozen=True)
class SourceInfo:
    kind: str  # "v4l2", "ids", "ueye", "sim", "replay"
    description: str  # device, model, serial, file...
    camera: CameraModel
    cam_to_body: Pose = field(default_factory=default_cam_to_body)
    triggered: bool = False  # software trigger: a grab exposes at the deadline
    paced: bool = False  # the source keeps its own timing (replay at recorded timing)
    extra: dict = field(default_factory=dict)  # written to sweep.json "source"


@dataclass(frozen=True)
class Grab:
    """One frame from a source. Times on the capture clock (s)."""

    image: np.ndarray  # HxW or HxWx3 uint8 (BGR)
    t_exposure_start_s: float  # host clock, start of exposure
    exposure_s: float
    t_host_s: float  # host clock when the frame arrived
    frame_id: int | None = None  # device frame counter (gaps are drops)
    t_device_s: float | None = None  # device timestamp, device clock
    gain: float | None = None
    state: VehicleState | None = None  # a source that knows the state (replay of a sweep, sim)
    truth: dict | None = None  # simulator ground truth for the frame (camera pose, homography)
    lost_before: int = 0  # frames the device says it lost before this one
    scheduled_mid_s: float | None = None  # a paced source's intended mid-exposure time (replay)

    @property
    def t_mid_s(self) -> float:
        return self.t_exposure_start_s + self.exposure_s / 2.0


@runtime_checkable
class FrameSource(Protocol):
    """A camera. ``open`` once, ``grab`` per deadline, ``close`` at the end (also after errors).

    ``grab(deadline_s)``: a triggered source starts the exposure at ``deadline_s``; a free-running
    one returns the newest frame; a paced one (replay) waits for its own next time and ignores it.
    Raises :class:`SourceLost` when the camera is gone, ``StopIteration`` at the end of a recording.
    """

    def open(self) -> SourceInfo: ...

    def grab(self, deadline_s: float) -> Grab: ...

    def close(self) -> None: ...
