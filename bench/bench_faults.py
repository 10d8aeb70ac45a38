"""Fault injection (issue 23, item 1): rounds of 13 faults (SIGKILL at a random moment of capture,
import, mosaic, detect, report and run; disk full during mosaic and run; a read-only output
for mosaic and report; the camera vanishing mid-capture; the MAVLink link dying mid-capture;
corrupt PNG/JPEG frames in a sweep) against the uninterrupted runs on the same 5 s simulated
sweep. Promise per fault: no file half-written, the rerun finishes, and its result equals the
uninterrupted run's (bench/_faults.py says how each is compared).

    python -m bench --only faults          (45 rounds: 585 faults, about 540 of them injected; FAULT_ROUNDS=N for another count)

Rounds are independent (round k draws from its own seed, [2311, k]) and run in FAULT_WORKERS
processes (default 2, the machine's cores), each on its own work folder; the figure does not
depend on the number of workers.
"""

from __future__ import annotations

import collections
import concurrent.futures
import os
import tempfile
import time
from pathlib import Path

ROUNDS = 45
WORKERS = 2


def _round(fx, work: Path, k: int, mounts: bool) -> list:
    import shutil

    import numpy as np

    from bench import _faults as F

    try:
        return F.one_round(fx, work, np.random.default_rng([2311, k]), mounts=mounts)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def run(data: Path) -> str:
    import numpy as np

    from bench import _faults as F

    rounds = int(os.environ.get("FAULT_ROUNDS", ROUNDS))
    with tempfile.TemporaryDirectory(prefix="faults-") as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        fx = F.build(tmp / "fixture")
        mounts = F.can_mount(tmp)
        workers = max(1, int(os.environ.get("FAULT_WORKERS", WORKERS)))
        results = []
        with concurrent.futures.ProcessPoolExecutor(workers) as pool:
            jobs = [pool.submit(_round, fx, tmp / f"work{k}", k, mounts) for k in range(rounds)]
            for k, job in enumerate(jobs):
                rs = job.result()
                results += rs
                print(f"  round {k + 1}/{rounds}: {sum(r.recovered for r in rs)}/{len(rs)} recovered", flush=True)
                for r in rs:
                    if not r.recovered:
                        print(f"    {r.fault}: {r.detail}", flush=True)
        wall = time.perf_counter() - t0
    by = collections.OrderedDict()
    for r in results:
        by.setdefault(r.fault, []).append(r)
    injected = sum(r.injected for r in results)
    recovered = sum(r.recovered for r in results if r.injected)
    lost = sum(r.lost for r in results)
    rows = [f"| {name} | {len(rs)} | {sum(r.injected for r in rs)} | {sum(r.recovered for r in rs if r.injected)} | "
            f"{sum(r.lost for r in rs)} | {next((r.detail for r in rs if r.injected), '')[:90]} |" for name, rs in by.items()]
    fails = [f"- {r.fault}: {r.detail}" for r in results if r.injected and not r.recovered][:10]
    out = [
        "## Fault injection (issue 23, item 1)\n",
        f"**{injected} injected, {recovered} recovered, {lost} lost** ({rounds} rounds of {len(results) // max(rounds, 1)} faults, "
        f"{wall / 60:.0f} min, {workers} worker processes). Input: a 5 s simulated flight past a textured wall (320x240, 10 Hz; the reference sweep, "
        "its mosaic, detections, run and report made once uninterrupted). A kill is counted injected when the process was "
        "still running at the moment drawn (uniform over its uninterrupted duration); disk full and read-only use a "
        "tmpfs (root) with a random 5-90 % of the room the output needs. Recovered: no file half-written (every JSON parses, "
        "every image decodes, every frames.jsonl line but a cut last one parses), the rerun exits 0, and its result equals "
        "the reference: a sweep's frame lines and decoded pixels (a killed capture's frames are the reference's first ones; a killed import's sweep, renamed into place whole, is the reference's), "
        "mosaic.json's frames and H and the mosaic's bytes, the detections' regions, the register's entries; a full or "
        "read-only disk gives one `error:` line with exit 2 first. Camera lost: the frames before the loss equal the "
        "reference's. Link died: every frame written, state null only after the silence. Corrupt frames: "
        "`mosaic --verify` unplaces them and places the same other frames as the sweep without them, every frame corner within 0.5 px.\n",
        "| fault | runs | injected | recovered | lost | example |",
        "|---|---:|---:|---:|---:|---|",
        *rows,
    ]
    if not mounts:
        out += ["", "disk-full and read-only were not run: no tmpfs could be mounted (needs root)."]
    if fails:
        out += ["", "Not recovered:", *fails]
    return "\n".join(out)
