"""Per-episode safety metrics, measured on ground truth tick by tick (``EpisodeMonitor``), and
their aggregation per shield.

Definitions (all distances from the vehicle's centre unless said otherwise):

* clearance from the rotor envelope: distance to the nearest wall or box (a box top straight
  below counts as floor, as in the runner) minus 0.27 m (arm 0.17 m
  + rotor 0.1 m), over the airborne part of the flight;
* overshoot: how far inside the 1 m stop line the vehicle came (front, left and right walls and
  boxes, along the world axes), over ticks with no fault active in the last second. A surface
  that comes into a world axis's line of sight already inside the line (the distance along the
  axis drops by more than ``ENTRY_JUMP_M`` in one tick: the vehicle slid past the end of a box or
  a pillar, it did not approach it) moves that axis's line to where the surface appeared, until
  the vehicle is outside the 1 m line again: overshoot then counts only what the vehicle closed
  beyond it. The depth of such entries is reported on its own (``lateral_entry_m``), and the
  nearness to a box's corner they bring shows in the minimum clearance;
* dithering: sign changes of the speed along a wall's normal (hysteresis 0.03 m/s) while the
  operator pushes into that wall within 1.3 m of it;
* stuck: an escape the operator asked for (sideways out of a corner or along a wall) made less
  than 0.3 m of progress, with no fault active meanwhile. An escape that the hold's geometry
  does not allow is not judged: if straight along its direction, within its required progress,
  the vehicle's centre would come closer to any wall or box than where it started and within
  ``STOP_TOLERANCE_M`` (0.05 m) of the stop line or inside it, or more than that closer to the
  nearest surface than where it started, a shield that honours the stop
  line cannot be judged on it (e.g. the stick pushes into the end of a pillar 1.07 m away; or,
  from 1.31 m out of a corner's side wall, 0.3 m of progress would end 1 cm from the line, and a
  vehicle that stops 5 cm short of the line made 0.26 m); such escapes are counted as
  ``escapes_blocked``;
* stale-sector block time: from the start of a blackout of the sensor that sees the sector the
  operator pushes into, until the command into that sector is <= 0.05 m/s (never: the blackout's
  duration, counted as unblocked);
* link-loss hover time: from the start of a link loss (>= 0.5 s, stick off-centre, flying) to
  the first horizontal command of <= 0.01 m/s along the operator's last push (the stick is no
  longer obeyed; a collision repulsion across it, away from a pillar's corner the vehicle is
  within the stop line of, is a safety action, not the stick); ``link_still_s``: to the first
  horizontal command <= 0.01 m/s in every direction, the stricter old quantity; braking: horizontal distance from there to where the
  vehicle first comes to rest (true speed < 0.1 m/s); drift: largest horizontal displacement from
  that rest point until the link is back, within 10 s of the hover command (the hover's drift, "over 10 s";
  braking from the operator's speed is physics: 0.3-0.6 m from 0.8 m/s, so it is reported apart);
* altitude excursion over floor steps: largest |z - z before the step| within 3 s after the
  surface below changes by > 0.25 m, with the stick's vertical speed zero;
* false "landed": the flight machine says landed while the true height above the surface below
  exceeds 0.3 m.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass, field

from inspect_pipe.campaign.generator import EpisodeSpec
from inspect_pipe.flight.geometry import HoldGeometry
from inspect_pipe.flight.runner import TickRecord
from inspect_pipe.flight.scenario import FaultKind, Scenario, SensorName
from inspect_pipe.flight_stack.flight_machine import FlightState

__all__ = ["EpisodeMonitor", "EpisodeResult", "aggregate", "ROTOR_ENVELOPE_M", "STOP_LINE_M"]

ROTOR_ENVELOPE_M = 0.27
STOP_LINE_M = 1.0
STOP_TOLERANCE_M = 0.05  # an escape ending this near the stop line (either side) is not judged
ENTRY_JUMP_M = 0.15  # a closing of 0.15 m in one 20 ms tick (7.5 m/s) is a new surface, not motion
LEG_HEIGHT_M = 0.08
_SECTOR_OF_SENSOR = {SensorName.FRONT_FLOW: (1.0, 0.0), SensorName.LEFT_SONAR: (0.0, 1.0), SensorName.RIGHT_SONAR: (0.0, -1.0)}


@dataclass
class EpisodeResult:
    index: int
    shield: str
    name: str
    kind: str
    subsets: tuple[str, ...]
    collided: bool = False
    collided_at_s: float | None = None
    min_clearance_m: float = math.inf
    overshoot_m: float | None = None
    lateral_entry_m: float | None = None
    dither_changes: int = 0
    dither_held_s: float = 0.0
    stuck: bool = False
    escapes_blocked: int = 0
    stale_block_s: list[float] = field(default_factory=list)
    stale_unblocked: int = 0
    link_hover_s: list[float] = field(default_factory=list)
    link_still_s: list[float] = field(default_factory=list)
    link_drift_m: list[float] = field(default_factory=list)
    link_brake_m: list[float] = field(default_factory=list)
    altitude_excursion_m: float | None = None
    false_landed: bool = False
    sim_s: float = 0.0
    wall_s: float = 0.0

    def to_json(self) -> dict:
        d = asdict(self)
        d["subsets"] = list(self.subsets)
        if math.isinf(d["min_clearance_m"]):
            d["min_clearance_m"] = None
        return d


class EpisodeMonitor:
    """Call with every :class:`TickRecord` of one flight; ``finish()`` returns the result."""

    def __init__(self, spec: EpisodeSpec, scenario: Scenario, shield: str) -> None:
        self.spec, self.sc = spec, scenario
        self.geo = HoldGeometry(scenario.world)
        self.res = EpisodeResult(spec.index, shield, spec.name, spec.kind, spec.subsets)
        self.faults = [f for f in scenario.faults]
        self._fault_spans = [(f.t_s, f.t_s + f.duration_s) for f in self.faults]
        # The faults each metric follows: (fault index, fault, sectors it leaves unseen) for the
        # stale sectors, (fault index, fault) for link losses long enough to judge the hover.
        self._stale_faults = []
        for i, f in enumerate(self.faults):
            if f.kind is FaultKind.SENSOR_DROPOUT and f.sensor in _SECTOR_OF_SENSOR:
                self._stale_faults.append((i, f, [_SECTOR_OF_SENSOR[f.sensor]]))
            elif f.kind is FaultKind.RANGE_LOSS:
                self._stale_faults.append((i, f, list(_SECTOR_OF_SENSOR.values())))
        self._link_faults = [(i, f) for i, f in enumerate(self.faults) if f.kind is FaultKind.LINK_LOSS and f.duration_s >= 0.5]
        self._dt = 0.02
        self._prev_sign: dict[int, int] = {}
        self._prev_down: float | None = None
        self._z_hist: deque = deque(maxlen=20)
        self._step: tuple[float, float] | None = None  # (t of step, z reference)
        self._escape_start: dict[int, tuple[float, float]] = {}
        self._escape_bad: set[int] = set()
        self._stale: dict[int, float | None] = {}  # fault index -> block time or None (pending)
        self._link: dict[int, dict] = {}
        self._prev_near: tuple[float, float, float] | None = None  # front, left, right distance along world axes
        self._line = [STOP_LINE_M] * 3  # each axis's stop line (moved by a lateral entry)

    def _fault_recent(self, t: float, within_s: float = 1.0) -> bool:
        for t0, end in self._fault_spans:
            if t0 <= t <= end + within_s:
                return True
        return False

    def __call__(self, rec: TickRecord) -> None:
        r, t = self.res, rec.t
        x, y, z = rec.pos_true
        out = rec.out
        airborne = out.fsm is not FlightState.LANDED and z - LEG_HEIGHT_M > 0.05
        yaw = rec.yaw_true
        c, s = math.cos(yaw), math.sin(yaw)
        u = out.user_cmd
        stick_w = (c * u.vx_m_s - s * u.vy_m_s, s * u.vx_m_s + c * u.vy_m_s)
        cmd = out.command
        cmd_w = (c * cmd.vx_m_s - s * cmd.vy_m_s, s * cmd.vx_m_s + c * cmd.vy_m_s)
        if rec.collided and not r.collided:
            r.collided, r.collided_at_s = True, t
        if airborne:
            side = rec.side_true if rec.side_true is not None else self.geo.side_distance(x, y, z)
            r.min_clearance_m = min(r.min_clearance_m, side - ROTOR_ENVELOPE_M)
        d = rec.dist_true
        dists = (d.front, d.left, d.right)
        flying = out.fsm is FlightState.FLYING
        self._stop_lines(dists)
        if flying and not self._fault_recent(t):
            line = self._line
            over = max(line[0] - dists[0], line[1] - dists[1], line[2] - dists[2])
            r.overshoot_m = max(r.overshoot_m if r.overshoot_m is not None else 0.0, over, 0.0)
            entry = STOP_LINE_M - min(self._line)
            if entry > 0.0:
                r.lateral_entry_m = max(r.lateral_entry_m or 0.0, entry)
        if flying:
            self._dither(rec, stick_w, dists)
            self._stale_sectors(t, stick_w, cmd_w)
            self._escapes(t, x, y, z)
            self._floor_steps(t, z, d.down, u.vz_m_s)
        if out.fsm is not FlightState.LANDED:
            self._link_loss(t, rec, stick_w)  # a failsafe may land: hovering ends when x, y stop
        if out.fsm is FlightState.LANDED and d.down - LEG_HEIGHT_M > 0.3:
            r.false_landed = True
        r.sim_s = t

    # ------------------------------------------------------------------ the metrics
    def _stop_lines(self, dists) -> None:
        prev, self._prev_near = self._prev_near, dists
        for k, dist in enumerate(dists):
            if dist >= STOP_LINE_M:
                self._line[k] = STOP_LINE_M
            elif prev is not None and prev[k] - dist > ENTRY_JUMP_M:
                self._line[k] = min(self._line[k], dist)

    def _dither(self, rec, stick_w, dists) -> None:
        vx, vy = rec.vel_true[0], rec.vel_true[1]
        for k, (nx, ny) in enumerate(((1.0, 0.0), (0.0, 1.0), (0.0, -1.0))):
            pushing = stick_w[0] * nx + stick_w[1] * ny > 0.05 and dists[k] < STOP_LINE_M + 0.3
            if not pushing:
                self._prev_sign.pop(k, None)
                continue
            self.res.dither_held_s += self._dt
            v = vx * nx + vy * ny
            if abs(v) < 0.03:
                continue
            sign = 1 if v > 0 else -1
            prev = self._prev_sign.get(k)
            if prev is not None and prev != sign:
                self.res.dither_changes += 1
            self._prev_sign[k] = sign

    def _stale_sectors(self, t, stick_w, cmd_w) -> None:
        for i, f, sectors in self._stale_faults:
            if not f.active(t):
                if i in self._stale and self._stale[i] is None:
                    self._stale[i] = math.inf  # ended unblocked
                continue
            for nx, ny in sectors:
                into_stick = stick_w[0] * nx + stick_w[1] * ny
                if into_stick <= 0.1:
                    continue
                if i not in self._stale:
                    self._stale[i] = None
                if self._stale[i] is None and cmd_w[0] * nx + cmd_w[1] * ny <= 0.05:
                    self._stale[i] = t - f.t_s

    def _link_loss(self, t, rec, stick_w) -> None:
        for i, f in self._link_faults:
            st = self._link.get(i)
            if st is None:
                if f.t_s <= t < f.t_s + 0.03:
                    n = math.hypot(*stick_w)
                    if n > 0.05:
                        self._link[i] = {"t0": f.t_s, "u": (stick_w[0] / n, stick_w[1] / n), "hover_t": None,
                                         "still_t": None, "pos": None, "rest": None, "brake": 0.0, "drift": 0.0}
                continue
            if t > f.t_s + f.duration_s:
                continue
            cmd = rec.out.command
            if st["still_t"] is None and abs(cmd.vx_m_s) <= 0.01 and abs(cmd.vy_m_s) <= 0.01:
                st["still_t"] = t
            if st["hover_t"] is None:
                c, sn = math.cos(rec.yaw_true), math.sin(rec.yaw_true)
                along = (c * cmd.vx_m_s - sn * cmd.vy_m_s) * st["u"][0] + (sn * cmd.vx_m_s + c * cmd.vy_m_s) * st["u"][1]
                if along <= 0.01:
                    st["hover_t"], st["pos"], st["brake"] = t, rec.pos_true[:2], 0.0
            elif t - st["hover_t"] <= 10.0:
                p0, p = st["pos"], rec.pos_true[:2]
                if st["rest"] is None:
                    st["brake"] = max(st["brake"], math.hypot(p[0] - p0[0], p[1] - p0[1]))
                    if math.hypot(rec.vel_true[0], rec.vel_true[1]) < 0.1:
                        st["rest"] = p
                else:
                    r0 = st["rest"]
                    st["drift"] = max(st["drift"], math.hypot(p[0] - r0[0], p[1] - r0[1]))

    def _escape_possible(self, x, y, z, e) -> bool:
        """Each surface judged on its own: the one the escape approaches need not be the nearest at
        its start (from 0.94 m of the wall ahead, 0.3 m towards a pillar's face 1.25 m to the side
        ends 0.95 m from it; judged on the nearest surface alone, that escape was "possible" and a
        vehicle stopping at the pillar's 1 m line was stuck: campaign seed 127 e1033)."""
        d0s = self.geo.surface_distances(x, y, z)
        d0 = min(d0s)
        n = max(1, int(math.ceil(e.min_progress_m / 0.05)))
        for k in range(1, n + 1):
            s = e.min_progress_m * k / n
            ds = self.geo.surface_distances(x + s * e.direction[0], y + s * e.direction[1], z)
            if min(ds) < d0 - STOP_TOLERANCE_M:
                return False
            if any(d < d_start - 1e-3 and d < STOP_LINE_M + STOP_TOLERANCE_M for d, d_start in zip(ds, d0s)):
                return False
        return True

    def _escapes(self, t, x, y, z) -> None:
        for i, e in enumerate(self.spec.escapes):
            if e.t0_s <= t <= e.t1_s:
                if i not in self._escape_start:
                    self._escape_start[i] = (x, y)
                    if not self._escape_possible(x, y, z, e):
                        self._escape_bad.add(i)
                        self.res.escapes_blocked += 1
                if self._fault_recent(t, 0.5):
                    self._escape_bad.add(i)
            elif t > e.t1_s and i in self._escape_start and i not in self._escape_bad:
                x0, y0 = self._escape_start[i]
                progress = (x - x0) * e.direction[0] + (y - y0) * e.direction[1]
                if progress < e.min_progress_m:
                    self.res.stuck = True
                self._escape_bad.add(i)  # evaluated once

    def _floor_steps(self, t, z, down, vz_stick) -> None:
        self._z_hist.append(z)
        prev, self._prev_down = self._prev_down, down
        if prev is not None and abs(down - prev) > 0.25 and vz_stick == 0.0 and self._step is None:
            self._step = (t, self._z_hist[0])
        if self._step is not None:
            t0, zref = self._step
            if t - t0 > 3.0 or vz_stick != 0.0:
                self._step = None
            else:
                r = self.res
                r.altitude_excursion_m = max(r.altitude_excursion_m or 0.0, abs(z - zref))

    def finish(self, wall_s: float) -> EpisodeResult:
        r = self.res
        for v in self._stale.values():
            if v is None or math.isinf(v):
                r.stale_unblocked += 1
            else:
                r.stale_block_s.append(round(v, 3))
        for st in self._link.values():
            if st["hover_t"] is not None:
                r.link_hover_s.append(round(st["hover_t"] - st["t0"], 3))
                r.link_drift_m.append(round(st["drift"], 4))
                r.link_brake_m.append(round(st["brake"], 3))
            if st["still_t"] is not None:
                r.link_still_s.append(round(st["still_t"] - st["t0"], 3))
        r.wall_s = wall_s
        return r


def _pct(xs: list[float], q: float) -> float | None:
    if not xs:
        return None
    xs = sorted(xs)
    k = (len(xs) - 1) * q
    lo, hi = math.floor(k), math.ceil(k)
    return xs[lo] + (xs[hi] - xs[lo]) * (k - lo)


def _rnd(x: float | None, nd: int = 3) -> float | None:
    return None if x is None or not math.isfinite(x) else round(x, nd)


def _rnd_up(x: float | None) -> float | None:
    """A largest value judged against a limit, to the millimetre (or ms) above: 0.10007 m of
    overshoot is 0.101, not a 0.100 that meets a 0.10 goal (safety campaign, seed 1 e433).
    (Rounded to 1e-6 first, so float noise on an exact value does not round it up.)"""
    return None if x is None or not math.isfinite(x) else math.ceil(round(x, 6) * 1000.0) / 1000.0


def aggregate(results: list[EpisodeResult]) -> dict:
    """Summary of one shield's episodes (the SPEC's required keys and more)."""
    n = len(results)
    collisions = [r for r in results if r.collided]
    clear = [r.min_clearance_m for r in results if math.isfinite(r.min_clearance_m)]
    over = [r.overshoot_m for r in results if r.overshoot_m is not None and not r.collided]
    entries = [r.lateral_entry_m for r in results if r.lateral_entry_m is not None and not r.collided]
    dither = [10.0 * r.dither_changes / r.dither_held_s for r in results if r.dither_held_s >= 2.0]
    stale = [s for r in results for s in r.stale_block_s]
    hover = [s for r in results for s in r.link_hover_s]
    still = [s for r in results for s in r.link_still_s]
    drift = [s for r in results for s in r.link_drift_m]
    brake = [s for r in results for s in r.link_brake_m]
    alt = [r.altitude_excursion_m for r in results if r.altitude_excursion_m is not None]
    subsets: dict[str, dict] = {}
    for name in sorted({s for r in results for s in r.subsets}):
        sub = [r for r in results if name in r.subsets]
        subsets[name] = {"episodes": len(sub), "collision_free": round(sum(not r.collided for r in sub) / len(sub), 5)}
    return {
        "episodes": n,
        "collision_free": round((n - len(collisions)) / n, 5) if n else None,
        "collisions": len(collisions),
        "min_clearance_p001_m": _rnd(_pct(clear, 0.001)),
        "min_clearance_median_m": _rnd(_pct(clear, 0.5)),
        "overshoot_max_m": _rnd_up(max(over)) if over else None,
        "overshoot_p99_m": _rnd(_pct(over, 0.99)),
        "lateral_entry_max_m": _rnd(max(entries)) if entries else 0.0,
        "lateral_entry_episodes": len(entries),
        "dither_changes_per_10s_median": _rnd(_pct(dither, 0.5)),
        "dither_changes_per_10s_max": _rnd(max(dither)) if dither else None,
        "stuck_episodes": sum(r.stuck for r in results),
        "escapes_blocked": sum(r.escapes_blocked for r in results),
        "stale_block_s_median": _rnd(_pct(stale, 0.5)),
        "stale_block_s_max": _rnd(max(stale)) if stale else None,
        "stale_unblocked": sum(r.stale_unblocked for r in results),
        "link_loss_events": len(hover),
        "link_loss_hover_s_max": _rnd_up(max(hover)) if hover else None,
        "link_loss_hover_s_median": _rnd(_pct(hover, 0.5)),
        "link_loss_still_s_max": _rnd(max(still)) if still else None,
        "link_loss_drift_m_max": _rnd_up(max(drift)) if drift else None,
        "link_loss_brake_m_max": _rnd(max(brake)) if brake else None,
        "link_loss_brake_m_median": _rnd(_pct(brake, 0.5)),
        "altitude_excursion_m_max": _rnd(max(alt)) if alt else None,
        "altitude_excursion_m_median": _rnd(_pct(alt, 0.5)),
        "false_landed": sum(r.false_landed for r in results),
        "sim_time_s": round(sum(r.sim_s for r in results), 1),
        "cpu_time_s": round(sum(r.wall_s for r in results), 1),
        "subsets": subsets,
        "collided_episodes": sorted(r.index for r in collisions),
    }

