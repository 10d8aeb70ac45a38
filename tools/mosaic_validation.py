"""Validation sweeps for the mosaicer's choices (issue 22): rendered like synth_rust_sweep over
textures the benchmark does not use, each with its exact frame-to-wall homographies, registered
with the focal length given and self-calibrated; corner error after one similarity.

    python tools/mosaic_validation.py [--data ../shared/data] [--work /tmp/mosaic_val] [--only NAME,...]
                                      [--focal both|given|self] [--set NAME=VALUE ...]

``--set`` changes a numeric RegisterParams field (``--set low_texture_side_px=320``) or an AlignParams
field (``--set align.pose_points_per_pair=12``), to score a variant on these sweeps.

The sweeps (``bench_mosaic.render_sweep``; the benchmark's own rows use walls/ photos _4, _29, _125 and the shared synthetic
sweeps, none of them here):

- eight walls/ photos (130, 143, 173, 196, 210, 257, 62, 87), the photo's centre square at
  2048 px, 5 passes of 33 frames (seeds 5-12);
- walls/ photo 7 twice (seeds 13, 14), same path;
- four photos at their own 1200 px, 3 passes of 16 (136, 197, 213, 85; seeds 15-18);
- the last three walls/ photos no sweep used, with plain grey paint beside their rust (88, 90, 91;
  seeds 19, 20, 23; added 2026-11-29), the centre square at 2048 px, 5 passes of 33;
- CrackForest's 37 unlabeled road images tiled into a 2048 px wall (seeds 21, 22).

Most of them are texture-poor (the sweep switches to equalised detection); docs/mosaic.md and
docs/benchmarks/mosaic_pose.md have the table of 2026-11-28.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from inspect_pipe.mosaic import RegisterParams  # noqa: E402
from inspect_pipe.mosaic._align import AlignParams  # noqa: E402
from inspect_pipe.mosaic._io import FolderSource  # noqa: E402
from inspect_pipe.mosaic._register import register  # noqa: E402
from inspect_pipe.mosaic.metrics import corner_error  # noqa: E402
from bench.bench_mosaic import render_sweep, wall_photo  # noqa: E402

FOCAL_PX = 618.0
PHOTO_SWEEPS = [(n, 5 + k, 2048, 5, 33) for k, n in enumerate((130, 143, 173, 196, 210, 257, 62, 87))] + [
    (7, 13, 2048, 5, 33), (7, 14, 2048, 5, 33),
    (136, 15, 1200, 3, 16), (197, 16, 1200, 3, 16), (213, 17, 1200, 3, 16), (85, 18, 1200, 3, 16),
    (88, 19, 2048, 5, 33), (90, 20, 2048, 5, 33), (91, 23, 2048, 5, 33),  # added 2026-11-29: plain grey paint
]
TILE_SEEDS = (21, 22)


def _tile_wall(data: Path, rng: np.random.Generator) -> np.ndarray:
    files = sorted((data / "defects" / "crackforest" / "image_unlabeled").glob("*.jpg"))
    tiles = [cv2.resize(cv2.imread(str(files[i])), (480, 320)) for i in rng.permutation(len(files))[:35]]
    wall = np.vstack([np.hstack(tiles[r * 5:(r + 1) * 5]) for r in range(7)])
    return cv2.resize(wall[:2240, :2400], (2048, 2048), interpolation=cv2.INTER_AREA)


def sweeps(data: Path, work: Path) -> dict[str, tuple[Path, dict[int, np.ndarray]]]:
    """Render every validation sweep once into ``work`` (kept: a second call reads the truth back)."""
    out = {}
    specs = [(f"photo_{n}_s{seed}", seed, lambda n=n, px=px: wall_photo(data / "walls" / f"vt_original_train_{n}.jpeg", px),
              passes, per) for n, seed, px, passes, per in PHOTO_SWEEPS]
    specs += [(f"crackforest_tiles_s{seed}", seed, None, 5, 33) for seed in TILE_SEEDS]
    for name, seed, make_wall, passes, per in specs:
        folder = work / name
        truth = folder / "truth.json"
        if not truth.is_file():
            rng = np.random.default_rng(seed)
            wall = make_wall() if make_wall else _tile_wall(data, rng)
            H = render_sweep(wall, folder / "frames", rng, passes, per)
            truth.write_text(json.dumps({str(k): v.tolist() for k, v in H.items()}))
        out[name] = (folder / "frames", {int(k): np.array(v) for k, v in json.loads(truth.read_text()).items()})
    return out


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--work", type=Path, default=Path("/tmp/mosaic_val"))
    ap.add_argument("--only", default="", help="comma-separated sweep names")
    ap.add_argument("--focal", choices=("both", "given", "self"), default="both", help="focal length given, self-calibrated or both")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="a RegisterParams field to change (number), e.g. --set low_texture_side_px=512, --set align.pose_max_nfev=100")
    args = ap.parse_args(argv)
    overrides, align = {}, {}
    for item in args.set:
        key, _, value = item.partition("=")
        group, name = (align, key.removeprefix("align.")) if key.startswith("align.") else (overrides, key)
        base = AlignParams() if group is align else RegisterParams()
        if name not in type(base).__dataclass_fields__ or not value:
            print(f"error: --set {item}: not NAME=VALUE with a RegisterParams (or align.AlignParams) field", file=sys.stderr)
            return 2
        kind = type(getattr(base, name))
        try:
            if kind not in (int, float, bool):
                raise ValueError
            group[name] = kind(float(value))
        except ValueError:
            print(f"error: --set {item}: {name} takes a number here", file=sys.stderr)
            return 2
    if align:
        overrides["align"] = replace(AlignParams(), **align)
    focals = {"both": (FOCAL_PX, None), "given": (FOCAL_PX,), "self": (None,)}[args.focal]
    only = {s for s in args.only.split(",") if s}
    needed = [args.data / "walls", args.data / "defects" / "crackforest" / "image_unlabeled"]
    missing = [str(p) for p in needed if not p.is_dir()]
    if missing:
        print(f"error: {missing[0]}: not found (give the shared data folder with --data)", file=sys.stderr)
        return 2
    print("| sweep | focal length | placed | groups | corner error median / max px | focal found | model | CPU |")
    print("|---|---|---|---|---|---|---|---|")
    for name, (frames, truth) in sweeps(args.data, args.work).items():
        if only and name not in only:
            continue
        for focal in focals:
            c0 = _cpu_s()
            reg = register(FolderSource(frames), params=RegisterParams(focal_px=focal, **overrides))
            cpu = _cpu_s() - c0
            g = reg.groups[0]
            ce = corner_error({f: g.H[f] for f in g.frames}, truth, reg.size_wh)
            placed = sum(len(x.frames) for x in reg.groups)
            f_found = f"{g.camera.f:.0f} px" if g.camera is not None else "-"
            print(f"| {name} | {'given' if focal else 'self-calibrated'} | {placed}/{len(truth)} | {len(reg.groups)} | "
                  f"{ce.median_px:.2f} / {ce.max_px:.2f} | {f_found} | {g.model} | {cpu:.0f} s |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
