"""``--source`` specs -> a :class:`FrameSource`, and the doctor's list of back-ends."""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass

from inspect_pipe.capture._clock import Clock, ManualClock
from inspect_pipe.errors import InputError

__all__ = ["Backend", "SOURCE_SPECS", "backends", "open_source"]

SOURCE_SPECS = "v4l2:/dev/videoN | ids[:SERIAL] | replay:PATH | sim:SCENARIO"


def open_source(spec: str, *, clock: Clock, rate_hz: float = 10.0, exposure_s: float | None = None, speed: float = 1.0,
                camera=None):
    """(source, clock to run it on, time base). A simulated source runs on its own simulated
    clock, faster than real time; every other source on ``clock``. ``camera`` (a calibrated
    :class:`CameraModel`): the simulated camera renders through it; other sources get it from
    :class:`CaptureConfig` ``camera``."""
    kind, _, arg = spec.partition(":")
    if kind == "v4l2":
        from inspect_pipe.capture.sources.v4l2 import V4L2Source

        if not arg:
            raise InputError(spec, "no device", "e.g. v4l2:/dev/video0")
        return V4L2Source(arg, clock=clock, rate_hz=rate_hz, exposure_s=exposure_s), clock, "host_monotonic_s"  # camera at its own rate, decimated
    if kind == "ids":
        from inspect_pipe.capture.sources.ids import open_ids

        kw = {"serial": arg or None, "fps": rate_hz}
        if exposure_s is not None:
            kw["exposure_s"] = exposure_s
        return open_ids(clock=clock, **kw), clock, "host_monotonic_s"
    if kind == "replay":
        from inspect_pipe.capture.sources.replay import ReplaySource

        if not arg:
            raise InputError(spec, "no path", "e.g. replay:out/sweep1 or replay:video.mp4")
        return ReplaySource(arg, clock=clock, rate_hz=rate_hz, speed=speed), clock, "host_monotonic_s"
    if kind == "sim":
        from inspect_pipe.capture.sources.sim import SimSource
        from inspect_pipe.flight import load_scenario

        if not arg:
            raise InputError(spec, "no scenario", "e.g. sim:scenarios/inspection_sweep_wall.yaml")
        sim_clock = ManualClock(0.0)
        return SimSource(load_scenario(arg), clock=sim_clock, camera=camera), sim_clock, "simulation_s"
    raise InputError(f"--source {spec}", "unknown source", f"one of {SOURCE_SPECS}")


@dataclass(frozen=True)
class Backend:
    name: str
    kind: str  # "camera" or "vehicle"
    usable: bool
    why: str
    spec: str


def _has(mod: str) -> bool:
    try:
        return importlib.util.find_spec(mod) is not None
    except (ImportError, ValueError):
        return False


def backends() -> list[Backend]:
    """Every camera and vehicle back-end, whether it is usable here, and why (not)."""
    out: list[Backend] = []
    from inspect_pipe.capture.sources.v4l2 import list_v4l2_devices, v4l2_backend_available

    devs = list_v4l2_devices()
    if not v4l2_backend_available():
        out.append(Backend("v4l2", "camera", False, "this OpenCV build has no V4L2 back-end", "v4l2:/dev/videoN"))
    elif not devs:
        out.append(Backend("v4l2", "camera", False, "OpenCV has V4L2, but no /dev/video* device exists (no camera attached, or a container without --device)", "v4l2:/dev/videoN"))
    else:
        out.append(Backend("v4l2", "camera", True, f"devices: {', '.join(devs)}", f"v4l2:{devs[0]}"))
    from inspect_pipe.capture.sources.ids import ids_status

    ok, why = ids_status()
    out.append(Backend("ids", "camera", ok, why, "ids[:SERIAL]"))
    import cv2

    try:
        from cv2 import videoio_registry

        video = [videoio_registry.getBackendName(b) for b in videoio_registry.getStreamBackends()]
    except Exception:
        video = []
    out.append(Backend("replay", "camera", True,
                       "sweeps and image folders always; video files via " + (", ".join(video) or "no OpenCV stream back-end"),
                       "replay:PATH"))
    sim_ok = _has("mujoco")
    out.append(Backend("sim", "camera", sim_ok, "MuJoCo simulator and wall renderer" if sim_ok else "mujoco not installed (pip install mujoco)", "sim:SCENARIO"))
    out.append(Backend("sim", "vehicle", sim_ok, "embedded MuJoCo cargo-hold simulator" if sim_ok else "mujoco not installed", "fly --scenario FILE"))
    mav = _has("pymavlink")
    out.append(Backend("mavlink", "vehicle", mav,
                       "pymavlink installed (MAVLink vehicle link)" if mav else "pymavlink not installed (pip install 'inspect-pipe[mavlink]')",
                       "fly --vehicle mavlink:URL"))
    ser = _has("serial")
    out.append(Backend("mavlink-serial", "vehicle", mav and ser,
                       "pymavlink and pyserial installed (an autopilot on a serial device)" if mav and ser
                       else "pyserial not installed (pip install 'inspect-pipe[serial]'); udp and tcp links need only pymavlink" if mav
                       else "pymavlink and pyserial not installed (pip install 'inspect-pipe[mavlink,serial]')",
                       "fly --vehicle mavlink:/dev/ttyACM0,57600"))
    del cv2
    return out
