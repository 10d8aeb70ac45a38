"""Capture: every camera behind one :class:`FrameSource` protocol, the 10 Hz capture service, and
the sweep directory format (``inspect_pipe.sweep/1``, see ``docs/sweep.md``) with its writer and
reader.

Reading a sweep (what the mosaicer uses)::

    from inspect_pipe.capture import read_sweep
    sweep = read_sweep("out/sweep1")
    K, dist = sweep.meta.camera.K, sweep.meta.camera.dist
    for f in sweep.frames:
        f.image_path, f.t_s, f.position_m, f.dist_front_m
        f.truth.H_wall_px_to_frame  # simulated sweeps: texture pixel -> undistorted frame pixel
"""

from inspect_pipe.capture._clock import Clock, ManualClock, MonotonicClock
from inspect_pipe.capture._geometry import CameraModel, Pose, wall_to_frame_homography
from inspect_pipe.capture._calibration import fit_camera, load_camera
from inspect_pipe.capture._open import SOURCE_SPECS, Backend, backends, open_source
from inspect_pipe.capture._scheduler import RateScheduler, Tick
from inspect_pipe.capture._service import CaptureConfig, CaptureResult, Progress, StopReason, run_capture
from inspect_pipe.capture._source import FrameSource, Grab, SourceInfo, SourceLost
from inspect_pipe.capture._state import StateFeed, TrajectoryFeed, TrueState, VehicleState
from inspect_pipe.capture._sweep import (
    FORMAT,
    FrameRecord,
    FrameTruth,
    Sweep,
    SweepMeta,
    SweepWriter,
    WallTextureInfo,
    read_sweep,
    verify_checksums,
)

__all__ = [
    "FORMAT",
    "SOURCE_SPECS",
    "Backend",
    "CameraModel",
    "CaptureConfig",
    "CaptureResult",
    "Clock",
    "FrameRecord",
    "FrameSource",
    "FrameTruth",
    "Grab",
    "ManualClock",
    "MonotonicClock",
    "Pose",
    "Progress",
    "RateScheduler",
    "SourceInfo",
    "SourceLost",
    "StateFeed",
    "StopReason",
    "Sweep",
    "SweepMeta",
    "SweepWriter",
    "Tick",
    "TrajectoryFeed",
    "TrueState",
    "VehicleState",
    "WallTextureInfo",
    "backends",
    "fit_camera",
    "load_camera",
    "open_source",
    "read_sweep",
    "run_capture",
    "verify_checksums",
    "wall_to_frame_homography",
]
