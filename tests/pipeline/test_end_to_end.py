"""One end-to-end run on a tiny simulated inspection: fly -> sweep -> mosaic -> detect -> report."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from inspect_pipe.pipeline import run_pipeline
from inspect_pipe.pipeline._demo import SHIPPED_MASK, SHIPPED_WALL, DEMO_SURVEY
from inspect_pipe.pipeline._steps import DetectConfig, RunConfig

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.skipif(not SHIPPED_WALL.is_file(), reason="scenario asset missing")
def test_tiny_simulated_run_end_to_end(tmp_path):
    # GIVEN an 8 s flight, 1 m right along the shipped CC0 corroded wall, camera 376 x 240 at 10 Hz
    sc = yaml.safe_load((REPO / "scenarios" / "inspection_sweep_wall.yaml").read_text())
    sc.update(name="tiny", duration_s=8.0)
    sc["camera"] = {"fps": 10, "width": 376, "height": 240, "hfov_deg": 60}
    sc["world"]["front_wall_texture"] = {"image": str(SHIPPED_WALL), "m_per_px": 0.003, "origin_uv": [3.0, 2.2],
                                         "defects_mask": str(SHIPPED_MASK)}
    sc["operator"] = [{"t": 0.5, "button": "takeoff"}, {"t": 3.0, "button": "inspection_mode_on"},
                      {"t": 3.5, "stick": {"vx": 0, "vy": -0.3, "vz": 0, "yaw_rate": 0}},
                      {"t": 7.5, "stick": {"vx": 0, "vy": 0, "vz": 0, "yaw_rate": 0}}]
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(sc))
    cfg = RunConfig(input=f"fly:{path}", survey=DEMO_SURVEY, detect=DetectConfig(keyframe_spacing=1.0),
                    report={"pdf": False, "coverage": {"max_m_per_px": 0.006}})
    # WHEN the whole pipeline runs
    out = run_pipeline(tmp_path / "run", cfg, log=lambda s: None)
    # THEN every step ran and the register is located on the wall the camera saw
    assert [s.action for s in out.steps] == ["ran"] * 4
    mosaic = json.loads((tmp_path / "run" / "mosaic" / "mosaic.json").read_text())
    assert mosaic["m_per_px"] > 0 and len(mosaic["frames"]) >= 40
    reg = json.loads((tmp_path / "run" / "report" / "defects.json").read_text())
    assert reg["survey"]["vessel"] == DEMO_SURVEY["vessel"]
    assert reg["defects"], "the corroded wall has defects"
    for d in reg["defects"]:
        u, v = d["centroid_wall_m"]
        assert 2.8 <= u <= 6.8 and -0.15 <= v <= 2.4, d  # on the wall the camera saw (floor at v = 0), give or take the fit
        assert d["frame_range"].startswith("Fr. ") and d["frames"]
    cov = json.loads((tmp_path / "run" / "report" / "coverage.json").read_text())
    assert 0.05 < cov["usable_fraction"] < 1.0 and cov["gaps"]
