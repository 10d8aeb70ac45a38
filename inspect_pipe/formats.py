"""The file formats the product reads, each declared once with pydantic and versioned by its
``format`` field. The readers validate a parsed document against its model; the first problem
becomes one line naming the file and the field (``FILE: field 'a.b': problem``), and
``tools/gen_schemas.py`` writes each model's JSON Schema into ``docs/schema/``.

    sweep.json            SweepJson            inspect_pipe.sweep/1
    frames.jsonl (line)   FrameLine            (a line of a inspect_pipe.sweep/1 sweep)
    mosaic.json           MosaicJson           inspect_pipe.mosaic/1
    detect/defects.json   DetectionsJson       inspect_pipe.defects/1
    report/defects.json   RegisterJson         inspect_pipe.defect_register/1
    camera.yaml           CameraCalibration    OpenCV FileStorage or ROS camera_info, parsed values
    survey plan           inspect_pipe.ship.SurveyPlan  inspect_pipe.survey_plan/1

The models are as lenient as the readers always were with files written by earlier versions
(unknown keys are kept, optional blocks may be missing or null); what they refuse is what the
readers cannot use: a wrong type, a non-finite number, a matrix of the wrong shape.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from inspect_pipe.errors import InputError

__all__ = [
    "CameraCalibration", "DetectionsJson", "FrameLine", "MosaicJson", "RegisterJson", "SweepJson",
    "first_error", "validate",
]

# A finite number (never a bool or a numeric string), a non-negative integer (never a float or bool).
Num = Annotated[float, Field(strict=True, allow_inf_nan=False)]
PosNum = Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0)]
Index = Annotated[int, Field(strict=True, ge=0)]
PosInt = Annotated[int, Field(strict=True, gt=0)]
Vec2 = tuple[Num, Num]
Vec3 = tuple[Num, Num, Num]
Mat3 = tuple[Vec3, Vec3, Vec3]


class _Open(BaseModel):
    """Unknown keys are kept (files of other versions add fields the reader does not need)."""

    model_config = ConfigDict(extra="allow", frozen=True)


# =============================================================================== errors


def first_error(err: ValidationError, enum_words: dict[str, str] | None = None) -> str:
    """The first validation error as ``field 'a.b': problem`` (or the problem alone at the top)."""
    e = err.errors(include_url=False)[0]
    # unions and constrained types add their branch names to the path: keep keys and indices
    loc = ".".join(str(p) for p in e["loc"] if isinstance(p, int) or ("[" not in p and "-" not in p and p not in _BRANCHES))
    msg = e["msg"].removeprefix("Value error, ")
    kind = e["type"]
    if kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal", "finite_number"):
        msg = f"{_short(e.get('input'))}: {msg[0].lower()}{msg[1:]}"
    elif kind in ("float_type", "int_type", "string_type", "bool_type", "list_type", "tuple_type", "dict_type", "model_type",
                  "literal_error", "too_short", "too_long", "int_from_float", "model_attributes_type"):
        msg = f"{_short(e.get('input'))}: {msg[0].lower()}{msg[1:]}"
    if kind == "extra_forbidden":
        msg = "unknown key"
    elif kind == "missing":
        msg = "missing"
    elif kind == "enum" and enum_words:
        msg = f"{_short(e.get('input'))} is not one of {enum_words.get(loc.split('.')[-1], msg)}"
    return f"field '{loc}': {msg}" if loc else msg


_BRANCHES = {"float", "int", "str", "bool", "list", "dict", "tuple", "none", "function-after", "function-before", "function-plain"}


def _short(v: Any, n: int = 40) -> str:
    s = repr(v)
    return s if len(s) <= n else s[: n - 3] + "..."


M = TypeVar("M", bound=BaseModel)


def validate(model: type[M], doc: Any, where: str, hint: str = "") -> M:
    """``model`` validated from a parsed document, else one-line InputError naming ``where``."""
    try:
        return model.model_validate(doc)
    except ValidationError as err:
        raise InputError(where, first_error(err), hint) from None


# =============================================================================== sweep.json


class CameraJson(_Open):
    K: Mat3 = Field(description="3x3 intrinsic matrix of the undistorted pinhole camera")
    dist: list[Num] = Field(default_factory=list, description="OpenCV distortion coefficients k1 k2 p1 p2 [k3 ...]")
    width: PosInt
    height: PosInt
    name: str = "camera"
    calibration: dict[str, Any] | None = Field(None, description="source, sha256, rms_px of the calibration; null for a guessed camera")

    @field_validator("K")
    @classmethod
    def _focal_positive(cls, v):
        if not (v[0][0] > 0 and v[1][1] > 0):
            raise ValueError(f"focal lengths fx {v[0][0]:g}, fy {v[1][1]:g} px: both must be positive")
        return v


class CamToBodyJson(_Open):
    R: Mat3 | None = None
    t_m: Vec3 | None = None


class SweepJson(_Open):
    """``sweep.json``: written first (atomically) by capture and import."""

    format: Annotated[str, Field(pattern=r"^inspect_pipe\.sweep/1$")] = Field(description="inspect_pipe.sweep/1")
    camera: CameraJson
    cam_to_body: CamToBodyJson | None = None
    survey: dict[str, Any] | None = Field(None, description="vessel, hold, wall, frame_spacing_m, reference_frame (older sweeps)")
    survey_plan: dict[str, Any] | None = Field(None, description="the survey plan (inspect_pipe.survey_plan/1, validated by its own model)")
    software_version: str | None = None
    source: dict[str, Any] | None = Field(None, description="kind (sim, v4l2, folder, import ...), description")
    rate_hz: Num | None = None
    image_format: str | None = Field(None, description="png or jpg")
    created_utc: str | None = None
    time_base: str | None = Field(None, description="what t_s counts: host_monotonic_s or simulation_s")
    odometry_frame: Literal["hold", "takeoff"] | None = Field(None, description="what frame positions are in (hold: simulator; takeoff: an autopilot)")
    simulation: dict[str, Any] | None = Field(None, description="scenario, hold, wall, wall_texture (simulated sweeps)")

    @field_validator("simulation")
    @classmethod
    def _wall(cls, v):
        if v is not None and v.get("wall", "front") not in ("front", "back", "left", "right"):
            raise ValueError(f"wall {v.get('wall')!r} is not front, back, left or right")
        return v


# =============================================================================== frames.jsonl


class StateJson(_Open):
    position_m: Any = None  # older sweeps wrote partial vectors; the reader keeps a 3-vector only
    dist_front_m: Any = None
    height_m: Any = None


class FrameLine(_Open):
    """One line of ``frames.jsonl``, appended after the frame's image is on disk."""

    index: Index = Field(description="the frame's number in the capture (unique)")
    image: str = Field(min_length=1, description="image path relative to the sweep, e.g. images/000012.png")
    t_s: Num = Field(description="mid-exposure time on the sweep's time base")
    exposure_s: Num
    state: dict[str, Any] | None = Field(None, description="vehicle state at mid-exposure (position_m, dist_front_m, height_m, ...)")
    truth: dict[str, Any] | None = Field(None, description="simulator ground truth (simulated sweeps)")

    @field_validator("image")
    @classmethod
    def _inside(cls, v: str):
        from pathlib import PurePosixPath, PureWindowsPath

        if PurePosixPath(v).is_absolute() or PureWindowsPath(v).is_absolute() or ".." in PurePosixPath(v).parts or "\x00" in v:
            raise ValueError(f"{v!r} is not a file inside the sweep")
        return v


# =============================================================================== mosaic.json


class MosaicFrame(_Open):
    index: Index = Field(description="position in the input's frame list")
    H: Mat3 = Field(description="frame pixel -> mosaic pixel homography")
    group: Index = Field(0, description="the mosaic image the frame is in (0: the main one)")
    size_wh: tuple[PosInt, PosInt] | None = None
    file: str | None = None


class MosaicJson(_Open):
    """``mosaic.json``: the placed frames and the map to wall metres."""

    format: Literal["inspect_pipe.mosaic/1"]
    frames: list[MosaicFrame]
    unplaced: list[dict[str, Any]] = Field(default_factory=list)
    groups: list[dict[str, Any]] = Field(default_factory=list)
    frame_size_wh: tuple[PosInt, PosInt] | None = None
    wall_from_mosaic: Mat3 | None = Field(None, description="mosaic pixel -> wall (u, v) m; absent for a plain folder")
    m_per_px: PosNum | None = None
    wall_fit: dict[str, Any] | None = None


# =============================================================================== defects.json (detect)


class Region(_Open):
    class_: str = Field(alias="class")
    polygon_px: list[tuple[Num, Num]] = Field(default_factory=list)
    area_px: Annotated[int, Field(strict=True, ge=0)] | None = None
    confidence: Num | None = None
    bbox_xywh: tuple[Num, Num, Num, Num] | None = None


class DetectionsJson(_Open):
    """``defects.json`` of ``detect`` and of a run's detect step."""

    format: Literal["inspect_pipe.defects/1"]
    kinds: list[str]
    regions: list[Region]
    images: list[dict[str, Any]] = Field(default_factory=list)
    keyframes: list[Index] | None = None
    model: dict[str, Any] | None = None
    errors: list[Any] = Field(default_factory=list)


# =============================================================================== defects.json (register)


class RegisterEntry(_Open):
    id: str | Annotated[int, Field(strict=True)]
    class_: str = Field(alias="class")
    status: Literal["suggested", "confirmed", "rejected"]
    note: str | None = ""
    polygon_wall_m: list[Vec2]
    centroid_wall_m: Vec2
    bbox_wall_m: tuple[Num, Num, Num, Num] | None = None
    area_m2: Num
    length_m: Num | None = None
    confidence: Num = 0.0
    frames: list[Annotated[int, Field(strict=True)]] = Field(default_factory=list)
    keyframes_detected: list[Annotated[int, Field(strict=True)]] = Field(default_factory=list)
    keyframes_seen: list[Annotated[int, Field(strict=True)]] = Field(default_factory=list)
    polygon_mosaic_px: list[tuple[Annotated[int, Field(strict=True)], Annotated[int, Field(strict=True)]]] = Field(default_factory=list)
    bbox_mosaic_xywh: tuple[int, int, int, int] | None = None
    area_px: Annotated[int, Field(strict=True)] = 0
    frame_range: str | None = None
    height_above_tank_top_m: Num | None = None
    redetected: bool = True
    crop: str | None = None
    context: str | None = None
    crop_frame: int | None = None
    location: dict[str, Any] | None = None
    detected_class: str | None = None
    severity: dict[str, Any] | None = None
    beyond_survey: bool = False  # the detection goes on past the surveyed region's edge: area of the surveyed part


class RegisterJson(_Open):
    """``report/defects.json``: the defect register with the surveyor's decisions."""

    format: Literal["inspect_pipe.defect_register/1"]
    defects: list[RegisterEntry]


# =============================================================================== camera.yaml


class CameraCalibration(BaseModel):
    """The values of a camera.yaml (OpenCV FileStorage ``%YAML:1.0`` or ROS ``camera_info``),
    after parsing: the pinhole camera with plumb_bob distortion."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    image_width: PosInt
    image_height: PosInt
    camera_matrix: Mat3 = Field(description="[[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
    distortion_coefficients: Annotated[list[Num], Field(min_length=4, max_length=14)] = Field(
        description="k1 k2 p1 p2 [k3] (plumb_bob); more only when the rest are zero")
    camera_name: str = "camera"
    avg_reprojection_error: Annotated[float, Field(allow_inf_nan=False, ge=0)] | None = None

    @field_validator("camera_matrix")
    @classmethod
    def _pinhole(cls, K):
        if not (K[0][0] > 0 and K[1][1] > 0 and K[1][0] == 0 and K[2][0] == 0 and K[2][1] == 0 and K[2][2] == 1):
            raise ValueError("not [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
        return K

    @field_validator("distortion_coefficients")
    @classmethod
    def _plumb_bob(cls, d):
        if len(d) > 5 and any(d[5:]):
            raise ValueError(f"{len(d)} values with k4.. non-zero (the pinhole model with k1 k2 p1 p2 [k3], plumb_bob)")
        return d


FORMATS: dict[str, tuple[type[BaseModel], str]] = {
    "sweep.schema.json": (SweepJson, "inspect_pipe.sweep/1"),
    "sweep_frame.schema.json": (FrameLine, "inspect_pipe.sweep/1#frames.jsonl"),
    "mosaic.schema.json": (MosaicJson, "inspect_pipe.mosaic/1"),
    "defects.schema.json": (DetectionsJson, "inspect_pipe.defects/1"),
    "defect_register.schema.json": (RegisterJson, "inspect_pipe.defect_register/1"),
    "camera.schema.json": (CameraCalibration, "inspect_pipe.camera/1"),
}
