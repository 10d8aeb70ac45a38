"""Calibrate `compare`'s noise rule on demo walls other than the bench's (docs/report.md, session 30).

Each wall (default 6-10; the bench's wall 5 is the evaluation) is flown unchanged with three flight
seeds (default 21, 22, 23) and every pair compared; the same wall edited (``edit_demo_wall``: 3
corrosion patches appear, 2 grow) is flown with the second seed and compared with the first flight.
Every group is then classified again, without flying, for a grid of noise figures (absolute cm² and
share of the larger area), and the table prints false changes on the unchanged pairs, true changes
reported (new or grown within 10 cm) and false changes on the edited walls.

    python tools/compare_calibration.py OUT_DIR [--walls 6,7,8,9,10] [--flights 21,22,23]

About 25 s a flight on 2 cores (20 flights for the defaults); flights already in OUT_DIR are reused.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.bench_compare import match_truth  # noqa: E402
from bench.bench_register import fly  # noqa: E402
from inspect_pipe.pipeline._demo import build_demo_wall, edit_demo_wall  # noqa: E402
from inspect_pipe.report._compare import CompareParams, _status, compare_runs  # noqa: E402

DATA = ROOT.parent / "shared" / "data"


def _flown(out: Path, wall, wall_seed: int, flight_seed: int) -> Path:
    if not (out / "report" / "defects.json").is_file():
        fly(DATA, out, wall_seed, flight_seed, wall=wall)
    return out


def _groups(old: Path, new: Path) -> list[dict]:
    """Every group compare makes of the pair, with what the status rule needs."""
    c = compare_runs(old, new)
    return [dict(a_old=ch.area_old_m2, a_new=ch.area_new_m2, po=ch.prob_area_old_m2, pn=ch.prob_area_new_m2,
                 missing="old" if not ch.old_ids else "new", c=ch.centroid_wall_m)
            for ch in c.changes + c.below_noise]  # not_compared groups are never changes


def _changes(groups: list[dict], params: CompareParams) -> list[tuple[str, tuple[float, float]]]:
    out = []
    for g in groups:
        status, _ = _status(g["a_old"], g["a_new"], g["po"], g["pn"], params, "", g["missing"])
        if status == "unchanged" or (status in ("new", "gone") and max(g["a_old"], g["a_new"]) < params.new_min_m2):
            continue
        out.append((status, g["c"]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--walls", default="6,7,8,9,10")
    ap.add_argument("--flights", default="21,22,23")
    a = ap.parse_args()
    if not (DATA / "defects" / "vt_corrosion_cs" / "images").is_dir():
        print(f"error: {DATA / 'defects' / 'vt_corrosion_cs'}: not found (the demo walls are cut from it; run from a checkout "
              "beside shared/data)", file=sys.stderr)
        sys.exit(2)
    walls = [int(x) for x in a.walls.split(",")]
    flights = [int(x) for x in a.flights.split(",")]
    same, edited = [], []  # (label, groups) / (label, groups, truth)
    for w in walls:
        wall = build_demo_wall(a.out / f"wall{w}", DATA, seed=w)
        runs = {f: _flown(a.out / f"w{w}_f{f}", wall, w, f) for f in flights}
        for x, y in itertools.combinations(flights, 2):
            same.append((f"wall {w}, flights {x}/{y}", _groups(runs[x], runs[y])))
        ed, truth = edit_demo_wall(wall, a.out / f"wall{w}_edited", DATA)
        e = _flown(a.out / f"e{w}_f{flights[1]}", ed, w, flights[1])
        edited.append((f"wall {w} edited", _groups(runs[flights[0]], e), [t.to_json() for t in truth]))
        print(f"wall {w}: flown and compared", flush=True)
    print("| noise (cm² + share) | false changes, unchanged pairs | pairs with one | true changes reported | false changes, edited |")
    print("|---|---:|---:|---:|---:|")
    for ab, rel in itertools.product((4, 6, 8, 12), (0.25, 0.30, 0.35)):
        p = CompareParams(noise_abs_m2=ab * 1e-4, noise_rel=rel)
        fs = [len(_changes(g, p)) for _, g in same]
        hit = tot = fe = 0
        for _, g, truth in edited:
            ch = _changes(g, p)
            found = match_truth(ch, truth)
            tot += len(truth)
            hit += sum(f is not None for f in found)
            fe += len(ch) - len({f[0] for f in found if f is not None})
        print(f"| {ab} + {rel:.0%} | {sum(fs)} | {sum(f > 0 for f in fs)} / {len(fs)} | {hit} / {tot} | {fe} |")


if __name__ == "__main__":
    main()
