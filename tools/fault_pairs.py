"""Fly every pair of fault classes at once, for a few seconds and for a long spell, and list the
flights that end badly: a collision, a front wall closer than 0.75 m, or a vertical speed past
1 m/s downwards.

The safety campaign (docs/campaign.md) draws its faults one at a time at random moments, so two
faults rarely overlap; this probe overlaps them on purpose. Each flight: take-off, a climb to
about 2 m, 1.5 m from the left wall and 3 m from the front wall; then a hover, or a push towards
the front wall at 0.6 m/s (and 0.2 m/s to the left); the first fault at 9 s, the second at 9.5 s,
both lasting 3 s or 12 s; land at 23 s. 15 fault classes give 105 pairs, 420 flights, about
3 minutes on one core.

    python tools/fault_pairs.py [--json OUT.json]
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from inspect_pipe.flight.runner import run_scenario  # noqa: E402
from inspect_pipe.flight.scenario import parse_scenario  # noqa: E402

FAULTS = {
    "no_bottom_flow": {"fault": "sensor_dropout", "sensor": "bottom_flow"},
    "no_front_flow": {"fault": "sensor_dropout", "sensor": "front_flow"},
    "no_teraranger": {"fault": "sensor_dropout", "sensor": "bottom_tof"},
    "stuck_teraranger": {"fault": "stuck_reading", "sensor": "bottom_tof"},
    "stuck_bottom_flow": {"fault": "stuck_reading", "sensor": "bottom_flow"},
    "stuck_front_flow": {"fault": "stuck_reading", "sensor": "front_flow"},
    "stuck_left_sonar": {"fault": "stuck_reading", "sensor": "left_sonar"},
    "range_loss": {"fault": "range_loss"},
    "vibration": {"fault": "vibration", "rate": 0.5},
    "gust": {"fault": "gust", "wind_m_s": [1.5, 0.5, -0.3]},
    "weak_motor": {"fault": "weak_motor", "rate": 0.25},
    "battery_sag": {"fault": "battery_sag", "rate": 0.2},
    "low_texture_bottom": {"fault": "low_texture", "sensor": "bottom_flow", "rate": 0.8},
    "flow_quality_zero_bottom": {"fault": "flow_quality_zero", "sensor": "bottom_flow"},
    "spurious_front": {"fault": "spurious_max_range", "sensor": "front_flow", "rate": 0.5},
}
DURATIONS_S = (3.0, 12.0)


def scenario(name: str, faults: list[dict], duration_s: float, push: bool) -> dict:
    still = {"vx": 0, "vy": 0, "vz": 0, "yaw_rate": 0}
    ops = [{"t": 0.5, "button": "takeoff"}, {"t": 4.0, "stick": dict(still, vz=0.5)}, {"t": 6.0, "stick": still}]
    if push:
        ops += [{"t": 8.0, "stick": dict(still, vx=0.6, vy=0.2)}, {"t": 22.0, "stick": still}]
    ops.append({"t": 23.0, "button": "land"})
    return {
        "format": "inspect_pipe.scenario/1", "name": name, "duration_s": 34, "seed": 5,
        "world": {"hold": {"length_m": 12, "width_m": 10, "height_m": 16}},
        "vehicle": {"start": {"position": [9.0, 3.5, 0], "yaw": 0}}, "operator": ops,
        "faults": [dict(f, t=9.0 + 0.5 * i, duration_s=duration_s) for i, f in enumerate(faults)],
    }


def fly(a: str, b: str, duration_s: float, push: bool) -> dict:
    recs: list = []
    res = run_scenario(parse_scenario(scenario(f"{a}+{b}", [FAULTS[a], FAULTS[b]], duration_s, push)), on_tick=recs.append)
    return {
        "faults": [a, b], "duration_s": duration_s, "push": push, "status": res.status.value,
        "final_state": res.final_fsm.value,
        "min_front_m": round(min(r.dist_true.front for r in recs), 3),
        "min_side_m": round(min(min(r.dist_true.left, r.dist_true.right) for r in recs), 3),
        "max_fall_m_s": round(max(-r.vel_true[2] for r in recs), 3),
    }


def bad(row: dict) -> bool:
    return row["status"] != "completed" or row["min_front_m"] < 0.75 or row["max_fall_m_s"] > 1.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", type=Path, help="write every flight's row here")
    args = ap.parse_args()
    rows = [fly(a, b, d, push) for a, b in itertools.combinations(FAULTS, 2) for push in (False, True) for d in DURATIONS_S]
    for r in rows:
        if bad(r):
            print(f"{'+'.join(r['faults']):45s} {r['duration_s']:4.0f} s {'push' if r['push'] else 'hover':5s} {r['status']:9s} "
                  f"front {r['min_front_m']:.2f} m side {r['min_side_m']:.2f} m fall {r['max_fall_m_s']:.2f} m/s ({r['final_state']})")
    print(f"{len(rows)} flights, {sum(bad(r) for r in rows)} bad, {sum(r['status'] == 'collision' for r in rows)} collisions")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
