"""Every file format the product reads is declared once (inspect_pipe.formats, pydantic) and its
readers turn the first problem into one line naming the file and the field."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from inspect_pipe.capture import read_sweep
from inspect_pipe.capture._calibration import load_camera
from inspect_pipe.errors import InputError
from inspect_pipe.formats import FORMATS, CameraCalibration, FrameLine, MosaicJson, RegisterJson, validate
from inspect_pipe.pipeline._store import RunStore
from inspect_pipe.report import read_register

K = [[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]]


def sweep_doc(**over):
    doc = {"format": "inspect_pipe.sweep/1", "camera": {"K": K, "dist": [0, 0, 0, 0, 0], "width": 320, "height": 240},
           "source": {"kind": "folder"}, "rate_hz": 10.0}
    doc.update(over)
    return doc


def write_sweep(root: Path, doc: dict, lines: list) -> Path:
    (root / "images").mkdir(parents=True, exist_ok=True)
    (root / "sweep.json").write_text(json.dumps(doc))
    (root / "frames.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))
    for x in lines:
        if isinstance(x, dict) and isinstance(x.get("image"), str) and x["image"].startswith("images/"):
            (root / x["image"]).write_bytes(b"x")
    return root


def frame(i, **over):
    d = {"index": i, "image": f"images/{i:06d}.png", "t_s": 0.1 * i, "exposure_s": 0.002}
    d.update(over)
    return d


@pytest.mark.parametrize("camera, field", [
    ({"K": [[1, 0], [0, 1]], "width": 320, "height": 240}, "field 'camera.K"),
    ({"K": K, "width": -3, "height": 240}, "field 'camera.width': -3"),
    ({"K": K, "width": 320, "height": 240, "dist": ["a"]}, "field 'camera.dist.0'"),
    ({"K": K, "width": 320.5, "height": 240}, "field 'camera.width'"),
    (None, "field 'camera'"),
])
def test_sweep_json_field_errors_are_one_line(tmp_path, camera, field):
    doc = sweep_doc(camera=camera)
    write_sweep(tmp_path / "s", doc, [frame(0)])
    with pytest.raises(InputError) as err:
        read_sweep(tmp_path / "s")
    msg = str(err.value)
    assert msg.startswith(str(tmp_path / "s" / "sweep.json") + ": " + field), msg
    assert "\n" not in msg


def test_sweep_json_odometry_frame_is_a_choice(tmp_path):
    write_sweep(tmp_path / "s", sweep_doc(odometry_frame="ned"), [])
    with pytest.raises(InputError, match=r"field 'odometry_frame': 'ned'"):
        read_sweep(tmp_path / "s")


def test_old_sweep_without_optional_blocks_still_reads(tmp_path):
    # an early sweep: no cam_to_body, survey, odometry_frame, time_base or created_utc, an extra key
    doc = sweep_doc(legacy_key=1)
    write_sweep(tmp_path / "s", doc, [frame(0), frame(1, state={"position_m": [1, 2]})])
    s = read_sweep(tmp_path / "s")
    assert len(s.frames) == 2 and s.meta.odometry_frame == "takeoff" and s.frames[1].position_m is None
    assert s.meta.camera.width == 320 and s.problems == ()


@pytest.mark.parametrize("line, problem", [
    (frame(-1), "field 'index': -1: input should be greater than or equal to 0"),
    (frame(True), "field 'index': True"),
    (frame(2, image="/etc/passwd"), "field 'image': '/etc/passwd' is not a file inside the sweep"),
    (frame(2, image="../x.png"), "is not a file inside the sweep"),
    (frame(2, t_s="soon"), "field 't_s': 'soon'"),
    ({"index": 2, "image": "images/000002.png", "t_s": 1.0}, "field 'exposure_s': missing"),
])
def test_bad_frame_line_is_skipped_with_its_field(tmp_path, line, problem):
    write_sweep(tmp_path / "s", sweep_doc(), [frame(0), line])
    s = read_sweep(tmp_path / "s")
    assert len(s.frames) == 1 and len(s.problems) == 1
    msg = str(s.problems[0])
    assert msg.startswith(str(tmp_path / "s" / "frames.jsonl") + ": line 2: ") and problem in msg, msg


def mosaic_doc(**over):
    doc = {"format": "inspect_pipe.mosaic/1", "frames": [{"index": 0, "H": np.eye(3).tolist(), "group": 0}],
           "wall_from_mosaic": np.eye(3).tolist(), "m_per_px": 0.001}
    doc.update(over)
    return doc


@pytest.mark.parametrize("doc, field", [
    (mosaic_doc(frames=[{"index": 0, "H": [[1, 0, 0], [0, 1, 0]]}]), "field 'frames.0.H"),
    (mosaic_doc(frames=[{"index": "a", "H": np.eye(3).tolist()}]), "field 'frames.0.index'"),
    (mosaic_doc(m_per_px=-1), "field 'm_per_px': -1"),
    (mosaic_doc(frames=None), "field 'frames'"),
    (mosaic_doc(format="inspect_pipe.mosaic/2"), "field 'format'"),
])
def test_mosaic_json_errors_name_the_field(tmp_path, doc, field):
    store = RunStore(tmp_path / "run")
    store.mosaic_dir.mkdir(parents=True)
    (store.mosaic_dir / "mosaic.json").write_text(json.dumps(doc))
    with pytest.raises(InputError) as err:
        store.load_mosaic_json()
    assert f"mosaic.json: {field}" in str(err.value) and "\n" not in str(err.value)


def test_detections_json_errors_name_the_field(tmp_path):
    store = RunStore(tmp_path / "run")
    store.detect_dir.mkdir(parents=True)
    good = {"format": "inspect_pipe.defects/1", "kinds": ["corrosion"],
            "regions": [{"class": "corrosion", "polygon_px": [[0, 0], [1, 0], [1, 1]], "area_px": 1, "confidence": 0.5}]}
    (store.detect_dir / "defects.json").write_text(json.dumps(good))
    assert store.load_detections()["kinds"] == ["corrosion"]
    bad = dict(good, regions=[{"class": "corrosion", "area_px": -4}])
    (store.detect_dir / "defects.json").write_text(json.dumps(bad))
    with pytest.raises(InputError, match=r"defects.json: field 'regions.0.area_px': -4"):
        store.load_detections()


def entry(**over):
    d = {"id": "D001", "class": "corrosion", "status": "suggested", "polygon_wall_m": [[0, 0], [0.1, 0], [0.1, 0.1]],
         "centroid_wall_m": [0.05, 0.05], "area_m2": 0.005}
    d.update(over)
    return d


def test_register_errors_name_the_entry_and_field(tmp_path):
    p = tmp_path / "defects.json"
    p.write_text(json.dumps({"format": "inspect_pipe.defect_register/1", "defects": [entry()]}))
    assert [d.id for d in read_register(p)] == ["D001"]
    p.write_text(json.dumps({"format": "inspect_pipe.defect_register/1", "defects": [entry(), entry(id="D002", status="fixed")]}))
    with pytest.raises(InputError, match=r"defects.json: field 'defects.1.status': 'fixed': input should be 'suggested', 'confirmed' or 'rejected'"):
        read_register(p)
    p.write_text(json.dumps({"format": "inspect_pipe.defect_register/1", "defects": [entry(centroid_wall_m=[0.1])]}))
    with pytest.raises(InputError, match=r"field 'defects.0.centroid_wall_m"):
        read_register(p)


ROS = """image_width: 640
image_height: 480
camera_name: cam
camera_matrix: {rows: 3, cols: 3, data: [612.5, 0, 321.2, 0, 611.9, 239.4, 0, 0, 1]}
distortion_model: plumb_bob
distortion_coefficients: {rows: 1, cols: 5, data: [-0.41, 0.19, 0.001, -0.002, 0]}
"""


@pytest.mark.parametrize("text, field", [
    (ROS.replace("612.5, 0, 321.2, 0, 611.9", "-612.5, 0, 321.2, 0, 611.9"), "field 'camera_matrix': not [[fx"),
    (ROS.replace("cols: 5, data: [-0.41, 0.19, 0.001, -0.002, 0]", "cols: 8, data: [-0.41, 0.19, 0.001, -0.002, 0, 0.3, 0, 0]"),
     "field 'distortion_coefficients': 8 values with k4.. non-zero"),
])
def test_camera_yaml_values_are_validated(tmp_path, text, field):
    p = tmp_path / "camera.yaml"
    p.write_text(text)
    with pytest.raises(InputError) as err:
        load_camera(p)
    assert str(err.value).startswith(f"{p}: {field}"), str(err.value)


def test_every_format_has_a_versioned_schema():
    assert set(FORMATS) >= {"sweep.schema.json", "sweep_frame.schema.json", "mosaic.schema.json", "defects.schema.json",
                            "defect_register.schema.json", "camera.schema.json"}
    for name, (model, fmt) in FORMATS.items():
        assert "/" in fmt and fmt.split("/")[1][0].isdigit(), name
        schema = model.model_json_schema(by_alias=True)
        assert schema["type"] == "object" and schema["properties"], name


def test_validate_gives_one_line_with_the_path():
    with pytest.raises(InputError) as err:
        validate(FrameLine, {"index": 0, "image": "a.png", "t_s": float("nan"), "exposure_s": 0}, "F")
    assert str(err.value) == "F: field 't_s': nan: input should be a finite number"
    with pytest.raises(InputError, match="^F: field 'defects': missing"):
        validate(RegisterJson, {"format": "inspect_pipe.defect_register/1"}, "F")
    with pytest.raises(InputError, match="^F: field 'image_width': 0"):
        validate(CameraCalibration, {"image_width": 0, "image_height": 1, "camera_matrix": K, "distortion_coefficients": [0, 0, 0, 0]}, "F")
    assert validate(MosaicJson, {"format": "inspect_pipe.mosaic/1", "frames": []}, "F").frames == []


def test_an_image_cut_short_is_named_before_any_reader_decodes_it(tmp_path):
    # OpenCV decodes a cut JPEG without an error (grey rows, a stray libjpeg line): every reader asks this first
    import cv2
    import numpy as np

    from inspect_pipe._images import truncation

    img = np.random.default_rng(1).integers(0, 255, (48, 64, 3), dtype=np.uint8)
    for ext, words in ((".jpg", "truncated JPEG"), (".png", "truncated PNG")):
        ok, buf = cv2.imencode(ext, img)
        whole, cut = tmp_path / f"whole{ext}", tmp_path / f"cut{ext}"
        whole.write_bytes(buf.tobytes())
        cut.write_bytes(buf.tobytes()[: len(buf) * 2 // 3])
        assert truncation(whole) == "" and words in truncation(cut)
    (tmp_path / "text.jpg").write_text("not an image")
    (tmp_path / "empty.png").write_bytes(b"")
    assert truncation(tmp_path / "text.jpg") == "not a JPEG file" and truncation(tmp_path / "empty.png") == "empty file"


def test_a_sweep_camera_with_a_negative_focal_length_is_refused_in_one_line():
    from inspect_pipe.errors import InputError
    from inspect_pipe.formats import CameraJson, validate

    cam = {"K": [[-651.0, 0, 376], [0, 651.0, 240], [0, 0, 1]], "dist": [0, 0, 0, 0, 0], "width": 752, "height": 480}
    with pytest.raises(InputError, match="focal lengths fx -651, fy 651 px: both must be positive"):
        validate(CameraJson, cam, "sweep.json", "")
