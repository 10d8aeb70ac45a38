"""Writing a mosaic so that a run on bad input never replaces a good earlier one.

The mosaic step writes into a staging folder beside ``OUT``; the files then replace ``OUT``'s
mosaic files (``mosaic.json``, ``mosaic.png``, ``mosaic_group<k>.png``; nothing else in ``OUT``
is touched), ``mosaic.json`` last, so a crash mid-way leaves the earlier ``mosaic.json`` naming
images that are all there or the new one. A result with bad-input problems (unreadable or
truncated images, no overlap: ``MosaicOutput.problems``) is not published over an earlier mosaic
made without problems (its ``mosaic.json`` records ``problems: []``): that one is kept and the
result says so (``published`` False). Over nothing, or over an earlier result with problems of
its own, a result with problems is published, as ``mosaic`` documents ("after writing whatever
could be mosaicked").
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Callable

from inspect_pipe._files import write_json

from ._mosaic import MosaicOutput

#: The files a mosaic output consists of (what publishing replaces in OUT).
MOSAIC_FILES = ("mosaic.json", "mosaic.png", "mosaic_group*.png")


def staged(out_dir: Path, make: Callable[[Path], MosaicOutput]) -> MosaicOutput:
    """``make(staging)`` writes a mosaic into a fresh staging folder; its files then replace
    ``out_dir``'s mosaic files, unless the result has problems and ``out_dir`` holds a mosaic made
    without any (kept; the result's ``published`` is False and its first problem says so). The
    staging folder is removed in every case."""
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.staging-", dir=out_dir.parent))
    try:
        result = make(staging)
        doc_path = staging / "mosaic.json"
        if doc_path.is_file():  # what the run found wrong with its input, for the next run's decision
            doc = json.loads(doc_path.read_text())
            doc["problems"] = list(result.problems)
            write_json(doc_path, doc)
        if result.problems and _clean_earlier(out_dir):
            problems = [f"{result.problems[0]}; {out_dir} keeps its earlier mosaic, made without problems "
                        "(nothing of this run written)"] + result.problems[1:]
            return dataclasses.replace(result, out_dir=out_dir, images=[], problems=problems, published=False)
        _publish(staging, out_dir)
        return dataclasses.replace(result, out_dir=out_dir, images=[out_dir / p.name for p in result.images])
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _clean_earlier(out_dir: Path) -> bool:
    """Whether ``out_dir`` holds a mosaic whose run recorded no problems (one written before
    problems were recorded counts as clean: it is kept rather than lost)."""
    try:
        doc = json.loads((out_dir / "mosaic.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and doc.get("mosaic") is not None and not doc.get("problems")


def _publish(staging: Path, out_dir: Path) -> None:
    """Move the staged files into ``out_dir`` (images first, then ``mosaic.json``), then remove the
    earlier mosaic's images the new one does not have: at every moment ``mosaic.json`` names
    images that are there."""
    out_dir.mkdir(parents=True, exist_ok=True)
    new = {p.name for p in staging.iterdir()}
    for p in sorted(staging.iterdir(), key=lambda p: p.name == "mosaic.json"):  # mosaic.json last
        os.replace(p, out_dir / p.name)
    if "mosaic.json" not in new:
        (out_dir / "mosaic.json").unlink(missing_ok=True)
    for pattern in MOSAIC_FILES:
        for old in out_dir.glob(pattern):
            if old.name not in new:
                old.unlink()
