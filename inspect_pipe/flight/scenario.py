"""Scenario files (``inspect_pipe.scenario/1``, see SPEC.md): typed, frozen, validated on load.

The file's structure is declared once, with pydantic (``ScenarioDoc``); its JSON Schema is
generated into docs/schema/. Every problem is an :class:`InputError` naming the file, the field
and what is expected (read from the schema: type, range, allowed values).
"""

from __future__ import annotations

import enum
import math
import reprlib
import types
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, Union, get_args, get_origin

import cv2
from pydantic import BaseModel, ConfigDict, Field, ValidationError, ValidationInfo, field_validator, model_validator
from pydantic.fields import FieldInfo

from inspect_pipe._images import truncation
from inspect_pipe._yaml import load_yaml
from inspect_pipe.errors import InputError
from inspect_pipe.flight_stack.messages import Button, SpeedCommand

__all__ = [
    "Battery",
    "Box",
    "ButtonEvent",
    "Camera",
    "Fault",
    "FaultKind",
    "Hold",
    "Scenario",
    "ScenarioDoc",
    "SensorName",
    "StickEvent",
    "VEHICLE_RADIUS_M",
    "VehicleSpec",
    "WallTexture",
    "World",
    "load_scenario",
    "parse_scenario",
]

FORMAT = "inspect_pipe.scenario/1"
VEHICLE_RADIUS_M = 0.35  # the collision sphere of the log's ``collided``


class SensorName(str, enum.Enum):
    BOTTOM_FLOW = "bottom_flow"  # bottom PX4Flow: flow and its sonar
    FRONT_FLOW = "front_flow"  # front PX4Flow: flow and its sonar
    BOTTOM_TOF = "bottom_tof"  # TeraRanger One
    LEFT_SONAR = "left_sonar"
    RIGHT_SONAR = "right_sonar"


class FaultKind(str, enum.Enum):
    SENSOR_DROPOUT = "sensor_dropout"  # blackout: the sensor delivers nothing
    LINK_LOSS = "link_loss"
    PACKET_LOSS = "packet_loss"  # each sample of the sensor lost with probability ``rate``
    STUCK_READING = "stuck_reading"  # the sensor repeats its last value, freshly stamped
    SPURIOUS_MAX_RANGE = "spurious_max_range"  # range sensor: max-range echo at grazing incidence, prob. ``rate``
    RANGE_LOSS = "range_loss"  # every range sensor silent (PX4Flow units lose their metric scale)
    FLOW_QUALITY_ZERO = "flow_quality_zero"  # PX4Flow quality 0 (texture-less surface); its sonar still works
    BATTERY_SAG = "battery_sag"  # ``rate``: fraction of thrust lost, and of the charge reading
    GUST = "gust"  # wind of ``wind_m_s`` (world frame) acting through the rotor drag
    WEAK_MOTOR = "weak_motor"  # ``rate``: share of the front motor's thrust lost (the firmware does not know)
    VIBRATION = "vibration"  # ``rate``: rotor vibration, rate x 3 m/s^2 added to the IMU (std of its 50 Hz mean)
    LOW_TEXTURE = "low_texture"  # PX4Flow ``sensor`` sees a surface with ``rate`` of its texture and light lost


# Which fields a fault kind needs: sensor, rate (0..1), wind vector.
_NEEDS_SENSOR = {FaultKind.SENSOR_DROPOUT, FaultKind.PACKET_LOSS, FaultKind.STUCK_READING,
                 FaultKind.SPURIOUS_MAX_RANGE, FaultKind.FLOW_QUALITY_ZERO, FaultKind.LOW_TEXTURE}
_NEEDS_RATE = {FaultKind.PACKET_LOSS, FaultKind.SPURIOUS_MAX_RANGE, FaultKind.BATTERY_SAG,
               FaultKind.WEAK_MOTOR, FaultKind.VIBRATION, FaultKind.LOW_TEXTURE}


@dataclass(frozen=True)
class Hold:
    length_m: float
    width_m: float
    height_m: float


@dataclass(frozen=True)
class Box:
    """Axis-aligned obstacle in the world frame (m)."""

    min_m: tuple[float, float, float]
    max_m: tuple[float, float, float]


@dataclass(frozen=True)
class WallTexture:
    image: Path
    m_per_px: float
    origin_uv: tuple[float, float]
    defects_mask: Path | None = None


WALLS = ("front", "back", "left", "right")  # the walls a scenario can texture (SPEC.md wall frames)
WallName = Literal["front", "back", "left", "right"]


@dataclass(frozen=True)
class World:
    hold: Hold
    boxes: tuple[Box, ...] = ()
    wall_textures: tuple[tuple[str, WallTexture], ...] = ()  # (wall, texture), wall in WALLS

    def texture(self, wall: str) -> WallTexture | None:
        return dict(self.wall_textures).get(wall)

    @property
    def front_wall_texture(self) -> WallTexture | None:
        return self.texture("front")


@dataclass(frozen=True)
class Battery:
    start_percent: float = 100.0
    drain_percent_per_min: float = 4.0


@dataclass(frozen=True)
class VehicleSpec:
    start_position_m: tuple[float, float, float]
    start_yaw_rad: float = 0.0
    battery: Battery = Battery()
    max_height_m: float | None = None  # limit_max_height; default from the hold
    mass_scale: float = 1.0  # true mass / nominal (model error the stack does not know)
    thrust_scale: float = 1.0  # true maximum thrust / nominal


@dataclass(frozen=True)
class Camera:
    fps: float = 10.0
    width: int = 752
    height: int = 480
    hfov_deg: float = 60.0


@dataclass(frozen=True)
class StickEvent:
    t_s: float
    stick: SpeedCommand


@dataclass(frozen=True)
class ButtonEvent:
    t_s: float
    button: Button


@dataclass(frozen=True)
class Fault:
    t_s: float
    duration_s: float
    kind: FaultKind
    sensor: SensorName | None = None
    rate: float | None = None  # packet_loss, spurious_max_range: probability; battery_sag, weak_motor, low_texture: fraction; vibration: level
    wind_m_s: tuple[float, float, float] | None = None  # gust

    def active(self, t: float) -> bool:
        return self.t_s <= t < self.t_s + self.duration_s


@dataclass(frozen=True)
class Scenario:
    name: str
    duration_s: float
    seed: int
    world: World
    vehicle: VehicleSpec
    camera: Camera = Camera()
    operator: tuple[StickEvent | ButtonEvent, ...] = ()
    faults: tuple[Fault, ...] = ()
    source: Path | None = None

    @property
    def max_height_m(self) -> float:
        if self.vehicle.max_height_m is not None:
            return self.vehicle.max_height_m
        return max(1.0, min(self.world.hold.height_m - 1.0, 12.0))


# --------------------------------------------------------------------------- the document (pydantic)
#
# The file's structure, declared once: types, ranges, which fields a fault kind takes. Checks that
# need more than one field of the file (a box inside the hold, the start spot free, an event
# inside the flight) follow in ``_build``. ``tools/gen_schemas.py`` writes the JSON Schema of
# ``ScenarioDoc`` to docs/schema/scenario.schema.json.

Num = Annotated[float, Field(strict=True, allow_inf_nan=False)]
Vec2 = tuple[Num, Num]
Vec3 = tuple[Num, Num, Num]


def _num(lo: float | None = None, hi: float | None = None, *, gt: float | None = None, default: Any = ..., doc: str = ""):
    return Field(default, strict=True, allow_inf_nan=False, ge=lo, le=hi, gt=gt, description=doc or None)


class _Doc(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class HoldDoc(_Doc):
    length_m: float = _num(2.0, 500.0, doc="along the ship (x, from the aft bulkhead)")
    width_m: float = _num(2.0, 500.0, doc="across (y, centred)")
    height_m: float = _num(2.0, 100.0, doc="tank top to hatch (z)")


class BoxDoc(_Doc):
    min: Vec3 = Field(description="lowest corner [x, y, z] in the hold frame (m)")
    max: Vec3 = Field(description="highest corner [x, y, z] (m)")

    @model_validator(mode="after")
    def _ordered(self) -> BoxDoc:
        if any(hi <= lo for lo, hi in zip(self.min, self.max)):
            raise ValueError(f"min {list(self.min)} not below max {list(self.max)} (expected min < max on every axis)")
        return self


class TextureDoc(_Doc):
    image: str = Field(min_length=1, description="image file, relative to the scenario file")
    m_per_px: float = _num(gt=0.0)
    origin_uv: Vec2 | None = Field(None, description="wall (u, v) of the image's top-left pixel (m); default [0, hold height]")
    defects_mask: str | None = Field(None, description="label image of the defects (optional)")


class WorldDoc(_Doc):
    hold: HoldDoc
    boxes: list[BoxDoc] | None = None
    front_wall_texture: TextureDoc | None = Field(None, description="the same as wall_textures.front (older files)")
    wall_textures: dict[WallName, TextureDoc] | None = None


class StartDoc(_Doc):
    position: Vec3 = Field(description="[x, y, z] in the hold frame (m); the vehicle starts landed")
    yaw: float = _num(-2 * math.pi, 2 * math.pi, default=0.0)


class BatteryDoc(_Doc):
    start_percent: float = _num(0.0, 100.0, default=100.0)
    drain_percent_per_min: float = _num(0.0, 100.0, default=4.0)


class VehicleDoc(_Doc):
    start: StartDoc
    battery: BatteryDoc | None = None
    max_height_m: float | None = _num(1.0, 14.0, default=None, doc="limit_max_height (also at most the hold's height)")
    mass_scale: float = _num(0.5, 1.5, default=1.0, doc="true mass / nominal (model error the stack does not know)")
    thrust_scale: float = _num(0.5, 1.5, default=1.0, doc="true maximum thrust / nominal")


#: Widest field of view, corner to corner, the simulated camera renders (``CameraDoc``).
MAX_DIAGONAL_FOV_DEG = 140.0


class CameraDoc(_Doc):
    fps: float = _num(gt=0.0, hi=200.0, default=10.0)
    # The simulated camera renders up to 8192 px a side (OpenCV's remap needs under 32767; a frame
    # that size is 200 MB) and at most MAX_DIAGONAL_FOV_DEG corner to corner: the renderer inverts
    # its lens model (a pinhole with mild barrel distortion) by fixed-point iteration, which does
    # not converge for rays much further out (measured: it did at 146 deg, not at 150).
    width: int = Field(752, strict=True, ge=16, le=8192)
    height: int = Field(480, strict=True, ge=16, le=8192)
    hfov_deg: float = _num(5.0, 150.0, default=60.0)

    @model_validator(mode="after")
    def _diagonal(self) -> CameraDoc:
        diag = 2.0 * math.degrees(math.atan(math.tan(math.radians(self.hfov_deg) / 2.0) * math.hypot(self.width, self.height) / self.width))
        if diag > MAX_DIAGONAL_FOV_DEG:
            raise ValueError(
                f"hfov_deg {self.hfov_deg:g} on a {self.width} x {self.height} frame sees {diag:.0f} deg corner to corner "
                f"(expected at most {MAX_DIAGONAL_FOV_DEG:.0f}: a smaller hfov_deg or a frame less tall)")
        return self


class StickDoc(_Doc):
    vx: float = _num(-3.0, 3.0, default=0.0)
    vy: float = _num(-3.0, 3.0, default=0.0)
    vz: float = _num(-3.0, 3.0, default=0.0)
    yaw_rate: float = _num(-3.0, 3.0, default=0.0)


class OperatorDoc(_Doc):
    t: float = _num(0.0, doc="seconds from the start (at most duration_s)")
    stick: StickDoc | None = None
    button: Button | None = None

    @model_validator(mode="after")
    def _one(self) -> OperatorDoc:
        if (self.stick is None) == (self.button is None):
            raise ValueError("needs exactly one of 'stick' or 'button' (expected {t, stick: {vx, vy, vz, yaw_rate}} or {t, button})")
        return self


class FaultDoc(_Doc):
    t: float = _num(0.0)
    duration_s: float = _num(gt=0.0)
    fault: FaultKind
    sensor: SensorName | None = Field(None, validate_default=True, description="for " + ", ".join(sorted(k.value for k in _NEEDS_SENSOR)))
    rate: float | None = Field(None, strict=True, allow_inf_nan=False, ge=0.0, le=1.0, validate_default=True,
                               description="probability or fraction, for " + ", ".join(sorted(k.value for k in _NEEDS_RATE)))
    wind_m_s: Vec3 | None = Field(None, validate_default=True, description="gust: wind [wx, wy, wz] in the world frame, at most 10 m/s")

    @field_validator("sensor", "rate", "wind_m_s", mode="after")
    @classmethod
    def _fields_of_kind(cls, value: Any, info: ValidationInfo) -> Any:
        """Which fields a fault kind takes: a sensor, a rate, a wind vector."""
        kind, name = info.data.get("fault"), info.field_name
        if kind is None:  # the kind itself is invalid: that is the error reported
            return value
        needed, expected = {
            "sensor": (kind in _NEEDS_SENSOR, "one of " + ", ".join(s.value for s in SensorName)),
            "rate": (kind in _NEEDS_RATE, "a number in [0, 1]"),
            "wind_m_s": (kind is FaultKind.GUST, "[wx, wy, wz] in m/s"),
        }[name]
        if needed and value is None:
            raise ValueError(f"missing: {kind.value} needs it (expected {expected})")
        if value is not None and not needed:
            raise ValueError(f"{kind.value} takes no {name} (expected no '{name}' field)")
        if name == "sensor" and value is not None:
            if kind in (FaultKind.FLOW_QUALITY_ZERO, FaultKind.LOW_TEXTURE) and value not in (SensorName.BOTTOM_FLOW, SensorName.FRONT_FLOW):
                raise ValueError(f"{value.value} has no flow (expected bottom_flow or front_flow)")
            if kind is FaultKind.SPURIOUS_MAX_RANGE and value is SensorName.BOTTOM_TOF:
                raise ValueError("the TeraRanger is not a sonar (expected bottom_flow, front_flow, left_sonar or right_sonar)")
        if name == "wind_m_s" and value is not None and math.hypot(*value) > 10.0:
            raise ValueError(f"{list(value)} is stronger than 10 m/s (expected a gust of at most 10 m/s)")
        return value


class ScenarioDoc(_Doc):
    """A simulated flight: the hold, the vehicle, the surveyor's stick and buttons, the faults."""

    format: Literal["inspect_pipe.scenario/1"]
    name: str = Field(min_length=1, max_length=200, pattern=r"^[^\x00-\x1f\x7f]+$")  # printed: no control characters
    duration_s: float = _num(hi=24 * 3600.0, gt=0.0)
    seed: int = Field(0, strict=True, ge=0)
    world: WorldDoc
    vehicle: VehicleDoc
    camera: CameraDoc | None = None
    operator: list[OperatorDoc] | None = None
    faults: list[FaultDoc] | None = None


# --------------------------------------------------------------------------- errors from the schema


def _schema_error(err: ValidationError) -> tuple[str, str, str]:
    """The first problem as (field, problem, expected), the expectation read from the schema."""
    e = err.errors(include_url=False)[0]
    kind, value = e["type"], e.get("input")
    loc = list(e["loc"])
    # pydantic's location names the union branches it tried ("float", "function-after[...]"); an
    # unknown key is the file's own text, whatever it reads, and is kept
    last = loc[-1:] if kind == "extra_forbidden" else []
    raw = [p for p in (loc[:-1] if last else loc) if isinstance(p, int) or not _is_branch(p)] + last
    on_key = "[key]" in e["loc"]
    field = _field_name(raw)
    if kind == "value_error":
        return field, str(e["msg"]).removeprefix("Value error, "), ""
    if kind == "missing" and raw and isinstance(raw[-1], int):  # a fixed-length list one short
        field = _field_name(raw[:-1])
        return field, "has too few numbers", _expected(*_schema_at(raw[:-1]))
    if kind == "invalid_key":
        return _field_name(raw[:-1]), f"key {_short(value)} is not a name", "field names as text"
    if kind == "extra_forbidden":
        parent, _ = _schema_at(raw[:-1])
        names = sorted(parent.model_fields) if isinstance(parent, type) and issubclass(parent, BaseModel) else []
        return field, "unknown field", "one of " + ", ".join(names) if names else ""
    if kind == "missing":
        return field, "missing", "it to be present"
    if kind == "string_pattern_mismatch":  # the only pattern: a name without control characters
        return field, f"is {_short(value)}", "printable text without control characters"
    tp, info = _schema_at(raw)
    if on_key:
        tp, info = get_args(_schema_at(raw[:-1])[0])[0], None
        return field, f"{_short(raw[-1] if raw else value)} is not a wall", _expected(tp, None)
    if kind in ("enum", "literal_error"):
        return field, f"unknown value {_short(value)}", _expected(tp, info)
    return field, f"is {_short(value)}", _expected(tp, info)


def _is_branch(part: str) -> bool:
    return "[" in part or part.startswith("function-") or part in {"float", "int", "str", "bool", "list", "dict", "tuple", "none"}


def _field_name(loc: list) -> str:
    out = ""
    for p in loc:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out


def _unwrap(tp: Any) -> Any:
    while True:
        if get_origin(tp) is Annotated:
            tp = get_args(tp)[0]
        elif get_origin(tp) in (Union, types.UnionType):
            args = [a for a in get_args(tp) if a is not type(None)]
            tp = args[0] if len(args) == 1 else tp
            if len(args) != 1:
                return tp
        else:
            return tp


def _schema_at(loc: list) -> tuple[Any, FieldInfo | None]:
    """The declared type (and field) at ``loc`` of ScenarioDoc."""
    tp: Any = ScenarioDoc
    info: FieldInfo | None = None
    for p in loc:
        tp = _unwrap(tp)
        origin = get_origin(tp)
        if isinstance(tp, type) and issubclass(tp, BaseModel) and p in tp.model_fields:
            info = tp.model_fields[p]
            tp = info.annotation
        elif origin is list:
            tp, info = get_args(tp)[0], None
        elif origin is dict:
            tp, info = get_args(tp)[1], None
        elif origin is tuple and isinstance(p, int):
            args = get_args(tp)
            tp, info = args[min(p, len(args) - 1)], None
        else:
            return None, None
    return _unwrap(tp), info


def _expected(tp: Any, info: FieldInfo | None) -> str:
    origin = get_origin(tp)
    if tp is float or tp is int:
        lo = hi = None
        lo_op = hi_op = ""
        for m in (info.metadata if info else []):
            for name, op in (("ge", ">="), ("gt", ">")):
                if getattr(m, name, None) is not None:
                    lo, lo_op = getattr(m, name), op
            for name, op in (("le", "<="), ("lt", "<")):
                if getattr(m, name, None) is not None:
                    hi, hi_op = getattr(m, name), op
        what = "a number" if tp is float else "an integer"
        if lo is not None and hi is not None:
            return f"{what} in {'[' if lo_op == '>=' else '('}{lo:g}, {hi:g}{']' if hi_op == '<=' else ')'}"
        if lo is not None:
            return f"{what} {lo_op} {lo:g}"
        if hi is not None:
            return f"{what} {hi_op} {hi:g}"
        return what
    if tp is str:
        return "a non-empty string"
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return "one of " + ", ".join(str(e.value) for e in tp)
    if origin is Literal:
        args = get_args(tp)
        return repr(args[0]) if len(args) == 1 else "one of " + ", ".join(str(a) for a in args)
    if origin is tuple:
        return f"a list of {len(get_args(tp))} numbers"
    if origin is list:
        return "a list"
    if origin is dict:
        return "a mapping {" + "|".join(get_args(_unwrap(get_args(tp)[0]))) + ": ...}"
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return "a mapping with " + ", ".join(tp.model_fields)
    return "a valid value"


def _short(v: Any, n: int = 40) -> str:
    s = reprlib.repr(v)  # bounded: a value from the file may be a list of millions
    return s if len(s) <= n else s[: n - 3] + "..."


# --------------------------------------------------------------------------- reading


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file."""
    path = Path(path)
    if not path.exists() or path.is_dir():  # a pipe (``<(...)``, /dev/stdin) is read as a file
        raise InputError(str(path), "scenario file not found" if not path.exists() else "is a directory, not a scenario file",
                         "give the path of a .yaml scenario")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError(str(path), "not UTF-8 text", "a YAML or JSON scenario") from None
    except OSError as err:
        raise InputError(str(path), f"cannot read it ({err.strerror or type(err).__name__})", "a readable YAML or JSON scenario") from None
    doc = load_yaml(text, str(path), "a YAML or JSON scenario")
    # files it names are relative to its folder; a pipe's (/dev/fd) is no folder: the current one
    return parse_scenario(doc, source=str(path), base=path.parent if path.is_file() else Path.cwd())


def parse_scenario(doc: Any, *, source: str = "<scenario>", base: Path = Path(".")) -> Scenario:
    """A scenario from a parsed document: the schema (``ScenarioDoc``) first, then the checks
    that relate fields (boxes and start inside the hold, events inside the flight, files found)."""
    if not isinstance(doc, dict):
        raise InputError(source, "is empty" if doc is None else f"is {type(doc).__name__}",
                         "expected a mapping with " + ", ".join(ScenarioDoc.model_fields))
    try:
        d = ScenarioDoc.model_validate(doc)
    except ValidationError as err:
        field, problem, expected = _schema_error(err)
        raise InputError(source, f"field '{field}': {problem}" if field else problem,
                         f"expected {expected}" if expected else "") from None
    return _build(d, _Checks(source, base))


class _Checks:
    def __init__(self, source: str, base: Path) -> None:
        self.source, self.base = source, base

    def fail(self, field: str, problem: str, expected: str = "") -> InputError:
        return InputError(self.source, f"field '{field}': {problem}", f"expected {expected}" if expected else "")

    def path(self, name: str, field: str) -> Path:
        p = (self.base / name).resolve()
        if not p.is_file():
            raise self.fail(field, f"file {name} not found" if not p.exists() else f"{name} is not a file",
                            "an existing image file, relative to the scenario file")
        # before the flight, not after it (the camera reads the texture at the end)
        why = truncation(p) or ("" if cv2.haveImageReader(str(p)) else "not an image OpenCV reads")
        if why:
            raise self.fail(field, f"{name}: {why}", "a whole PNG or JPEG image")
        return p


def _build(d: ScenarioDoc, r: _Checks) -> Scenario:
    hold = Hold(d.world.hold.length_m, d.world.hold.width_m, d.world.hold.height_m)
    boxes = []
    for i, b in enumerate(d.world.boxes or []):
        lo, hi = b.min, b.max
        inside = (
            lo[0] >= 0 and hi[0] <= hold.length_m and lo[1] >= -hold.width_m / 2 and hi[1] <= hold.width_m / 2
            and lo[2] >= 0 and hi[2] <= hold.height_m
        )
        if not inside:
            raise r.fail(
                f"world.boxes[{i}]", f"box {list(lo)}..{list(hi)} is outside the hold",
                f"x in [0, {hold.length_m}], y in [{-hold.width_m / 2}, {hold.width_m / 2}], z in [0, {hold.height_m}]",
            )
        boxes.append(Box(lo, hi))

    def texture(t: TextureDoc, f: str) -> WallTexture:
        return WallTexture(
            image=r.path(t.image, f + ".image"), m_per_px=t.m_per_px,
            origin_uv=t.origin_uv if t.origin_uv is not None else (0.0, hold.height_m),
            defects_mask=r.path(t.defects_mask, f + ".defects_mask") if t.defects_mask else None,
        )

    textures = {name: texture(t, f"world.wall_textures.{name}") for name, t in (d.world.wall_textures or {}).items()}
    if d.world.front_wall_texture is not None:
        if "front" in textures:
            raise r.fail("world.front_wall_texture", "also given as world.wall_textures.front", "give it once")
        textures["front"] = texture(d.world.front_wall_texture, "world.front_wall_texture")
    world = World(hold, tuple(boxes), tuple(sorted(textures.items())))

    v = d.vehicle
    _check_start(r, world, v.start.position)
    bat = v.battery or BatteryDoc()
    if v.max_height_m is not None and v.max_height_m > hold.height_m:
        raise r.fail("vehicle.max_height_m", f"is {v.max_height_m}", f"at most the hold's height {hold.height_m}")
    vehicle = VehicleSpec(
        v.start.position, v.start.yaw, Battery(bat.start_percent, bat.drain_percent_per_min), v.max_height_m,
        mass_scale=v.mass_scale, thrust_scale=v.thrust_scale,
    )
    c = d.camera or CameraDoc()
    camera = Camera(c.fps, c.width, c.height, c.hfov_deg)

    events: list[StickEvent | ButtonEvent] = []
    for i, e in enumerate(d.operator or []):
        if e.t > d.duration_s:
            raise r.fail(f"operator[{i}].t", f"is {e.t}", f"a time within the flight's duration_s {d.duration_s:g}")
        if e.button is not None:
            events.append(ButtonEvent(e.t, e.button))
        else:
            st = e.stick
            events.append(StickEvent(e.t, SpeedCommand(st.vx, st.vy, st.vz, st.yaw_rate)))
    if any(b.t_s < a.t_s for a, b in zip(events, events[1:])):
        raise r.fail("operator", "events are not in time order", "non-decreasing t")
    for i, f in enumerate(d.faults or []):
        if f.t > d.duration_s:  # a fault that begins after the flight never happens: a typing error, as an operator event
            raise r.fail(f"faults[{i}].t", f"is {f.t}", f"a time within the flight's duration_s {d.duration_s:g}")
    faults = tuple(Fault(f.t, f.duration_s, f.fault, f.sensor, f.rate, f.wind_m_s) for f in d.faults or [])
    return Scenario(
        name=d.name, duration_s=d.duration_s, seed=d.seed, world=world, vehicle=vehicle, camera=camera,
        operator=tuple(events), faults=faults, source=Path(r.source) if r.source else None,
    )


def _check_start(r: _Checks, world: World, pos: tuple[float, ...]) -> None:
    hold, rad = world.hold, VEHICLE_RADIUS_M
    x, y, z = pos
    f = "vehicle.start.position"
    if not (rad <= x <= hold.length_m - rad and -hold.width_m / 2 + rad <= y <= hold.width_m / 2 - rad):
        raise r.fail(
            f, f"{list(pos)} is outside the hold or within {rad} m of a wall",
            f"x in [{rad}, {hold.length_m - rad}], y in [{-hold.width_m / 2 + rad}, {hold.width_m / 2 - rad}]",
        )
    if not 0.0 <= z <= hold.height_m:
        raise r.fail(f, f"z={z} is outside the hold", f"z in [0, {hold.height_m}] (the vehicle starts landed)")
    # Landed: on the tank top, or on a box whose top is under it.
    tops = [b.max_m[2] for b in world.boxes if b.min_m[0] <= x <= b.max_m[0] and b.min_m[1] <= y <= b.max_m[1]]
    if abs(z) > 0.01 and not any(abs(z - top) <= 0.01 for top in tops):
        raise r.fail(f, f"z={z:g} is in mid-air (the vehicle starts landed)",
                     "".join(f"z {top:g} (the top of the box under it) or " for top in tops)
                     + f"z 0 on the tank top, at least {VEHICLE_RADIUS_M} m from every box")
    for i, b in enumerate(world.boxes):
        near = all(b.min_m[k] - rad < pos[k] < b.max_m[k] + rad for k in range(2))
        if near and z < b.max_m[2]:
            raise r.fail(f, f"{list(pos)} is inside obstacle world.boxes[{i}] (or within {rad} m of it)", "a free landing spot")
