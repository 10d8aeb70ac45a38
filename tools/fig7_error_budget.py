"""Fig. 7's inspection passes: how far each lateral pass's mean true speed is from 0.20 m/s, with
the simulator's error sources turned off one at a time, and the shipped code's per-pass error split
into the estimate's error (truth against estimate) and the speed loop's (estimate against command).

The passes are the windows the scenario test measures (10.0-15.5, 23.0-26.5 and 33.0-35.5 s of
``scenarios/fig7_inspection_sweep.yaml``); a pass is off when its mean is more than 0.01 m/s from
0.20. About 0.7 s of CPU a seed and a variant.

    python tools/fig7_error_budget.py --seeds 501-540 [--variants shipped,no_disturbance,...]

Seeds 501-540 are the analysis seeds of docs/flight.md (session 32); give fresh ones to check.
"""

from __future__ import annotations

import argparse
import dataclasses as dc
import math
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from inspect_pipe.flight.runner import SimParts, run_scenario  # noqa: E402
from inspect_pipe.flight.scenario import load_scenario  # noqa: E402

PASSES = ((10.0, 15.5), (23.0, 26.5), (33.0, 35.5))
TOLERANCE_M_S = 0.01


def _parts(variant: str) -> SimParts:
    """The embedded simulator with one error source at zero."""
    p = SimParts()
    s = p.sensors
    if variant == "shipped":
        return p
    if variant == "no_disturbance":
        return dc.replace(p, vehicle=dc.replace(p.vehicle, disturbance_force_n=0.0))
    if variant == "no_attitude_error":
        a = dc.replace(s.attitude, level_bias_rad=0.0, drift_rad=0.0, accel_coupling=0.0, gyro_scale=0.0)
        return dc.replace(p, sensors=dc.replace(s, attitude=a))
    if variant == "no_flow_bias":
        f = dc.replace(s.flow, bias_m_s=0.0, gyro_bias_rad_s=0.0, gyro_scale=0.0)
        return dc.replace(p, sensors=dc.replace(s, flow=f))
    if variant == "no_flow_noise":
        f = dc.replace(s.flow, noise_rad_s=0.0, gyro_noise_rad_s=0.0)
        return dc.replace(p, sensors=dc.replace(s, flow=f))
    if variant == "no_imu_error":
        i = dc.replace(s.imu, bias_m_s2=0.0, noise_m_s2=0.0, vibration_m_s2=0.0)
        return dc.replace(p, sensors=dc.replace(s, imu=i))
    raise SystemExit(f"fig7_error_budget: unknown variant {variant!r}; give one of {', '.join(VARIANTS)}")


VARIANTS = ("shipped", "no_disturbance", "no_attitude_error", "no_flow_bias", "no_flow_noise", "no_imu_error")


def _rms(xs: list[float]) -> float:
    return math.sqrt(statistics.fmean(x * x for x in xs))


def budget(variant: str, seeds: range) -> dict:
    base = load_scenario(ROOT / "scenarios" / "fig7_inspection_sweep.yaml")
    parts = _parts(variant)
    off, est_err, track = [], [], []
    for seed in seeds:
        ticks = []
        run_scenario(dc.replace(base, seed=seed), parts=parts, on_tick=ticks.append)
        for t0, t1 in PASSES:
            sel = [r for r in ticks if t0 <= r.t <= t1]
            off.append(abs(statistics.fmean(r.vel_true[1] for r in sel)) - 0.2)
            # Heading-frame lateral speed: the frame of the estimate and the command.
            true_h = statistics.fmean(math.cos(r.yaw_true) * r.vel_true[1] - math.sin(r.yaw_true) * r.vel_true[0] for r in sel)
            est = statistics.fmean(r.out.estimate.vy_m_s for r in sel)
            est_err.append(true_h - est)
            track.append(est - statistics.fmean(r.out.command.vy_m_s for r in sel))
    return {
        "variant": variant, "passes": len(off), "off": sum(abs(e) > TOLERANCE_M_S for e in off),
        "worst_m_s": max(map(abs, off)), "rms_m_s": _rms(off),
        "estimate_rms_m_s": _rms(est_err), "tracking_rms_m_s": _rms(track),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="501-540", help="LO-HI, inclusive")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    a = ap.parse_args(argv)
    try:
        lo, hi = (int(x) for x in a.seeds.split("-"))
    except ValueError:
        raise SystemExit(f"fig7_error_budget: --seeds {a.seeds!r} is not LO-HI (e.g. 501-540)") from None
    print("| turned off | passes off | worst (m/s) | rms (m/s) | estimate rms | tracking rms |")
    print("|---|---:|---:|---:|---:|---:|")
    for v in a.variants.split(","):
        r = budget(v.strip(), range(lo, hi + 1))
        print(f"| {r['variant']} | {r['off']} / {r['passes']} | {r['worst_m_s']:.4f} | {r['rms_m_s']:.4f} "
              f"| {r['estimate_rms_m_s']:.4f} | {r['tracking_rms_m_s']:.4f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
