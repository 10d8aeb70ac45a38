"""Scenario files (``inspect_pipe.scenario/1``, see SPEC.md): typed, frozen, validated on load.

Every problem is an :class:`InputError` naming the file, the field and what is expected.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

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


# --------------------------------------------------------------------------- parsing helpers


class _Reader:
    def __init__(self, source: str, base: Path) -> None:
        self.source = source
        self.base = base

    def fail(self, field: str, problem: str, expected: str = "") -> InputError:
        return InputError(self.source, f"field '{field}': {problem}", f"expected {expected}" if expected else "")

    def mapping(self, obj: Any, field: str, allowed: set[str], required: set[str]) -> dict:
        if not isinstance(obj, dict):
            raise self.fail(field or "<top>", f"is {type(obj).__name__}", "a mapping")
        for key in obj:
            if key not in allowed:
                raise self.fail(_join(field, str(key)), "unknown field", "one of " + ", ".join(sorted(allowed)))
        for key in sorted(required):
            if key not in obj:
                raise self.fail(_join(field, key), "missing", "it to be present")
        return obj

    def number(self, obj: Any, field: str, *, lo: float = -math.inf, hi: float = math.inf, positive: bool = False) -> float:
        if isinstance(obj, bool) or not isinstance(obj, (int, float)) or not math.isfinite(obj):
            raise self.fail(field, f"is {obj!r}", "a number")
        if positive and obj <= 0:
            raise self.fail(field, f"is {obj}", "a number > 0")
        if not lo <= obj <= hi:
            raise self.fail(field, f"is {obj}", f"a number in [{lo}, {hi}]")
        return float(obj)

    def integer(self, obj: Any, field: str, *, lo: int = 0) -> int:
        if isinstance(obj, bool) or not isinstance(obj, int) or obj < lo:
            raise self.fail(field, f"is {obj!r}", f"an integer >= {lo}")
        return int(obj)

    def vector(self, obj: Any, field: str, n: int) -> tuple[float, ...]:
        if not isinstance(obj, (list, tuple)) or len(obj) != n:
            raise self.fail(field, f"is {obj!r}", f"a list of {n} numbers")
        return tuple(self.number(v, f"{field}[{i}]") for i, v in enumerate(obj))

    def enum(self, obj: Any, field: str, kind: type[enum.Enum]):
        values = [e.value for e in kind]  # type: ignore[attr-defined]
        if obj not in values:
            raise self.fail(field, f"unknown value {obj!r}", "one of " + ", ".join(values))
        return kind(obj)

    def path(self, obj: Any, field: str) -> Path:
        if not isinstance(obj, str) or not obj:
            raise self.fail(field, f"is {obj!r}", "a file path relative to the scenario file")
        p = (self.base / obj).resolve()
        if not p.is_file():
            raise self.fail(field, f"file {obj} not found", "an existing image file")
        return p


def _join(a: str, b: str) -> str:
    return f"{a}.{b}" if a else b


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(str(path), "scenario file not found", "give the path of a .yaml scenario")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError(str(path), "not UTF-8 text", "a YAML or JSON scenario") from None
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise InputError(str(path), f"not valid YAML{where}", "a YAML or JSON scenario") from None
    return parse_scenario(doc, source=str(path), base=path.parent)


def parse_scenario(doc: Any, *, source: str = "<scenario>", base: Path = Path(".")) -> Scenario:
    r = _Reader(source, base)
    top = r.mapping(
        doc, "", {"format", "name", "duration_s", "seed", "world", "vehicle", "camera", "operator", "faults"},
        {"format", "name", "duration_s", "world", "vehicle"},
    )
    if top["format"] != FORMAT:
        raise r.fail("format", f"is {top['format']!r}", repr(FORMAT))
    if not isinstance(top["name"], str) or not top["name"]:
        raise r.fail("name", f"is {top['name']!r}", "a non-empty string")
    duration = r.number(top["duration_s"], "duration_s", positive=True, hi=24 * 3600)
    seed = r.integer(top.get("seed", 0), "seed")

    w = r.mapping(top["world"], "world", {"hold", "boxes", "front_wall_texture", "wall_textures"}, {"hold"})
    h = r.mapping(w["hold"], "world.hold", {"length_m", "width_m", "height_m"}, {"length_m", "width_m", "height_m"})
    hold = Hold(
        r.number(h["length_m"], "world.hold.length_m", lo=2.0, hi=500.0),
        r.number(h["width_m"], "world.hold.width_m", lo=2.0, hi=500.0),
        r.number(h["height_m"], "world.hold.height_m", lo=2.0, hi=100.0),
    )
    boxes = []
    raw_boxes = w.get("boxes") or []
    if not isinstance(raw_boxes, list):
        raise r.fail("world.boxes", f"is {type(raw_boxes).__name__}", "a list of {min: [x,y,z], max: [x,y,z]}")
    for i, b in enumerate(raw_boxes):
        f = f"world.boxes[{i}]"
        b = r.mapping(b, f, {"min", "max"}, {"min", "max"})
        lo, hi = r.vector(b["min"], f + ".min", 3), r.vector(b["max"], f + ".max", 3)
        if any(hi[k] <= lo[k] for k in range(3)):
            raise r.fail(f, f"min {list(lo)} not below max {list(hi)}", "min < max on every axis")
        inside = (
            lo[0] >= 0 and hi[0] <= hold.length_m and lo[1] >= -hold.width_m / 2 and hi[1] <= hold.width_m / 2
            and lo[2] >= 0 and hi[2] <= hold.height_m
        )
        if not inside:
            raise r.fail(
                f, f"box {list(lo)}..{list(hi)} is outside the hold",
                f"x in [0, {hold.length_m}], y in [{-hold.width_m / 2}, {hold.width_m / 2}], z in [0, {hold.height_m}]",
            )
        boxes.append(Box(lo, hi))  # type: ignore[arg-type]
    def texture(t, f: str) -> WallTexture:
        t = r.mapping(t, f, {"image", "m_per_px", "origin_uv", "defects_mask"}, {"image", "m_per_px"})
        return WallTexture(
            image=r.path(t["image"], f + ".image"),
            m_per_px=r.number(t["m_per_px"], f + ".m_per_px", positive=True),
            origin_uv=r.vector(t.get("origin_uv", [0.0, hold.height_m]), f + ".origin_uv", 2),  # type: ignore[arg-type]
            defects_mask=r.path(t["defects_mask"], f + ".defects_mask") if t.get("defects_mask") else None,
        )

    textures: dict[str, WallTexture] = {}
    if w.get("wall_textures") is not None:
        wt = w["wall_textures"]
        if not isinstance(wt, dict):
            raise r.fail("world.wall_textures", f"is {type(wt).__name__}", "a mapping {front|back|left|right: {image, m_per_px, ...}}")
        for name, t in wt.items():
            if name not in WALLS:
                raise r.fail(f"world.wall_textures.{name}", "is not a wall", "one of " + ", ".join(WALLS))
            textures[name] = texture(t, f"world.wall_textures.{name}")
    if w.get("front_wall_texture") is not None:
        if "front" in textures:
            raise r.fail("world.front_wall_texture", "also given as world.wall_textures.front", "give it once")
        textures["front"] = texture(w["front_wall_texture"], "world.front_wall_texture")
    world = World(hold, tuple(boxes), tuple(sorted(textures.items())))

    v = r.mapping(top["vehicle"], "vehicle", {"start", "battery", "max_height_m", "mass_scale", "thrust_scale"}, {"start"})
    s = r.mapping(v["start"], "vehicle.start", {"position", "yaw"}, {"position"})
    pos = r.vector(s["position"], "vehicle.start.position", 3)
    yaw = r.number(s.get("yaw", 0.0), "vehicle.start.yaw", lo=-2 * math.pi, hi=2 * math.pi)
    _check_start(r, world, pos)
    bat = r.mapping(v.get("battery", {}), "vehicle.battery", {"start_percent", "drain_percent_per_min"}, set())
    battery = Battery(
        r.number(bat.get("start_percent", 100.0), "vehicle.battery.start_percent", lo=0.0, hi=100.0),
        r.number(bat.get("drain_percent_per_min", 4.0), "vehicle.battery.drain_percent_per_min", lo=0.0, hi=100.0),
    )
    max_h = None
    if v.get("max_height_m") is not None:
        max_h = r.number(v["max_height_m"], "vehicle.max_height_m", lo=1.0, hi=min(14.0, hold.height_m))
    vehicle = VehicleSpec(
        pos, yaw, battery, max_h,  # type: ignore[arg-type]
        mass_scale=r.number(v.get("mass_scale", 1.0), "vehicle.mass_scale", lo=0.5, hi=1.5),
        thrust_scale=r.number(v.get("thrust_scale", 1.0), "vehicle.thrust_scale", lo=0.5, hi=1.5),
    )

    camera = Camera()
    if top.get("camera") is not None:
        c = r.mapping(top["camera"], "camera", {"fps", "width", "height", "hfov_deg"}, set())
        camera = Camera(
            r.number(c.get("fps", 10.0), "camera.fps", positive=True, hi=200.0),
            r.integer(c.get("width", 752), "camera.width", lo=16),
            r.integer(c.get("height", 480), "camera.height", lo=16),
            r.number(c.get("hfov_deg", 60.0), "camera.hfov_deg", lo=5.0, hi=170.0),
        )

    events: list[StickEvent | ButtonEvent] = []
    raw_ops = top.get("operator") or []
    if not isinstance(raw_ops, list):
        raise r.fail("operator", f"is {type(raw_ops).__name__}", "a list of {t, stick} or {t, button} events")
    for i, e in enumerate(raw_ops):
        f = f"operator[{i}]"
        e = r.mapping(e, f, {"t", "stick", "button"}, {"t"})
        t = r.number(e["t"], f + ".t", lo=0.0, hi=duration)
        if ("stick" in e) == ("button" in e):
            raise r.fail(f, "needs exactly one of 'stick' or 'button'", "{t, stick: {vx, vy, vz, yaw_rate}} or {t, button}")
        if "button" in e:
            events.append(ButtonEvent(t, r.enum(e["button"], f + ".button", Button)))
        else:
            st = r.mapping(e["stick"], f + ".stick", {"vx", "vy", "vz", "yaw_rate"}, set())
            events.append(
                StickEvent(
                    t,
                    SpeedCommand(
                        r.number(st.get("vx", 0.0), f + ".stick.vx", lo=-3, hi=3),
                        r.number(st.get("vy", 0.0), f + ".stick.vy", lo=-3, hi=3),
                        r.number(st.get("vz", 0.0), f + ".stick.vz", lo=-3, hi=3),
                        r.number(st.get("yaw_rate", 0.0), f + ".stick.yaw_rate", lo=-3, hi=3),
                    ),
                )
            )
    if any(b.t_s < a.t_s for a, b in zip(events, events[1:])):
        raise r.fail("operator", "events are not in time order", "non-decreasing t")

    faults = []
    raw_faults = top.get("faults") or []
    if not isinstance(raw_faults, list):
        raise r.fail("faults", f"is {type(raw_faults).__name__}", "a list of {t, duration_s, fault[, sensor]}")
    for i, fl in enumerate(raw_faults):
        f = f"faults[{i}]"
        fl = r.mapping(fl, f, {"t", "duration_s", "fault", "sensor", "rate", "wind_m_s"}, {"t", "duration_s", "fault"})
        kind = r.enum(fl["fault"], f + ".fault", FaultKind)
        sensor = rate = wind = None
        if kind in _NEEDS_SENSOR:
            if "sensor" not in fl:
                raise r.fail(f + ".sensor", "missing", "one of " + ", ".join(s.value for s in SensorName))
            sensor = r.enum(fl["sensor"], f + ".sensor", SensorName)
            if kind in (FaultKind.FLOW_QUALITY_ZERO, FaultKind.LOW_TEXTURE) and sensor not in (SensorName.BOTTOM_FLOW, SensorName.FRONT_FLOW):
                raise r.fail(f + ".sensor", f"{sensor.value} has no flow", "bottom_flow or front_flow")
            if kind is FaultKind.SPURIOUS_MAX_RANGE and sensor is SensorName.BOTTOM_TOF:
                raise r.fail(f + ".sensor", "the TeraRanger is not a sonar", "a sonar: bottom_flow, front_flow, left_sonar, right_sonar")
        elif "sensor" in fl:
            raise r.fail(f + ".sensor", f"{kind.value} names no sensor", "no 'sensor' field")
        if kind in _NEEDS_RATE:
            if "rate" not in fl:
                raise r.fail(f + ".rate", "missing", "a number in [0, 1]")
            rate = r.number(fl["rate"], f + ".rate", lo=0.0, hi=1.0)
        elif "rate" in fl:
            raise r.fail(f + ".rate", f"{kind.value} takes no rate", "no 'rate' field")
        if kind is FaultKind.GUST:
            if "wind_m_s" not in fl:
                raise r.fail(f + ".wind_m_s", "missing", "[wx, wy, wz] in m/s")
            wind = r.vector(fl["wind_m_s"], f + ".wind_m_s", 3)
            if math.hypot(*wind) > 10.0:
                raise r.fail(f + ".wind_m_s", f"{list(wind)} is stronger than 10 m/s", "a gust of at most 10 m/s")
        elif "wind_m_s" in fl:
            raise r.fail(f + ".wind_m_s", f"{kind.value} takes no wind", "no 'wind_m_s' field")
        faults.append(
            Fault(
                r.number(fl["t"], f + ".t", lo=0.0), r.number(fl["duration_s"], f + ".duration_s", positive=True),
                kind, sensor, rate, wind,  # type: ignore[arg-type]
            )
        )
    return Scenario(
        name=top["name"], duration_s=duration, seed=seed, world=world, vehicle=vehicle, camera=camera,
        operator=tuple(events), faults=tuple(faults), source=Path(source) if source else None,
    )


def _check_start(r: _Reader, world: World, pos: tuple[float, ...]) -> None:
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
    for i, b in enumerate(world.boxes):
        near = all(b.min_m[k] - rad < pos[k] < b.max_m[k] + rad for k in range(2))
        if near and z < b.max_m[2]:
            raise r.fail(f, f"{list(pos)} is inside obstacle world.boxes[{i}] (or within {rad} m of it)", "a free landing spot")
