from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from inspect_pipe.mosaic.synthetic import SweepPath, lawnmower_homographies, render_frame, textured_wall

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures" / "mosaic"


@pytest.fixture(scope="session")
def synthetic_sweep(tmp_path_factory):
    """3 passes x 8 frames of 256x192 over a synthetic wall, with exact frame -> wall homographies."""
    rng = np.random.default_rng(42)
    path = SweepPath()
    wall = textured_wall(700, 560, rng)
    Hs = lawnmower_homographies(path, rng)
    folder = tmp_path_factory.mktemp("sweep")
    for i, H in enumerate(Hs):
        cv2.imwrite(str(folder / f"f{i:03d}.png"), render_frame(wall, H, path.frame_wh))
    return folder, {i: H for i, H in enumerate(Hs)}, path, wall


@pytest.fixture(scope="session")
def rust_mini():
    gt = json.loads((FIXTURES / "synth_rust_mini_gt.json").read_text())
    return FIXTURES / "synth_rust_mini", {i: np.array(h) for i, h in enumerate(gt["H_frame_to_canvas"])}, gt["focal_px"]
