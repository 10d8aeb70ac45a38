"""What a sweep still lacks for a georeferenced report, and what follows (``doctor --sweep``, the
warnings of ``run``, the report's limitations). Pure: reads a ``Sweep`` (and an optional survey
plan given on the command line), returns findings."""

from __future__ import annotations

from dataclasses import dataclass, replace

__all__ = ["Finding", "sweep_readiness"]


@dataclass(frozen=True)
class Finding:
    what: str  # calibration | vehicle state | wall distance | survey plan | take-off tie | hold dimensions | time alignment
    ok: bool
    detail: str  # what the sweep has
    consequence: str = ""  # what follows for the report when not ok (what to provide)

    def line(self) -> str:
        return f"{self.what}: {self.detail}" + ("" if self.ok else f" -> {self.consequence}")


def sweep_readiness(sweep, plan=None) -> list[Finding]:
    """Findings for a sweep; ``plan`` (a SurveyPlan) overrides the one stored in it."""
    meta = sweep.meta
    plan = plan if plan is not None else meta.survey_plan
    out: list[Finding] = []
    cam = (meta.raw.get("camera") or {}) if isinstance(meta.raw, dict) else {}
    cal = cam.get("calibration") if isinstance(cam, dict) else None
    if cal:
        rms = cal.get("rms_px")
        out.append(Finding("calibration", True, f"{cal.get('source')}" + (f" (RMS {rms:.2f} px)" if isinstance(rms, (int, float)) else "")))
    else:
        note = cam.get("note") if isinstance(cam, dict) else None
        out.append(Finding("calibration", False, note or "no camera calibration recorded",
                           "lens distortion is not removed and metres per pixel rest on a guessed focal length: "
                           "calibrate (inspect-pipe calibrate) and give --camera camera.yaml"))
    n = len(sweep.frames)
    with_pos = sum(1 for f in sweep.frames if f.position_m is not None)
    with_dist = sum(1 for f in sweep.frames if f.dist_front_m is not None)
    if with_pos == 0:
        out.append(Finding("vehicle state", False, f"none of {n} frames carries a vehicle position",
                           "the mosaic cannot be placed on the wall: no metric positions in the report (only --m-per-px from "
                           "the mosaic's corner); capture with --vehicle mavlink:URL or import with the flight log"))
    else:
        out.append(Finding("vehicle state", True, f"{with_pos} of {n} frames carry a position ({meta.odometry_frame} frame)"))
    if with_dist == 0:
        out.append(Finding("wall distance", False, "no frame carries a distance to the wall ahead",
                           "no metric scale (metres per pixel) from the stand-off: a forward range sensor (DISTANCE_SENSOR "
                           "orientation 0) in the telemetry, or control points in the survey plan"))
    else:
        out.append(Finding("wall distance", True, f"{with_dist} of {n} frames carry a forward range"))
    sim = meta.simulation is not None
    if plan is None:
        out.append(Finding("survey plan", False, "no survey plan" + (" (a simulated hold)" if sim else ""),
                           "locations in wall metres only, no ship frame numbers or distances from the centreline, and the "
                           "survey record lacks vessel, IMO number and survey type: give --survey plan.yaml (docs/ship.md)"))
    else:
        out.append(Finding("survey plan", True, f"{plan.vessel.name}, {plan.compartment.name}, {plan.wall.name.title}"))
        if meta.odometry_frame == "takeoff" and plan.takeoff is None:
            out.append(Finding("take-off tie", False, "the plan has no takeoff point or heading",
                               "the flight's take-off frame is taken as the hold frame: positions along the wall are "
                               "off by wherever the vehicle took off; add takeoff: {position_m, heading_deg} to the plan"))
    # the wall frame as the given plan (not only the one stored in the sweep) makes it
    note = replace(meta, survey_plan=plan).wall_frame_note()
    if note:
        out.append(Finding("hold dimensions", False, note, "add the hold's length_m / width_m to the survey plan's hold"))
    ta = meta.raw.get("time_alignment") if isinstance(meta.raw, dict) else None
    if isinstance(ta, dict):
        conf = ta.get("confidence")
        ok = not isinstance(conf, (int, float)) or conf >= 0.5
        out.append(Finding("time alignment", ok, f"camera clock offset {ta.get('camera_clock_offset_s')} s by {ta.get('method')}"
                           + (f", confidence {conf:.2f}" if isinstance(conf, (int, float)) else ""),
                           "frames may carry the state of another moment: check the offset, give --time-offset"))
    return out
