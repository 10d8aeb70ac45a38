"""The survey plan (``inspect_pipe.survey_plan/1``): what is surveyed, in ship terms, written
before the flight as IACS Rec. 42 asks for remote inspection techniques.

Declared once as pydantic models (unknown keys refused, types and bounds checked); the loader turns
the first validation error into one line naming the file and the field. ``docs/ship.md`` documents
every field.
"""

from __future__ import annotations

import datetime as _dt
import math
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from inspect_pipe._yaml import load_yaml
from inspect_pipe.errors import InputError

from ._walls import Wall

__all__ = ["FORMAT", "SurveyPlan", "load_survey_plan", "parse_survey_plan", "imo_check_digit_ok"]

FORMAT = "inspect_pipe.survey_plan/1"


class _Strict(BaseModel):
    # no NaN or infinity in any number of the plan (a heading, a control point, a frame number)
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Vessel(_Strict):
    name: str = Field(min_length=1)
    imo: str | None = Field(None, description="IMO ship identification number, 7 digits")
    class_society: str | None = None
    flag: str | None = None

    @field_validator("imo", mode="before")
    @classmethod
    def _imo(cls, v: Any) -> Any:
        if v is None:
            return v
        s = str(v).strip().upper().removeprefix("IMO").strip()
        if not (len(s) == 7 and s.isdigit()):
            raise ValueError(f"{v!r} is not an IMO number (7 digits, e.g. '9074729')")
        return s


class Survey(_Strict):
    type: str = Field(min_length=1, description="e.g. special survey, intermediate survey, annual survey")
    date: _dt.date
    rit_provider: str | None = Field(None, description="remote inspection technique provider (IACS UR Z17)")
    pilot: str | None = None
    surveyor: str | None = Field(None, description="the attending surveyor")
    port: str | None = None


class Compartment(_Strict):
    name: str = Field(min_length=1)
    coating: str | None = None


class FrameSpacing(_Strict):
    """From ``from_frame`` forward, frames are ``spacing_m`` apart (until the next entry)."""

    from_frame: int
    spacing_m: Annotated[float, Field(gt=0.05, le=10.0)]


class Hold(_Strict):
    aft_bulkhead_frame: float = Field(description="ship frame number of the aft transverse bulkhead (hold x = 0)")
    frame_spacing_m: Annotated[float, Field(gt=0.05, le=10.0)] | list[FrameSpacing] = Field(
        description="metres between frames, or a table of {from_frame, spacing_m} for irregular spacing")
    tank_top_above_baseline_m: Annotated[float, Field(ge=0.0, le=40.0)] | None = None
    length_m: Annotated[float, Field(gt=0.5, le=400.0)] | None = None
    width_m: Annotated[float, Field(gt=0.5, le=80.0)] | None = None
    height_m: Annotated[float, Field(gt=0.5, le=60.0)] | None = None

    @field_validator("frame_spacing_m")
    @classmethod
    def _table(cls, v):
        if isinstance(v, list):
            if not v:
                raise ValueError("an empty frame spacing table")
            frames = [s.from_frame for s in v]
            if frames != sorted(frames) or len(set(frames)) != len(frames):
                raise ValueError("table entries must have increasing from_frame")
        return v


class WallSpec(_Strict):
    name: Wall
    stiffener_spacing_m: Annotated[float, Field(gt=0.05, le=10.0)] | None = Field(
        None, description="on a transverse bulkhead: spacing of the vertical stiffeners, counted from the centreline")


class Takeoff(_Strict):
    position_m: tuple[float, float, float] = Field(description="hold coordinates of the take-off point")
    heading_deg: float = Field(description="vehicle heading at take-off: 0 forward, 90 to port")

    @field_validator("position_m")
    @classmethod
    def _finite(cls, v):
        if not all(math.isfinite(c) for c in v):
            raise ValueError("not finite")
        return v


class ControlPoint(_Strict):
    """A pixel of a named image and the wall point (u, v) m it shows (like ODM's GCP file)."""

    image: str
    pixel: tuple[Annotated[float, Field(ge=0.0)], Annotated[float, Field(ge=0.0)]] = Field(
        description="(x, y) in the image's pixels, from its top-left corner")
    wall_m: tuple[float, float]


class Equipment(_Strict):
    drone: str | None = None
    camera: str | None = None
    lighting: str | None = None
    other: str | None = None


class SurveyPlan(_Strict):
    format: Literal["inspect_pipe.survey_plan/1"]
    vessel: Vessel
    survey: Survey
    compartment: Compartment
    hold: Hold
    wall: WallSpec
    takeoff: Takeoff | None = None
    control_points: list[ControlPoint] = Field(default_factory=list)
    equipment: Equipment | None = None
    limitations: list[str] = Field(default_factory=list)

    @field_validator("wall", mode="before")
    @classmethod
    def _wall(cls, v):
        return {"name": v} if isinstance(v, str) else v

    @model_validator(mode="after")
    def _takeoff_in_hold(self):
        """A take-off point outside the hold's stated size is a typing error (hold coordinates: x from the aft
        bulkhead, y from the centreline to port, z from the tank top; docs/ship.md)."""
        if self.takeoff is None:
            return self
        x, y, z = self.takeoff.position_m
        h, slack = self.hold, 0.5
        for name, value, lo, hi in (("x", x, 0.0, h.length_m), ("y", y, None if h.width_m is None else -h.width_m / 2, None if h.width_m is None else h.width_m / 2),
                                    ("z", z, 0.0, h.height_m)):
            if hi is not None and not (lo - slack <= value <= hi + slack):
                raise ValueError(f"takeoff.position_m {name} = {value:g} m lies outside the hold ({lo:g} to {hi:g} m)")
        return self

    # ----------------------------------------------------------------- derived, in ship terms

    def to_json(self) -> dict:
        return self.model_dump(mode="json", exclude_none=True)

    @property
    def warnings(self) -> list[str]:
        out = []
        if self.vessel.imo and not imo_check_digit_ok(self.vessel.imo):
            out.append(f"vessel.imo {self.vessel.imo}: the check digit does not match (check the number)")
        return out


def imo_check_digit_ok(imo: str) -> bool:
    """IMO numbers carry a check digit: sum of the first six digits times 7..2, last digit of it."""
    d = [int(c) for c in imo]
    return sum(a * b for a, b in zip(d[:6], range(7, 1, -1))) % 10 == d[6]


def _first_error(err: ValidationError) -> str:
    errors = err.errors()
    # a union (frame_spacing_m: a number or a table) reports every branch's error: the deepest is
    # the branch the input took (a table entry's negative spacing, not "should be a number")
    e = max(errors, key=lambda x: (len(x["loc"]), -errors.index(x)))
    # unions and constrained types add their branch names to the path: keep keys and indices
    loc = ".".join(str(p) for p in e["loc"] if isinstance(p, int) or ("[" not in p and "-" not in p))
    msg = e["msg"].removeprefix("Value error, ")
    if e["type"] in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        msg = f"{e.get('input')!r}: {msg[0].lower()}{msg[1:]}"
    if e["type"] == "extra_forbidden":
        msg = "unknown key"
    elif e["type"] == "missing":
        msg = "missing"
    elif e["type"] == "enum":
        msg = f"{e.get('input')!r} is not one of {', '.join(w.value for w in Wall)}"
    return f"field '{loc}': {msg}" if loc else msg


def parse_survey_plan(doc: Any, where: str) -> SurveyPlan:
    if not isinstance(doc, dict):
        raise InputError(where, "not a survey plan (a YAML mapping with format: inspect_pipe.survey_plan/1)")
    if doc.get("format") != FORMAT:
        raise InputError(where, f"field 'format': {doc.get('format')!r} is not {FORMAT}", "docs/ship.md describes the survey plan")
    try:
        return SurveyPlan.model_validate(doc)
    except ValidationError as err:
        raise InputError(where, _first_error(err), "docs/ship.md describes the survey plan") from None


def load_survey_plan(path: str | Path) -> SurveyPlan:
    """Read and validate a survey plan file; one-line InputError naming the file and field."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(str(p), "no such survey plan file") from None
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(str(p), f"cannot read the survey plan ({err.__class__.__name__})") from None
    doc = load_yaml(text, str(p), "docs/ship.md describes the survey plan")
    return parse_survey_plan(doc, str(p))
