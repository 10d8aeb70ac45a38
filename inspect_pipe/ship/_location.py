"""Where a point of the hold is, as a surveyor writes it: ship frame number (side shells and tank
top), distance from the centreline with side (bulkheads and tank top), height above the tank top.
Pure functions of the survey plan; no I/O."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._plan import SurveyPlan
from ._walls import Wall, WallFrame, wall_frame

__all__ = ["Location", "ShipFrames", "locate", "plan_wall_frame", "hold_from_takeoff"]


@dataclass(frozen=True)
class ShipFrames:
    """Ship frame numbers along the hold's x axis: the aft bulkhead is ``aft_frame`` at x = 0;
    frames increase forward; spacing regular or piecewise (``[(from_frame, spacing_m), ...]``)."""

    aft_frame: float
    segments: tuple[tuple[float, float], ...]  # (from_frame, spacing_m), increasing from_frame

    @classmethod
    def from_plan(cls, plan: SurveyPlan) -> "ShipFrames":
        sp = plan.hold.frame_spacing_m
        if isinstance(sp, list):
            return cls(float(plan.hold.aft_bulkhead_frame), tuple((float(s.from_frame), float(s.spacing_m)) for s in sp))
        return cls(float(plan.hold.aft_bulkhead_frame), ((-math.inf, float(sp)),))

    def _spacing_at(self, frame: float) -> float:
        s = self.segments[0][1]
        for f0, sp in self.segments:
            if frame >= f0:
                s = sp
        return s

    def frame_at(self, x_m: float) -> float:
        """Ship frame number (decimal) at hold x: walks frame by frame with the spacing in force."""
        f, x = self.aft_frame, 0.0
        step = 1.0 if x_m >= 0 else -1.0
        for _ in range(100_000):
            nxt = math.floor(f + 1e-9) + 1 if step > 0 else math.ceil(f - 1e-9) - 1
            sp = self._spacing_at(min(f, nxt))
            dx = abs(nxt - f) * sp
            if abs(x_m - x) <= dx:
                return f + step * abs(x_m - x) / sp
            x += step * dx
            f = nxt
        raise ValueError(f"hold x {x_m} m is too far from the aft bulkhead")

    def x_of(self, frame: float) -> float:
        """Hold x of a ship frame number (inverse of frame_at)."""
        lo, hi = -2000.0, 2000.0
        for _ in range(80):
            mid = (lo + hi) / 2
            if self.frame_at(mid) < frame:
                lo = mid
            else:
                hi = mid
        return (lo + hi) / 2


@dataclass(frozen=True)
class Location:
    """``location`` of a register entry (SPEC.md)."""

    wall: str
    frame: float | None
    from_centreline_m: float | None
    side: str | None  # "port" | "starboard" | "CL"
    above_tank_top_m: float
    text: str
    stiffener: float | None = None

    def to_json(self) -> dict:
        return {
            "wall": self.wall,
            "frame": None if self.frame is None else round(self.frame, 2),
            "from_centreline_m": None if self.from_centreline_m is None else round(self.from_centreline_m, 2),
            "side": self.side,
            "above_tank_top_m": round(self.above_tank_top_m, 2),
            "stiffener": None if self.stiffener is None else round(self.stiffener, 1),
            "text": self.text,
        }


def plan_wall_frame(plan: SurveyPlan, *, length_m: float | None = None, width_m: float | None = None) -> WallFrame:
    """The plan's wall frame; the plan's hold dimensions win over the given (e.g. simulated) ones."""
    return wall_frame(plan.wall.name, plan.hold.length_m or length_m, plan.hold.width_m or width_m)


def hold_from_takeoff(plan: SurveyPlan | None, p_takeoff: np.ndarray) -> np.ndarray:
    """(N, 3) positions in the flight's take-off frame (origin at take-off, x along the take-off
    heading, y to its left, z up) -> hold coordinates, by the plan's ``takeoff`` tie."""
    p = np.asarray(p_takeoff, float).reshape(-1, 3)
    if plan is None or plan.takeoff is None:
        return p.copy()
    a = math.radians(plan.takeoff.heading_deg)
    R = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    return p @ R.T + np.asarray(plan.takeoff.position_m, float)


def _side(y: float) -> str:
    if abs(y) < 0.005:
        return "CL"
    return "port" if y > 0 else "starboard"


def _cl_text(y: float) -> str:
    s = _side(y)
    return "on CL" if s == "CL" else f"{abs(y):.2f} m to {s} of CL"


def _frame_text(frames: ShipFrames, frame: float) -> str:
    n = math.floor(frame + 1e-9)
    off_mm = round((frames.x_of(frame) - frames.x_of(n)) * 1000 / 10) * 10
    if off_mm >= round((frames.x_of(n + 1) - frames.x_of(n)) * 1000):
        n, off_mm = n + 1, 0
    return f"Fr. {n}" if off_mm == 0 else f"Fr. {n} + {off_mm:.0f} mm"


def locate(plan: SurveyPlan, frame: WallFrame, uv: tuple[float, float]) -> Location:
    """The location of wall point (u, v) of the plan's wall, in ship terms."""
    xyz = frame.to_hold(np.array([uv], float))[0]
    x, y, z = (float(c) for c in xyz)
    frames = ShipFrames.from_plan(plan)
    wall = plan.wall.name
    if wall is Wall.TANK_TOP:
        fr = frames.frame_at(x)
        return Location(wall.value, fr, abs(y), _side(y), 0.0, f"{_frame_text(frames, fr)}, {_cl_text(y)}")
    height = f"{z:.2f} m above tank top"
    if wall.is_side_shell:
        fr = frames.frame_at(x)
        return Location(wall.value, fr, None, None, z, f"{_frame_text(frames, fr)}, {height}")
    stiff = None
    text = _cl_text(y)
    sp = plan.wall.stiffener_spacing_m
    if sp:
        stiff = abs(y) / sp
        k = round(stiff)
        side = {"port": "P", "starboard": "S"}.get(_side(y), "")
        text += f" (stiffener {k}{side})" if k > 0 else " (at the CL stiffener)"
    return Location(wall.value, None, abs(y), _side(y), z, f"{text}, {height}", stiff)
