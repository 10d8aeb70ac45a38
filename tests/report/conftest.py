"""A synthetic run directory with known geometry: mosaic px -> wall m is u = 3 + 0.005 x,
v = 3 - 0.005 y; six 200 x 150 frames on a 3 x 2 grid; a corrosion rectangle and a meandering crack."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from inspect_pipe.pipeline import RunStore
from inspect_pipe.pipeline._store import write_json

S = 0.005  # m per mosaic px
W_FROM_M = [[S, 0, 3.0], [0, -S, 3.0], [0, 0, 1]]
FRAME_WH = (200, 150)
OFFSETS = [(x, y) for y in (0, 120) for x in (0, 160, 320)]  # mosaic 520 x 270
CORROSION = (100, 60, 40, 20)  # x, y, w, h px -> centroid (119.5, 69.5), 800 px = 0.02 m^2
CRACK = ((300, 200), (325, 195), (350, 203), (375, 197), (400, 202))  # a meandering crack, about 103 px = 0.52 m (a straight line this long would be a seam)


def make_run(root: Path, *, survey: dict | None = None, seed: int = 0, painted: bool = False) -> RunStore:
    """``painted``: the demo's worn-paint texture (features at every scale, for registering two
    surveys) instead of blurred noise."""
    rng = np.random.default_rng(seed)
    store = RunStore(root)
    sweep = root / "input_sweep"
    (sweep / "images").mkdir(parents=True)
    mosaic = np.zeros((270, 520, 4), np.uint8)
    base = (rng.normal(128, 25, (270, 520, 3))).clip(0, 255).astype(np.uint8)
    base = cv2.GaussianBlur(base, (3, 3), 0)
    if painted:
        from inspect_pipe.pipeline._demo import paint

        base = paint(270, 520, rng)
    mosaic[:, :, :3] = base
    mosaic[:, :, 3] = 255
    lines = []
    frames = []
    for i, (ox, oy) in enumerate(OFFSETS):
        img = base[oy:oy + 150, ox:ox + 200]
        cv2.imwrite(str(sweep / "images" / f"{i:06d}.png"), img)
        lines.append(json.dumps({"index": i, "image": f"images/{i:06d}.png", "t_s": 0.1 * i, "exposure_s": 0.004}))
        frames.append({"index": i, "file": f"images/{i:06d}.png", "H": [[1, 0, ox], [0, 1, oy], [0, 0, 1]], "group": 0, "image": "mosaic.png"})
    (sweep / "frames.jsonl").write_text("\n".join(lines) + "\n")
    write_json(sweep / "sweep.json", {
        "format": "inspect_pipe.sweep/1", "software_version": "test",
        "camera": {"model": "pinhole_opencv", "name": "t", "width": 200, "height": 150,
                   "K": [[300, 0, 100], [0, 300, 75], [0, 0, 1]], "dist": [0, 0, 0, 0, 0]},
        "survey": survey if survey is not None else {"vessel": "MV Test", "hold": "2", "wall": "front", "frame_spacing_m": 0.8, "reference_frame": 112},
    })
    write_json(store.run_json, {"format": "inspect_pipe.run/1", "steps": {}, "input": {"spec": str(sweep), "kind": "sweep", "sweep": str(sweep)}})
    store.mosaic_dir.mkdir(parents=True)
    cv2.imwrite(str(store.mosaic_dir / "mosaic.png"), mosaic)
    write_json(store.mosaic_dir / "mosaic.json", {
        "format": "inspect_pipe.mosaic/1", "frames": frames, "unplaced": [], "m_per_px": S, "wall_from_mosaic": W_FROM_M,
        "wall_fit": {"rms_m": 0.01, "max_m": 0.02},
    })
    corr = np.zeros((270, 520), np.uint8)
    x, y, w, h = CORROSION
    corr[y:y + h, x:x + w] = 255
    crack = np.zeros((270, 520), np.uint8)
    cv2.polylines(crack, [np.array(CRACK, np.int32)], False, 255, 1)  # 5 mm wide
    store.save_class_map("mosaic", "corrosion", "mask", corr)
    store.save_class_map("mosaic", "corrosion", "prob", np.where(corr > 0, 240, 10).astype(np.uint8))
    store.save_class_map("mosaic", "crack", "mask", crack)
    store.save_class_map("mosaic", "crack", "prob", np.where(crack > 0, 200, 5).astype(np.uint8))
    write_json(store.detect_dir / "defects.json", {
        "format": "inspect_pipe.defects/1", "model": {"file": "defects_v1.npz", "version": "1", "operating_points": {"corrosion": 0.5}},
        "kinds": ["corrosion", "crack"], "images": [], "regions": [], "errors": [], "keyframes": [],
    })
    return store


@pytest.fixture
def run_dir(tmp_path) -> RunStore:
    return make_run(tmp_path / "run")
