"""``--camera camera.yaml`` on the commands that take frames: the sweep records the calibration
and where it came from (or says it has none); mosaic and run use it; resolutions are checked."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from inspect_pipe.capture import read_sweep
from inspect_pipe.capture._calibration import load_camera

from .conftest import write_scenario

MINI = Path(__file__).resolve().parent.parent / "fixtures" / "mosaic" / "synth_rust_mini"  # 13 frames, 256x192


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def ros_yaml(path: Path, w: int, h: int, f: float, k1: float = 0.0) -> Path:
    path.write_text(f"""image_width: {w}
image_height: {h}
camera_name: test_cam
camera_matrix:
  rows: 3
  cols: 3
  data: [{f}, 0, {(w - 1) / 2}, 0, {f}, {(h - 1) / 2}, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [{k1}, 0, 0, 0, 0]
""")
    return path


@pytest.fixture
def frames(tmp_path) -> Path:
    d = tmp_path / "frames"
    d.mkdir()
    for p in sorted(MINI.glob("*.jpg"))[:4]:
        shutil.copy(p, d / p.name)
    return d


def test_capture_records_the_calibration_and_its_source(tmp_path, frames):
    cam = ros_yaml(tmp_path / "cam.yaml", 256, 192, 300.0, k1=-0.05)
    res = run("capture", "--source", f"replay:{frames}", "-o", tmp_path / "sw", "--speed", 100, "--camera", cam)
    assert res.exit_code == 0, res.output
    meta = read_sweep(tmp_path / "sw").meta
    assert meta.camera.K[0, 0] == 300.0 and meta.camera.dist[0] == -0.05
    cal = meta.camera.calibration
    assert cal["source"] == str(cam.resolve()) and cal["sha256"] == hashlib.sha256(cam.read_bytes()).hexdigest()
    assert "note" not in json.loads((tmp_path / "sw" / "sweep.json").read_text())["camera"]


def test_capture_without_calibration_says_so(tmp_path, frames):
    res = run("capture", "--source", f"replay:{frames}", "-o", tmp_path / "sw", "--speed", 100)
    assert res.exit_code == 0, res.output
    cam = json.loads((tmp_path / "sw" / "sweep.json").read_text())["camera"]
    assert cam["calibration"] is None and cam["note"] == "uncalibrated: 60\u00b0 guess"
    assert read_sweep(tmp_path / "sw").meta.camera.calibration is None


def test_capture_scales_a_calibration_of_the_same_aspect_and_refuses_another(tmp_path, frames):
    cam = ros_yaml(tmp_path / "cam512.yaml", 512, 384, 600.0)
    res = run("capture", "--source", f"replay:{frames}", "-o", tmp_path / "sw", "--speed", 100, "--camera", cam)
    assert res.exit_code == 0, res.output
    assert "calibrated at 512x384; scaled to the frames' 256x192" in res.output
    meta = read_sweep(tmp_path / "sw").meta
    assert meta.camera.K[0, 0] == pytest.approx(300.0) and meta.camera.K[0, 2] == pytest.approx(127.5)
    assert meta.camera.calibration["scaled_from_wh"] == [512, 384]
    wide = ros_yaml(tmp_path / "wide.yaml", 640, 360, 500.0)
    res = run("capture", "--source", f"replay:{frames}", "-o", tmp_path / "sw2", "--speed", 100, "--camera", wide)
    assert res.exit_code == 2 and res.output.count("\n") == 1
    assert "wide.yaml: calibrated at 640x360, but the frames of" in res.output and "another aspect ratio" in res.output
    assert not (tmp_path / "sw2").exists()


def test_capture_with_a_malformed_camera_file_writes_nothing(tmp_path, frames):
    bad = tmp_path / "cam.yaml"
    bad.write_text("camera_matrix: [1, 2\n")
    res = run("capture", "--source", f"replay:{frames}", "-o", tmp_path / "sw", "--camera", bad)
    assert res.exit_code == 2 and "cam.yaml: not valid YAML" in res.output and "Traceback" not in res.output
    assert not (tmp_path / "sw").exists()


def test_simulated_camera_renders_through_the_calibration(tmp_path):
    sc = write_scenario(tmp_path / "sc", duration_s=4.0)
    res = run("capture", "--source", f"sim:{sc}", "-o", tmp_path / "plain", "--frames", 3)
    assert res.exit_code == 0, res.output
    plain = read_sweep(tmp_path / "plain")
    assert plain.meta.camera.calibration["source"] == "simulator"  # exact, not a guess
    cam = ros_yaml(tmp_path / "cam.yaml", 320, 240, 250.0, k1=-0.1)
    res = run("capture", "--source", f"sim:{sc}", "-o", tmp_path / "sw", "--frames", 3, "--camera", cam)
    assert res.exit_code == 0, res.output
    s = read_sweep(tmp_path / "sw")
    assert s.meta.camera.K[0, 0] == 250.0 and s.meta.camera.calibration["source"] == str(cam.resolve())
    # the truth homography of a frame is the calibrated K's: it differs from the 60-degree sweep's
    Hc, Hp = s.frames[1].truth.H_wall_m_to_frame, plain.frames[1].truth.H_wall_m_to_frame
    assert not np.allclose(Hc / Hc[2, 2], Hp / Hp[2, 2], rtol=1e-3)


def test_mosaic_uses_the_camera_file(tmp_path):
    cam = ros_yaml(tmp_path / "cam.yaml", 256, 192, 300.0)
    res = run("mosaic", MINI, "-o", tmp_path / "m", "--camera", cam, "-q")
    assert res.exit_code == 0, res.output
    doc = json.loads((tmp_path / "m" / "mosaic.json").read_text())
    used = doc["input"]["camera"]
    assert used["K"][0][0] == 300.0 and used["calibration"]["sha256"] == hashlib.sha256(cam.read_bytes()).hexdigest()
    assert len(doc["frames"]) == 13


def test_mosaic_camera_errors_write_nothing(tmp_path):
    wide = ros_yaml(tmp_path / "wide.yaml", 640, 360, 500.0)
    res = run("mosaic", MINI, "-o", tmp_path / "m", "--camera", wide)
    assert res.exit_code == 2 and "calibrated at 640x360, but the images of" in res.output
    assert not (tmp_path / "m" / "mosaic.json").exists()
    cam = ros_yaml(tmp_path / "cam.yaml", 256, 192, 300.0)
    res = run("mosaic", MINI, "-o", tmp_path / "m", "--camera", cam, "--focal-px", 300)
    assert res.exit_code == 2 and "--focal-px and --camera" in res.output


def test_mosaic_camera_overrides_a_sweeps_own(tmp_path, frames):
    res = run("capture", "--source", f"replay:{frames}", "-o", tmp_path / "sw", "--speed", 100)
    assert res.exit_code == 0, res.output
    cam = ros_yaml(tmp_path / "cam.yaml", 256, 192, 280.0)
    res = run("mosaic", tmp_path / "sw", "-o", tmp_path / "m", "--camera", cam, "-q")
    assert res.exit_code in (0, 2), res.output  # four frames without vehicle state: placed or not, the camera is recorded
    doc = json.loads((tmp_path / "m" / "mosaic.json").read_text())
    assert doc["input"]["camera"]["K"][0][0] == 280.0 and doc["input"]["camera"]["calibration"]["source"] == str(cam.resolve())


def test_run_config_carries_the_camera(tmp_path):
    from cli.run import build_config
    from inspect_pipe.pipeline._steps import STEPS, step_options

    cam = load_camera(ros_yaml(tmp_path / "cam.yaml", 256, 192, 300.0, k1=-0.02))
    cfg = build_config(str(MINI), kinds="all", keyframe_spacing=0.5, scheme="MSC.1/Circ.1330", area_m=1.0, no_pdf=True,
                       m_per_px=None, focal_px=None, camera=cam)
    back = cfg.camera_model()
    np.testing.assert_array_equal(back.K, cam.K)
    np.testing.assert_array_equal(back.dist, cam.dist)
    assert back.calibration == cam.calibration
    mosaic = next(s for s in STEPS if s.name == "mosaic")
    assert step_options(mosaic, cfg)["camera"]["calibration"]["sha256"] == cam.calibration["sha256"]


def test_report_limitations_follow_the_mosaics_camera():
    from inspect_pipe.report._report import _limitations

    assert "uncalibrated camera" in _limitations(None, None)[0]
    assert "uncalibrated" not in _limitations(None, None, {"source": "/x/camera.yaml", "sha256": "0" * 64})[0]


def test_run_checks_the_camera_against_each_input_before_anything_runs(tmp_path):
    from cli.run import check_camera

    assert "calibrated at 512x384; scaled to the frames' 256x192" in check_camera(str(MINI), load_camera(ros_yaml(tmp_path / "c.yaml", 512, 384, 600.0)))
    assert check_camera(str(MINI), load_camera(ros_yaml(tmp_path / "d.yaml", 256, 192, 300.0))) == ""
    wide = ros_yaml(tmp_path / "wide.yaml", 640, 360, 500.0)
    res = run("run", MINI, "-o", tmp_path / "out", "--camera", wide, "--workers", 1)
    assert res.exit_code == 2 and res.output.count("\n") == 1 and "another aspect ratio" in res.output
    assert not (tmp_path / "out").exists()
    res = run("run", MINI, "-o", tmp_path / "out", "--camera", wide, "--focal-px", 300)
    assert res.exit_code == 2 and "--focal-px: given with --camera" in res.output


def test_report_limitations_say_uncalibrated_for_a_sweep_without_calibration(tmp_path, frames):
    from inspect_pipe.report._report import _limitations

    assert run("capture", "--source", f"replay:{frames}", "-o", tmp_path / "sw", "--speed", 100).exit_code == 0
    sweep = read_sweep(tmp_path / "sw")
    lines = _limitations(sweep, None)
    assert any(x.startswith("calibration: uncalibrated: 60\u00b0 guess") for x in lines)
    # the mosaic used --camera: the report does not call the camera uncalibrated
    assert not any(x.startswith("calibration") for x in _limitations(sweep, None, {"source": "/c.yaml", "sha256": "0" * 64}))
