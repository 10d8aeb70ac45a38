"""A simulated flight as a real drone leaves it: the sweep's frames as JPEGs whose only time is
EXIF DateTimeOriginal / SubSecTimeOriginal / OffsetTimeOriginal, on a camera clock that is off.

    inspect-pipe fly --scenario scenarios/inspection_sweep_wall.yaml --log out/f.jsonl --sweep out/sweep --tlog out/f.tlog
    .venv/bin/python tools/sweep_to_footage.py out/sweep out/DCIM --clock-offset 3.2 --utc-offset-h 2
    inspect-pipe import out/DCIM --log out/f.tlog -o out/imported

``--clock-offset`` is the camera's error (camera time minus true time, s); ``import`` should find it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from inspect_pipe.errors import InputError  # noqa: E402
from inspect_pipe.importer import write_drone_footage  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="tools/sweep_to_footage.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("sweep", type=Path, help="sweep directory (fly --sweep, capture)")
    ap.add_argument("out", type=Path, help="folder for the JPEGs")
    ap.add_argument("--clock-offset", type=float, required=True, help="camera clock error, s (camera minus true)")
    ap.add_argument("--utc-offset-h", type=float, default=0.0, help="the camera's time zone (OffsetTimeOriginal), hours")
    ap.add_argument("--quality", type=int, default=92, help="JPEG quality")
    a = ap.parse_args(argv)
    try:
        n = write_drone_footage(a.sweep, a.out, clock_offset_s=a.clock_offset, utc_offset_h=a.utc_offset_h, quality=a.quality)
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"{n} JPEGs in {a.out} (camera clock {a.clock_offset:+.3f} s, UTC{a.utc_offset_h:+g} h)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
