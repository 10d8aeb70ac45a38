"""Fuzzing (issue 23, item 2): 10,000 hypothesis-generated inputs through the product's readers of
every file it reads (scenario, survey plan, sweep.json, frames.jsonl, mosaic.json, both
defects.json, camera.yaml, the .npz and .onnx models, ULog and tlog) and through the MAVLink
live link's parser and handlers (random bytes, mutated frames, well-formed messages with nonsense
values). Allowed: a result or one line naming the file; a crash (traceback, multi-line or
unnamed error, printed chatter) or a hang (10 s per case) is a finding.

    python -m bench --only fuzz            (10,000 cases; FUZZ_CASES=N for another total)
"""

from __future__ import annotations

import os
import time
from pathlib import Path

TOTAL = 10_000


def run(data: Path) -> str:
    from bench._fuzz_targets import TARGETS, drive

    total = int(os.environ.get("FUZZ_CASES", TOTAL))
    names = list(TARGETS)
    per = -(-total // len(names))
    rows, sums, findings = [], dict(cases=0, ok=0, error=0, crash=0, hang=0), []
    t0 = time.perf_counter()
    for i, name in enumerate(names):
        t = drive(name, per, seed=2311 + i)
        print(f"  {name}: {t.cases} cases, {t.crash} crashes, {t.hang} hangs ({t.seconds:.0f} s)", flush=True)
        rows.append(f"| {name} | {t.cases} | {t.ok} | {t.error} | {t.crash} | {t.hang} | {1e3 * t.seconds / max(t.cases, 1):.1f} |")
        for k in sums:
            sums[k] += getattr(t, k)
        findings += [f"- {name}: {k}: {d}" for k, _, d in t.findings[:3]]
    wall = time.perf_counter() - t0
    out = [
        "## Fuzzing (issue 23, item 2)\n",
        f"{sums['cases']:,} fuzzed inputs (hypothesis, seeds 2311+): **{sums['crash']} tracebacks, {sums['hang']} hangs**; "
        f"{sums['error']:,} gave one line naming the file, {sums['ok']:,} a result. {wall:.0f} s. "
        "Each input is a valid file of its format (or a valid MAVLink frame) truncated, bit-flipped, overwritten, "
        "spliced or emptied, or its parsed document with one value replaced by another JSON value or a key deleted; "
        "MAVLink: random datagrams, mutated frames and well-formed messages of every type the link reads with "
        "arbitrary field values (NaN, infinities, out-of-range enums). A case may run 10 s.\n",
        "| target | cases | result | one-line error | crash | hang | ms per case |",
        "|---|---:|---:|---:|---:|---:|---:|",
        *rows,
        "",
        "Crash classes found and fixed while building the fuzzer (each kept as a regression in "
        "tests/reliability/test_fuzz.py): a scenario that is not UTF-8 (UnicodeDecodeError); a key with a newline "
        "echoed in a message (two lines: InputError now escapes control characters); a truncated, emptied or "
        "bit-flipped .npz model (EOFError, zipfile.BadZipFile, zlib.error); onnxruntime printing its 'EP Error' "
        "banner and log lines around a damaged .onnx model's one line; OpenCV's FileStorage reader aborting the "
        "process (SIGABRT) on a damaged !!opencv-matrix node of camera.yaml (now read with PyYAML).",
    ]
    if findings:
        out += ["", "Findings of this run:", *findings]
    return "\n".join(out)
