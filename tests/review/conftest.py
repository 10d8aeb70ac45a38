"""A real run directory (``run_pipeline`` on the mini rusty-folder fixture: mosaic, detect,
report), whose detections are then replaced by a known set drawn into the mosaic's class masks
(12 corrosion patches and 2 meandering cracks) and its report redone: a register of 14 entries
that ``inspect-pipe run`` keeps working on. Built once per session (about 20 s); each test gets a copy."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "mosaic" / "synth_rust_mini"
PATCHES = [(60 + 85 * i, 60 + 95 * j) for j in range(3) for i in range(4)]  # mosaic px, radius 9 px (2 mm/px)
CRACKS = [((40, 300), (52, 305), (64, 297), (76, 306), (88, 299), (100, 304)),
          ((300, 40), (306, 52), (298, 64), (305, 76), (299, 88))]


def run_args(src: Path, out: Path) -> list[str]:
    """``inspect-pipe run`` with the fixture's options (so a later run skips what is done)."""
    return ["run", str(src), "-o", str(out), "--focal-px", "618", "--m-per-px", "0.002", "--keyframe-spacing", "0", "--engine", "saliency"]


def _cfg(src: Path):
    from cli.run import build_config

    return build_config(str(src), kinds="all", keyframe_spacing=0.0, scheme="MSC.1/Circ.1330", area_m=1.0, no_pdf=False,
                        m_per_px=0.002, focal_px=618.0, engine="saliency")  # its detections are replaced: the engine that ships in the package


@pytest.fixture(scope="session")
def review_source(tmp_path_factory) -> tuple[Path, Path]:
    """(frames folder, run directory) of the session's run; copy before changing it."""
    from inspect_pipe.pipeline import RunStore, run_pipeline

    root = tmp_path_factory.mktemp("review")
    src = root / "frames"
    shutil.copytree(FIXTURE, src)
    run = root / "run"
    run_pipeline(run, _cfg(src), log=lambda s: None)
    store = RunStore(run)
    h, w = cv2.imread(str(store.mosaic_dir / "mosaic.png"), cv2.IMREAD_UNCHANGED).shape[:2]
    corr = np.zeros((h, w), np.uint8)
    for x, y in PATCHES:
        cv2.circle(corr, (x, y), 9, 255, -1)
    crack = np.zeros((h, w), np.uint8)
    for line in CRACKS:
        cv2.polylines(crack, [np.array(line, np.int32)], False, 255, 2)
    for cls, m in (("corrosion", corr), ("crack", crack)):
        store.save_class_map("mosaic", cls, "mask", m)
        store.save_class_map("mosaic", cls, "prob", np.where(m > 0, 230, 5).astype(np.uint8))
    shutil.rmtree(store.report_dir)
    run_pipeline(run, _cfg(src), log=lambda s: None)  # the report again (its output is gone), from these detections
    doc = json.loads((store.report_dir / "defects.json").read_text())
    assert [d["class"] for d in doc["defects"]].count("corrosion") == 12, [d["class"] for d in doc["defects"]]
    assert [d["class"] for d in doc["defects"]].count("crack") == 2
    return src, run


@pytest.fixture
def review_run(review_source, tmp_path) -> tuple[Path, Path]:
    """(frames folder, a copy of the session's run directory)."""
    src, run = review_source
    dst = tmp_path / "run"
    shutil.copytree(run, dst)
    return src, dst
