"""What a front-diagonal sonar pair would have heard in the open blind-diagonal episodes.

    python tools/blind_diagonal_whatif.py scenarios/regressions/open/campaign_s325_e01682_inspection_sweep.yaml [...]

Flies each scenario with the shipped stack, then re-casts, at every tick of the last ``--window``
seconds before the contact, the beams of the paper's three horizontal HRLV-EZ4s (front, left,
right) and of a hypothetical pair on the front diagonals (+-45 deg), all +-15 deg wide as the
simulator's (``SensorSpecs``), from the vehicle's true pose. Echoes are judged by the simulator's
incidence rule: "sure" within ``grazing_deg`` of a surface's normal (always heard), "maybe" up to
``miss_all_deg`` (heard with a falling chance). For each beam it prints when a box (a pillar or a
floor box: the hold's walls are not counted) was first heard nearer than ``--near`` metres.

A measurement for the owner's decision on the blind diagonals (docs/flight.md, Limits); the
stack is not changed and no diagonal sonar is flown.
"""

from __future__ import annotations

import argparse
import math

import sys

import mujoco
import numpy as np

from inspect_pipe.errors import InputError
from inspect_pipe.flight.runner import run_scenario
from inspect_pipe.flight.scenario import load_scenario
from inspect_pipe.flight.sensors import SensorSpecs, _fan
from inspect_pipe.flight.vehicle_sim import QuadrotorSim

BEAMS = {"front": 0.0, "left": math.pi / 2, "right": -math.pi / 2,
         "front_left (new)": math.pi / 4, "front_right (new)": -math.pi / 4}


def whatif(path: str, window_s: float, near_m: float) -> None:
    specs = SensorSpecs()
    sc = load_scenario(path)
    recs: list = []
    res = run_scenario(sc, on_tick=recs.append)
    tc = res.collided_at_s
    print(f"{path}: {res.status.name}" + ("" if tc is None else f" at {tc:.2f} s"))
    if tc is None:
        return
    sim = QuadrotorSim(sc.world, sc.vehicle.start_position_m, sc.vehicle.start_yaw_rad, seed=0)
    m, d = sim.model, sim.data
    fans = {k: _fan(a, specs) for k, a in BEAMS.items()}
    limits = {"sure": math.radians(specs.grazing_deg), "maybe": math.radians(specs.miss_all_deg)}
    first: dict = {}
    quat = np.zeros(4)
    for r in recs:
        if r.t < tc - window_s:
            continue
        d.qpos[:3] = r.pos_true
        roll, pitch, yaw = r.rpy_true
        mujoco.mju_euler2Quat(quat, np.array([yaw, pitch, roll]), "zyx")  # the simulator's ZYX angles
        d.qpos[3:7] = quat
        mujoco.mj_forward(m, d)
        for k, fan in fans.items():
            for tag, lim in limits.items():
                rng = sim.first_echo(tuple(r.pos_true), fan, accept=lambda inc, lim=lim: inc <= lim)
                if rng is None or rng >= near_m or (k, tag) in first:
                    continue
                if m.geom(sim._last_hit[3]).name.startswith("box"):
                    first[(k, tag)] = (tc - r.t, rng)
    for k in BEAMS:
        parts = []
        for tag in limits:
            f = first.get((k, tag))
            parts.append(f"{tag}: " + ("never" if f is None else f"{f[0]:.2f} s before contact, at {f[1]:.2f} m"))
        print(f"  {k:18s} " + "; ".join(parts))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenarios", nargs="+")
    ap.add_argument("--window", type=float, default=8.0, help="seconds before the contact to look at")
    ap.add_argument("--near", type=float, default=1.5, help="an echo nearer than this counts (m)")
    a = ap.parse_args()
    for p in a.scenarios:
        try:
            whatif(p, a.window, a.near)
        except InputError as err:
            sys.exit(f"error: {err}")


if __name__ == "__main__":
    main()
