"""Writing a mosaic so that a run on bad input never replaces a good earlier one.

The callers check their input first (a missing or empty folder, a sweep without readable frames:
nothing is written). The mosaic step then writes into a staging folder inside ``OUT``
(``OUT/.staging-*``: the same file system, whatever ``OUT`` links to), and its files replace
``OUT``'s mosaic files (``mosaic.json``, ``mosaic.png``, ``mosaic_group<k>.png``; nothing else in
``OUT`` is touched): the earlier ``mosaic.json`` is removed first and the new one moved in last, so
a crash in between leaves no ``mosaic.json`` (no mosaic, which the next run replaces), never one
beside images that are not its own. A result with bad-input problems (unreadable or truncated
images, no overlap: ``MosaicOutput.problems``) is not published over an earlier mosaic made without
problems (its ``mosaic.json`` records ``problems: []`` and every image it names is whole): that
one is kept and the result says so (``published`` False). Over nothing, or over an earlier result
with problems of its own, a result with problems is published, as ``mosaic`` documents ("after
writing whatever could be mosaicked").
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
from inspect_pipe._images import truncation
from inspect_pipe.errors import InputError

from ._mosaic import MosaicOutput

#: The files a mosaic output consists of (what publishing replaces in OUT).
MOSAIC_FILES = ("mosaic.json", "mosaic.png", "mosaic_group*.png")


def check_out(out_dir: Path) -> None:
    """Before any work: ``out_dir`` must be a folder or not there yet."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(str(out_dir), "a file is there, where the mosaic's folder is written", "give another -o, or move the file")


def staged(out_dir: Path, make: Callable[[Path], MosaicOutput]) -> MosaicOutput:
    """``make(staging)`` writes a mosaic into a fresh staging folder inside ``out_dir``; its files
    then replace ``out_dir``'s mosaic files, unless the result has problems and ``out_dir`` holds a
    whole mosaic made without any (kept; the result's ``published`` is False and its first problem
    says so). The staging folder is removed in every case."""
    out_dir = Path(out_dir)
    check_out(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".staging-", dir=out_dir))
    try:
        result = make(staging)
        doc_path = staging / "mosaic.json"
        if doc_path.is_file():  # what the run found wrong with its input, for the next run's decision
            doc = json.loads(doc_path.read_text())
            doc["problems"] = list(result.problems)
            write_json(doc_path, doc)
        if result.problems and _clean_earlier(out_dir):
            first = result.problems[0].replace(", listed in mosaic.json)", ")")  # this run's mosaic.json is not written
            problems = [f"{first}; {out_dir} keeps its earlier mosaic, made without problems (nothing of this run written)"]
            return dataclasses.replace(result, out_dir=out_dir, images=[], problems=problems + result.problems[1:],
                                       published=False)
        _publish(staging, out_dir)
        return dataclasses.replace(result, out_dir=out_dir, images=[out_dir / p.name for p in result.images])
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _clean_earlier(out_dir: Path) -> bool:
    """Whether ``out_dir`` holds a whole mosaic whose run recorded no problems: its ``mosaic.json``
    reads, names a mosaic, records none (one written before problems were recorded counts as
    clean), and every image it names is there and not cut short."""
    try:
        doc = json.loads((out_dir / "mosaic.json").read_text())
    except (OSError, ValueError):
        return False
    if not isinstance(doc, dict) or doc.get("mosaic") is None or doc.get("problems"):
        return False
    names = {doc["mosaic"]} | {g.get("image") for g in doc.get("groups") or [] if isinstance(g, dict)}
    return all(isinstance(n, str) and not truncation(out_dir / n) for n in names if n is not None)


def _publish(staging: Path, out_dir: Path) -> None:
    """Remove the earlier ``mosaic.json``, move the staged images in, then the new ``mosaic.json``,
    then remove the earlier images the new mosaic does not have."""
    new = {p.name for p in staging.iterdir()}
    (out_dir / "mosaic.json").unlink(missing_ok=True)
    for p in sorted(staging.iterdir(), key=lambda p: p.name == "mosaic.json"):  # mosaic.json last
        os.replace(p, out_dir / p.name)
    for pattern in MOSAIC_FILES:
        for old in out_dir.glob(pattern):
            if old.name not in new:
                old.unlink()
