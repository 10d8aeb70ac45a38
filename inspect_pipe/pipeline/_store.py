"""RunStore: the one class that knows every path of a run directory.

    RUN/run.json             inspect_pipe.run/1: input, and per finished step its effective config
    RUN/sweep/               capture step (a flown scenario or a live source); a sweep input is not copied
    RUN/mosaic/              mosaic.png, mosaic.json (inspect_pipe.mosaic/1)
    RUN/detect/              defects.json (inspect_pipe.defects/1), mosaic.{prob,mask}.png,
                             mosaic.<class>.{prob,mask}.png, frames/<index>.<class>.mask.png
    RUN/report/              report.html, report.pdf, defects.json, defects.csv, coco.json, assets/
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from inspect_pipe._files import write_json, write_png
from inspect_pipe._images import imread, truncation
from inspect_pipe.errors import InputError

RUN_FORMAT = "inspect_pipe.run/1"
DEFECTS_FORMAT = "inspect_pipe.defects/1"




def _whole_json(path: Path) -> bool:
    """A step's JSON artifact is there and parses (one cut by a crash or a copy is no output: the step runs again)."""
    try:
        return isinstance(json.loads(path.read_text(encoding="utf-8")), dict)
    except (OSError, ValueError):
        return False


def _whole_image(path: Path) -> bool:
    return path.is_file() and not truncation(path)


def read_png(path: Path, flags: int = cv2.IMREAD_UNCHANGED) -> np.ndarray:
    if not path.is_file():
        raise InputError(str(path), "missing")
    why = truncation(path)
    img = None if why else imread(str(path), flags)
    if img is None:
        raise InputError(str(path), why or "unreadable image")
    return img


class RunStore:
    """Paths, existence checks, loaders and savers of one run directory."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    # ------------------------------------------------------------------ run.json
    @property
    def run_json(self) -> Path:
        return self.root / "run.json"

    def run_exists(self) -> bool:
        return self.run_json.is_file()

    def load_run(self) -> dict:
        if not self.run_exists():
            return {"format": RUN_FORMAT, "steps": {}}
        try:
            doc = json.loads(self.run_json.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError):
            raise InputError(str(self.run_json), "not valid JSON", "delete it to start the run afresh") from None
        if not isinstance(doc, dict) or doc.get("format") != RUN_FORMAT:
            raise InputError(str(self.run_json), f"field 'format': expected {RUN_FORMAT!r}")
        doc.setdefault("steps", {})
        return doc

    def save_run(self, doc: dict) -> None:
        write_json(self.run_json, doc)

    def step_record(self, step: str) -> dict | None:
        return self.load_run()["steps"].get(step)

    def mark_step(self, step: str, record: dict) -> None:
        doc = self.load_run()
        doc["steps"][step] = record
        self.save_run(doc)

    def forget_step(self, step: str) -> None:
        doc = self.load_run()
        if doc["steps"].pop(step, None) is not None:
            self.save_run(doc)

    # ------------------------------------------------------------------ sweep
    @property
    def sweep_dir(self) -> Path:
        return self.root / "sweep"

    def sweep_exists(self) -> bool:
        return (self.sweep_dir / "sweep.json").is_file() and (self.sweep_dir / "COMPLETE").is_file()

    def input_sweep(self) -> Path | None:
        """The sweep this run works on: its own capture, or the input sweep recorded in run.json."""
        if (self.sweep_dir / "sweep.json").is_file():
            return self.sweep_dir
        inp = self.load_run().get("input") or {}
        p = inp.get("sweep")
        return Path(p) if p else None

    def load_sweep(self):
        from inspect_pipe.capture import read_sweep

        p = self.input_sweep()
        return read_sweep(p) if p is not None else None

    # ------------------------------------------------------------------ mosaic
    @property
    def mosaic_dir(self) -> Path:
        return self.root / "mosaic"

    def mosaic_exists(self) -> bool:
        return _whole_json(self.mosaic_dir / "mosaic.json") and _whole_image(self.mosaic_dir / "mosaic.png")

    def load_mosaic_json(self) -> dict:
        from inspect_pipe.report._geo import read_json

        path = self.mosaic_dir / "mosaic.json"
        if not path.is_file():
            raise InputError(str(path), "missing", "run the mosaic step first: inspect-pipe run INPUT -o RUN")
        doc = read_json(path)
        if doc.get("format") != "inspect_pipe.mosaic/1":
            raise InputError(str(path), f"field 'format': {doc.get('format')!r}", "expected 'inspect_pipe.mosaic/1'")
        from inspect_pipe.formats import MosaicJson, validate

        validate(MosaicJson, doc, str(path), "docs/mosaic.md describes mosaic.json; run --rerun-from mosaic to write it again")
        return doc

    def load_mosaic_image(self) -> np.ndarray:
        """BGRA mosaic (alpha 255 where a frame covers the wall)."""
        img = read_png(self.mosaic_dir / "mosaic.png")
        if img.ndim == 2:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGRA)
        elif img.shape[2] == 3:
            img = np.dstack([img, np.full(img.shape[:2], 255, np.uint8)])
        return img

    # ------------------------------------------------------------------ detect
    @property
    def detect_dir(self) -> Path:
        return self.root / "detect"

    def detect_exists(self) -> bool:
        return _whole_json(self.detect_dir / "defects.json")

    def load_detections(self) -> dict:
        from inspect_pipe.report._geo import read_json

        path = self.detect_dir / "defects.json"
        if not path.is_file():
            raise InputError(str(path), "missing", "run the detect step first: inspect-pipe run INPUT -o RUN")
        doc = read_json(path)
        if doc.get("format") != DEFECTS_FORMAT:
            raise InputError(str(path), f"field 'format': {doc.get('format')!r}", f"expected {DEFECTS_FORMAT!r}")
        from inspect_pipe.formats import DetectionsJson, validate

        validate(DetectionsJson, doc, str(path), "run --rerun-from detect to write it again")
        return doc

    def class_map_path(self, image: str, cls: str, what: str) -> Path:
        """what: 'mask' or 'prob'; image: 'mosaic' or a frame index."""
        sub = self.detect_dir if image == "mosaic" else self.detect_dir / "frames"
        return sub / f"{image}.{cls}.{what}.png"

    def save_class_map(self, image: str, cls: str, what: str, arr: np.ndarray) -> None:
        write_png(self.class_map_path(image, cls, what), arr)

    def load_class_map(self, image: str, cls: str, what: str) -> np.ndarray:
        return read_png(self.class_map_path(image, cls, what), cv2.IMREAD_GRAYSCALE)

    # ------------------------------------------------------------------ report
    @property
    def report_dir(self) -> Path:
        return self.root / "report"

    def report_exists(self) -> bool:
        d = self.report_dir
        return (d / "report.html").is_file() and _whole_json(d / "defects.json")
