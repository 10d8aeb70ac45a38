"""Seeded episode generator: a random hold, an operator script and faults, as a scenario document
(``inspect_pipe.scenario/1``) that ``inspect-pipe fly --scenario`` accepts.

Episode ``i`` of campaign seed ``S`` depends on ``(S, i)`` only (its own ``random.Random``), so
any episode can be regenerated alone and the campaign is reproducible in any order or process.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

from inspect_pipe.flight.scenario import FORMAT, Scenario, parse_scenario

__all__ = ["EpisodeSpec", "Escape", "SCRIPT_KINDS", "generate_episode"]

SCRIPT_KINDS = ("wall_push", "push_yaw", "corner_push", "inspection_sweep", "takeoff_landing", "passage")
_SCRIPT_WEIGHTS = (0.24, 0.14, 0.2, 0.2, 0.1, 0.12)
_FAULTS = ("sensor_dropout", "packet_loss", "stuck_reading", "spurious_max_range", "range_loss",
           "flow_quality_zero", "link_loss", "battery_sag", "gust")
_FAULT_WEIGHTS = (0.22, 0.1, 0.08, 0.1, 0.1, 0.08, 0.16, 0.06, 0.1)
# The honest simulator's fault classes (issue 19): drawn from a stream of their own, so that every
# episode without one is the one earlier campaigns (and the regression scenarios) flew.
_HONEST_FAULTS = ("weak_motor", "vibration", "low_texture")
HONEST_FAULT_SHARE = 0.25  # of the episodes get one of them
_SENSORS = ("bottom_flow", "front_flow", "bottom_tof", "left_sonar", "right_sonar")
_SECTOR_SENSOR = {"front": "front_flow", "left": "left_sonar", "right": "right_sonar"}
DROPOUT_FAULTS = frozenset({"sensor_dropout", "packet_loss", "stuck_reading", "spurious_max_range", "range_loss", "flow_quality_zero",
                            "low_texture"})


@dataclass(frozen=True)
class Escape:
    """The operator asks to leave a wall or corner along ``direction`` (world, unit) during
    [t0_s, t1_s]; a vehicle that does not move ``min_progress_m`` that way is stuck."""

    t0_s: float
    t1_s: float
    direction: tuple[float, float]
    min_progress_m: float = 0.3


@dataclass(frozen=True)
class EpisodeSpec:
    index: int
    seed: int
    kind: str
    doc: dict  # the scenario document
    subsets: tuple[str, ...]
    escapes: tuple[Escape, ...] = ()

    @property
    def name(self) -> str:
        return self.doc["name"]

    def scenario(self) -> Scenario:
        return parse_scenario(self.doc, source=f"<campaign episode {self.index}>")


def _r(x: float, nd: int = 3) -> float:
    return round(float(x), nd)


class _Script:
    def __init__(self) -> None:
        self.events: list[dict] = []
        self.t = 0.0

    def button(self, name: str) -> None:
        self.events.append({"t": _r(self.t), "button": name})

    def stick(self, vx=0.0, vy=0.0, vz=0.0, yaw_rate=0.0) -> None:
        self.events.append({"t": _r(self.t), "stick": {"vx": _r(vx), "vy": _r(vy), "vz": _r(vz), "yaw_rate": _r(yaw_rate)}})

    def wait(self, s: float) -> None:
        self.t += s


def _box_heights_ok(h: float, alt_lo: float, alt_hi: float) -> bool:
    # Box tops near the flight altitude are seen by no sensor of any shield (single-ray sonars
    # along the body axes); they are left out so that an episode tests avoidance, not blindness.
    return not (alt_lo - 0.6 < h < alt_hi + 0.5)


def _world(rng: random.Random, kind: str, alt_lo: float, alt_hi: float, front_d: float, side: tuple[float, float] | None):
    """A hold with the start ``front_d`` from the front wall (and ``side[1]`` from the wall on
    side ``side[0]``: +1 left, -1 right), so that episodes stay short."""
    L, W, H = _r(rng.uniform(8, 30), 2), _r(rng.uniform(6, 20), 2), _r(rng.uniform(6, 15), 2)
    H = _r(max(H, alt_hi + 3.0), 2)
    sx = _r(max(1.5, L - front_d), 2)
    if side is None:
        sy = _r(rng.uniform(-W / 2 + 1.6, W / 2 - 1.6), 2)
    else:
        sy = _r(side[0] * max(-W / 2 + 1.6, W / 2 - side[1]), 2)
    boxes: list[dict] = []

    def free_of_start(x0, x1, y0, y1, margin) -> bool:
        return not (x0 - margin < sx < x1 + margin and y0 - margin < sy < y1 + margin)

    def height() -> float | None:
        for _ in range(20):
            h = rng.uniform(0.3, 1.5)
            if _box_heights_ok(h, alt_lo, alt_hi):
                return _r(h, 2)
        return None

    if kind == "passage":
        g = rng.uniform(2.4, 4.0)
        yg = rng.uniform(-W / 2 + g / 2 + 0.5, W / 2 - g / 2 - 0.5)
        xp = rng.uniform(sx + 3.0, max(sx + 3.1, L - 3.0))
        xp = min(xp, L - 2.0)
        th = rng.uniform(0.3, 0.8)
        boxes.append({"min": [_r(xp), _r(-W / 2), 0], "max": [_r(xp + th), _r(yg - g / 2), _r(H)]})
        boxes.append({"min": [_r(xp), _r(yg + g / 2), 0], "max": [_r(xp + th), _r(W / 2), _r(H)]})
        sy = _r(yg + rng.uniform(-0.4, 0.4), 2)
    for _ in range(rng.choice((0, 1, 1, 2, 2, 3))):
        t = rng.choice(("step", "coaming", "pillar"))
        if t == "pillar":  # an inside corner at the front wall
            d, w = rng.uniform(0.5, 2.0), rng.uniform(0.5, 2.0)
            y0, y1 = (W / 2 - w, W / 2) if rng.random() < 0.5 else (-W / 2, -W / 2 + w)
            b = (L - d, L, y0, y1, H)
        else:
            h = height()
            if h is None:
                continue
            if t == "step":
                x0 = rng.uniform(sx + 1.5, max(sx + 1.6, L - 3.0))
                y0, y1 = (-W / 2, W / 2) if rng.random() < 0.4 else sorted(rng.uniform(-W / 2, W / 2) for _ in range(2))
                b = (x0, min(L, x0 + rng.uniform(1.0, 4.0)), y0, max(y1, y0 + 1.0), h)
            else:
                x0, y0 = rng.uniform(0.5, L - 2.0), rng.uniform(-W / 2, W / 2 - 1.0)
                b = (x0, min(L, x0 + rng.uniform(1.0, 3.0)), y0, min(W / 2, y0 + rng.uniform(1.0, 3.0)), h)
        x0, x1, y0, y1, top = b
        y0, y1 = max(y0, -W / 2), min(y1, W / 2)
        if y1 - y0 < 1.0:
            y0, y1 = (y1 - 1.0, y1) if y1 - 1.0 >= -W / 2 else (y0, y0 + 1.0)
        if x1 - x0 < 0.2 or y1 - y0 < 0.2 or not free_of_start(x0, x1, y0, y1, 1.6):
            continue
        boxes.append({"min": [_r(x0), _r(y0), 0], "max": [_r(x1), _r(y1), _r(top)]})
    world = {"hold": {"length_m": L, "width_m": W, "height_m": H}, "boxes": boxes}
    return world, (sx, sy)


def generate_episode(seed: int, index: int, *, honest_faults: bool = True) -> EpisodeSpec:
    """Episode ``index`` of the campaign with seed ``seed``. ``honest_faults``: draw the honest
    simulator's fault classes (weak motor, vibration, low texture) too; without them the episode
    is the one campaigns before issue 19 flew (what a regression scenario replays)."""
    rng = random.Random(f"inspect_pipe.campaign/{seed}/{index}")
    kind = rng.choices(SCRIPT_KINDS, _SCRIPT_WEIGHTS)[0]
    alt = _r(rng.uniform(1.0, 3.5), 2)
    sweep_up = rng.uniform(0.4, 1.2) if kind == "inspection_sweep" else 0.0
    u = rng.uniform(0.2, 1.0)  # the operator's push speed
    reach = lambda speed: rng.uniform(2.5, 2.0 + 8.0 * speed)  # noqa: E731 - approach of at most ~15 s
    sector = rng.choice(("front", "left", "right")) if kind == "wall_push" else "front"
    corner_side = rng.choice((-1.0, 1.0))
    if sector != "front":
        side = (1.0 if sector == "left" else -1.0, reach(u))
    elif kind == "corner_push":
        side = (corner_side, reach(u))
    else:
        side = None
    front_d = reach(u if kind in ("wall_push", "corner_push", "passage", "push_yaw") else 0.5)
    if kind == "passage":
        front_d += 4.0
    world, (sx, sy) = _world(rng, kind, alt, alt + sweep_up, front_d, side)
    L, W = world["hold"]["length_m"], world["hold"]["width_m"]
    sc = _Script()
    escapes: list[Escape] = []
    pushes: list[tuple[float, float, str]] = []  # (t0, t1, sector): the operator pushes towards it
    moving: list[tuple[float, float]] = []  # the stick is off-centre

    sc.t = 0.5
    sc.button("takeoff")
    sc.wait(3.5)
    if kind != "takeoff_landing" and alt > 1.05:
        sc.stick(vz=0.4)
        sc.wait((alt - 1.0) / 0.4)
        sc.stick()
    sc.wait(1.0)
    t_active = sc.t

    def push(vx: float, vy: float, distance_m: float, hold_s: float, sector: str, yaw_rate: float = 0.0) -> None:
        speed = max(math.hypot(vx, vy), 0.05)
        t0 = sc.t
        sc.stick(vx, vy, 0.0, yaw_rate)
        sc.wait(max(distance_m - 1.0, 0.0) / speed + hold_s)
        pushes.append((t0, sc.t, sector))
        moving.append((t0, sc.t))
        sc.stick()
        sc.wait(1.5)

    def escape(vy: float, seconds: float) -> None:
        t0 = sc.t
        sc.stick(vy=vy)
        sc.wait(seconds)
        escapes.append(Escape(_r(t0), _r(sc.t), (0.0, math.copysign(1.0, vy))))
        moving.append((t0, sc.t))
        sc.stick()
        sc.wait(1.0)

    if kind == "wall_push":
        if sector == "front":
            push(u, 0.0, L - sx, rng.uniform(3, 8), "front")
            escape(rng.choice((-1, 1)) * 0.4, 4.0)
        else:
            s = 1.0 if sector == "left" else -1.0
            push(0.0, s * u, W / 2 - s * sy, rng.uniform(3, 8), sector)
            escape(-s * 0.4, 4.0)
    elif kind == "push_yaw":
        u = min(u, 0.6)
        push(u, 0.0, L - sx, rng.uniform(6, 12), "front", yaw_rate=rng.choice((-1, 1)) * rng.uniform(0.1, 0.3))
    elif kind == "corner_push":
        side = corner_side
        th = math.radians(rng.uniform(30, 60))
        u = max(u, 0.3)
        dist = max((L - sx) / max(math.cos(th), 0.3), (W / 2 - side * sy) / max(math.sin(th), 0.3))
        push(u * math.cos(th), side * u * math.sin(th), min(dist, 12.0), rng.uniform(3, 6), "front")
        escape(-side * 0.4, 5.0)
    elif kind == "inspection_sweep":
        push(0.5, 0.0, L - sx, 2.0, "front")
        sc.button("inspection_mode_on")
        sc.wait(0.5)
        direction = rng.choice((-1.0, 1.0))
        for leg in range(rng.randint(2, 4)):
            t0 = sc.t
            sc.stick(vx=rng.uniform(0.0, 0.3), vy=direction * 0.2)
            sc.wait(rng.uniform(4, 8))
            moving.append((t0, sc.t))
            if leg % 2 == 0 and sweep_up > 0:
                sc.stick(vz=0.2)
                sc.wait(sweep_up / 0.2 / 2)
            direction = -direction
        sc.stick()
        sc.button("inspection_mode_off")
        sc.wait(1.0)
    elif kind == "takeoff_landing":
        sc.wait(rng.uniform(1, 4))
        for _ in range(rng.randint(1, 2)):
            t0 = sc.t
            a = rng.uniform(0, 2 * math.pi)
            sc.stick(0.25 * math.cos(a), 0.25 * math.sin(a))
            sc.wait(rng.uniform(1.0, 2.0))
            moving.append((t0, sc.t))
            sc.stick()
            sc.wait(2.0)
            sc.button("land")
            sc.wait(9.0)
            sc.button("takeoff")
            sc.wait(5.0)
        sc.button("land")
        sc.wait(8.0)
    else:  # passage
        u = min(max(u, 0.3), 0.8)
        push(u, 0.0, L - sx, rng.uniform(2, 5), "front")
    duration = _r(sc.t + 1.0, 2)

    faults: list[dict] = []
    vehicle: dict = {"start": {"position": [sx, sy, 0], "yaw": 0},
                     "battery": {"start_percent": _r(rng.uniform(50, 100), 1), "drain_percent_per_min": 4}}
    subsets: set[str] = {kind}
    n_faults = 0 if rng.random() < 0.3 else rng.randint(1, 3)
    span = (t_active, max(t_active + 1.0, duration - 1.0))
    for _ in range(n_faults):
        f = rng.choices(_FAULTS, _FAULT_WEIGHTS)[0]
        t = rng.uniform(*span)
        if f in ("sensor_dropout", "range_loss") and pushes and rng.random() < 0.6:
            p0, p1, sector = rng.choice(pushes)
            t = rng.uniform(p0 + 0.5 * (p1 - p0), p1)  # during the approach or the push at the wall
            sensor = _SECTOR_SENSOR[sector]
        else:
            sensor = rng.choice(_SENSORS)
        if f == "link_loss" and moving and rng.random() < 0.7:
            m0, m1 = rng.choice(moving)
            t = rng.uniform(m0, max(m0, m1 - 0.3))
        fault: dict = {"t": _r(t), "fault": f}
        if f == "sensor_dropout":
            fault.update(duration_s=_r(rng.uniform(0.2, 3.0)), sensor=sensor)
        elif f == "packet_loss":
            fault.update(duration_s=_r(rng.uniform(5, 20)), sensor=rng.choice(_SENSORS), rate=_r(rng.uniform(0.0, 0.1)))
        elif f == "stuck_reading":
            fault.update(duration_s=_r(rng.uniform(0.2, 2.0)), sensor=rng.choice(_SENSORS))
        elif f == "spurious_max_range":
            fault.update(duration_s=_r(rng.uniform(5, 20)), sensor=rng.choice(("bottom_flow", "front_flow", "left_sonar", "right_sonar")),
                         rate=_r(rng.uniform(0.1, 0.5)))
        elif f == "range_loss":
            fault.update(duration_s=_r(rng.uniform(0.2, 3.0)))
        elif f == "flow_quality_zero":
            fault.update(duration_s=_r(rng.uniform(0.5, 5.0)), sensor=rng.choice(("bottom_flow", "front_flow")))
        elif f == "link_loss":
            fault.update(duration_s=_r(rng.uniform(0.2, 10.0)))
        elif f == "battery_sag":
            fault.update(duration_s=_r(rng.uniform(1.0, 5.0)), rate=_r(rng.uniform(0.05, 0.25)))
        else:  # gust
            a, s = rng.uniform(0, 2 * math.pi), rng.uniform(0.3, 2.0)
            fault.update(duration_s=_r(rng.uniform(1.0, 5.0)), wind_m_s=[_r(s * math.cos(a)), _r(s * math.sin(a)), _r(rng.uniform(-0.3, 0.3))])
        faults.append(fault)
        subsets.add("dropout" if f in DROPOUT_FAULTS else f)
    if rng.random() < 0.15:
        key = rng.choice(("mass_scale", "thrust_scale"))
        vehicle[key] = _r(rng.uniform(0.7, 1.3))
        subsets.add("model_error")
    hrng = random.Random(f"inspect_pipe.campaign.honest/{seed}/{index}")
    if honest_faults and hrng.random() < HONEST_FAULT_SHARE:
        f = hrng.choice(_HONEST_FAULTS)
        fault = {"t": _r(hrng.uniform(*span)), "fault": f}
        if f == "weak_motor":
            fault.update(duration_s=_r(hrng.uniform(2.0, 20.0)), rate=_r(hrng.uniform(0.05, 0.3)))
        elif f == "vibration":
            fault.update(duration_s=_r(hrng.uniform(2.0, 20.0)), rate=_r(hrng.uniform(0.05, 0.5)))
        else:  # low texture: a texture-poor or dark stretch under one PX4Flow
            fault.update(duration_s=_r(hrng.uniform(1.0, 10.0)), sensor=hrng.choice(("bottom_flow", "front_flow")),
                         rate=_r(hrng.uniform(0.3, 0.9)))
        faults.append(fault)
        subsets.add("dropout" if f in DROPOUT_FAULTS else f)
    faults.sort(key=lambda f: f["t"])
    if not (subsets & {"dropout", "link_loss", "gust", "battery_sag", "model_error"}):
        subsets.add("clean")
    doc = {
        "format": FORMAT,
        "name": f"campaign_s{seed}_e{index:05d}_{kind}",
        "duration_s": duration,
        "seed": (seed * 100003 + index) % (2**31),
        "world": world,
        "vehicle": vehicle,
        "operator": sc.events,
        "faults": faults,
    }
    return EpisodeSpec(index, seed, kind, doc, tuple(sorted(subsets)), tuple(escapes))
