"""Run the benchmarks and rewrite docs/BENCHMARKS.md.

    python -m bench [--data ../shared/data] [--only mosaic,flight]

Each module ``bench/bench_<name>.py`` exposes ``run(data: Path) -> str`` (a Markdown section).
A section is stored in ``docs/benchmarks/<name>.md`` with the machine and date it was measured
on, so one benchmark can be re-run alone; ``docs/BENCHMARKS.md`` is always rebuilt from all
stored sections.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import importlib
import os
import platform
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SECTIONS = ROOT / "docs" / "benchmarks"
DOC = ROOT / "docs" / "BENCHMARKS.md"


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        import psutil

        mem = f"{psutil.virtual_memory().total / 2**30:.0f} GiB"
    except Exception:  # psutil is a dependency; this only guards odd platforms
        mem = "? GiB"
    return f"{cpu}, {os.cpu_count()} cores, {mem}, Python {platform.python_version()}"


def available() -> list[str]:
    return sorted(p.stem[len("bench_"):] for p in Path(__file__).parent.glob("bench_*.py"))


def rebuild_doc() -> None:
    parts = [
        "# Benchmarks\n",
        "Written by `make bench` (`python -m bench`). Each section names the machine and date it was "
        "measured on; ratios are against the peer measured in the same run, because these machines "
        "are shared and noisy.\n",
    ]
    for path in sorted(SECTIONS.glob("*.md")):
        parts.append(path.read_text().rstrip() + "\n")
    DOC.write_text("\n".join(parts))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench")
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--only", default="", help="comma-separated names, e.g. mosaic,flight")
    args = ap.parse_args(argv)
    names = [n for n in args.only.split(",") if n] or available()
    SECTIONS.mkdir(parents=True, exist_ok=True)
    for name in names:
        if name not in available():
            print(f"error: no benchmark named {name!r}; have {', '.join(available())}", file=sys.stderr)
            return 2
        print(f"== bench {name}", flush=True)
        module = importlib.import_module(f"bench.bench_{name}")
        body = module.run(args.data)
        stamp = _dt.datetime.now().strftime("%Y-%m-%d %H:%M")
        SECTIONS.joinpath(f"{name}.md").write_text(
            f"{body.rstrip()}\n\n_Measured {stamp} on {machine()}._\n"
        )
    rebuild_doc()
    print(f"wrote {DOC.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
