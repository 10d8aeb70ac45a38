"""Small synthetic worlds for the capture tests: a textured wall scenario that flies in seconds."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from inspect_pipe.capture import CaptureConfig, ManualClock, read_sweep, run_capture
from inspect_pipe.capture.sources.sim import SimSource
from inspect_pipe.flight import load_scenario


def write_texture(path: Path, w: int = 600, h: int = 400, seed: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.standard_normal((h, w, 3)).astype(np.float32), (0, 0), 3)
    img = np.clip(128 + 45 * img / img.std(), 0, 255).astype(np.uint8)  # contrast like painted, rusty steel
    cv2.imwrite(str(path), img)
    return path


def write_scenario(folder: Path, *, duration_s: float = 8.0, width: int = 320, height: int = 240, texture: Path | None = None,
                   operator: list | None = None, name: str = "tiny_wall") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    texture = texture or write_texture(folder / "wall.png")
    doc = {
        "format": "inspect_pipe.scenario/1", "name": name, "duration_s": duration_s, "seed": 3,
        "world": {"hold": {"length_m": 12, "width_m": 10, "height_m": 16},
                  "front_wall_texture": {"image": texture.name, "m_per_px": 0.004, "origin_uv": [3.8, 2.0]}},
        "vehicle": {"start": {"position": [10.5, 0.0, 0], "yaw": 0}},
        "camera": {"fps": 10, "width": width, "height": height, "hfov_deg": 60},
        "operator": operator if operator is not None else [{"t": 0.5, "button": "takeoff"},
                                                           {"t": 4.0, "stick": {"vx": 0, "vy": -0.2, "vz": 0, "yaw_rate": 0}}],
    }
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.fixture(scope="session")
def sim_sweep(tmp_path_factory) -> Path:
    """A complete simulated sweep: 8 s of flight at 10 Hz, 320x240."""
    root = tmp_path_factory.mktemp("simsweep")
    sc = load_scenario(write_scenario(root / "scenario"))
    clock = ManualClock()
    res = run_capture(SimSource(sc, clock=clock), root / "sweep", clock=clock,
                      config=CaptureConfig(time_base="simulation_s", rate_hz=10))
    assert res.frames_written > 70, res
    return root / "sweep"


def copy_sweep(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst)
    return dst


@pytest.fixture
def sweep_copy(sim_sweep, tmp_path) -> Path:
    return copy_sweep(sim_sweep, tmp_path / "copy")


__all__ = ["copy_sweep", "read_sweep", "write_scenario", "write_texture"]
