"""A user's YAML/JSON files (scenario, stack parameters, survey plan) and the flight/campaign
options: what a hostile or careless file does gives one line naming the file, never a traceback,
and nothing runs for minutes or fills memory first."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
import yaml

from inspect_pipe._yaml import MAX_VALUES, load_yaml
from inspect_pipe.campaign.run import CampaignConfig
from inspect_pipe.errors import MAX_PART_CHARS, InputError
from inspect_pipe.flight import load_scenario
from inspect_pipe.flight_stack.params import load_params

from tests.flight.test_scenario_file import GOOD


def _scenario(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "s.yaml"
    p.write_text(text)
    return p


def _bomb(levels: int) -> str:
    """A "billion laughs": 10**levels values from a few hundred bytes of nested aliases."""
    lines = ["a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    for i in range(1, levels):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]")
    return "\n".join(lines) + f"\nduration_s: *a{levels - 1}\n"


@pytest.mark.parametrize(
    "text, problem",
    [
        ("[" * 2000 + "]" * 2000, "nested too deeply"),
        ("seed: " + "9" * 5000 + "\n", "thousands of digits"),
        (_bomb(8), f"more than {MAX_VALUES:,} values"),
        ("name: a\nname: b\n", "key 'name' given twice"),
        ("", "is empty"),
    ],
)
def test_a_hostile_scenario_file_is_one_line_and_quick(tmp_path, text, problem):
    p = _scenario(tmp_path, text)
    t0 = time.process_time()
    with pytest.raises(InputError) as err:
        load_scenario(p)
    assert time.process_time() - t0 < 5.0
    msg = str(err.value)
    assert msg.startswith(str(p)) and problem in msg and "\n" not in msg and len(msg) < 3 * MAX_PART_CHARS


def test_the_same_hostile_files_as_stack_parameters(tmp_path):
    for text, problem in ((_bomb(8), "values"), ("[" * 2000 + "]" * 2000, "nested too deeply"),
                          ("control: {tick_hz: " + "9" * 5000 + "}\n", "digits"), ("control:\n", "is empty")):
        p = tmp_path / "p.yaml"
        p.write_text(text)
        with pytest.raises(InputError, match=problem):
            load_params(p)
    # a long list where a number belongs: named in a few characters, not echoed whole
    p.write_text("control: {tick_hz: [" + ", ".join(["1"] * 100000) + "]}\n")
    with pytest.raises(InputError) as err:
        load_params(p)
    assert "tick_hz" in str(err.value) and len(str(err.value)) < 300


def test_json_and_yaml_1_2_exponents_are_numbers(tmp_path):
    doc = dict(GOOD, duration_s="@D@")
    text = json.dumps(doc).replace('"@D@"', "1e1")
    assert load_scenario(_scenario(tmp_path, text)).duration_s == 10.0
    assert load_yaml("a: 1.0e3\nb: 3e0\nc: 2\nd: 1.2.3\ne: .5\n", "x") == {"a": 1000.0, "b": 3.0, "c": 2, "d": "1.2.3", "e": 0.5}
    p = tmp_path / "p.json"
    p.write_text('{"control": {"tick_hz": 5e1}}')
    assert load_params(p).control.tick_hz == 50.0


@pytest.mark.parametrize(
    "where, value, problem",
    [
        (("vehicle", "start", "position"), [2, 0, 8], "z=8 is in mid-air"),
        (("camera", "hfov_deg"), 170, "camera.hfov_deg"),
        (("camera",), {"fps": 10, "width": 752, "height": 480, "hfov_deg": 140}, "146 deg corner to corner"),
        (("camera",), {"fps": 10, "width": 16, "height": 8000, "hfov_deg": 30}, "corner to corner"),
        (("camera", "width"), 32767, "camera.width"),
        (("name",), "a\x1b[31mb", "control characters"),
        (("int",), 1, "field 'int': unknown field"),
        (("world", "hold", "float"), 1, "field 'world.hold.float': unknown field (expected one of height_m, length_m, width_m)"),
    ],
)
def test_a_scenario_the_simulator_cannot_fly_or_render_is_refused_before_the_flight(tmp_path, where, value, problem):
    doc = json.loads(json.dumps(GOOD))
    node = doc
    for k in where[:-1]:
        node = node[k]
    node[where[-1]] = value
    with pytest.raises(InputError) as err:
        load_scenario(_scenario(tmp_path, yaml.safe_dump(doc)))
    assert problem in str(err.value) and "\x1b" not in str(err.value)


def test_a_vehicle_may_start_on_a_box_top(tmp_path):
    doc = json.loads(json.dumps(GOOD))
    doc["vehicle"]["start"]["position"] = [5, 0, 1.0]  # GOOD's box spans x 4..6, y -1..1, top at 1.0
    assert load_scenario(_scenario(tmp_path, yaml.safe_dump(doc))).vehicle.start_position_m[2] == 1.0


def test_a_texture_that_is_not_an_image_is_refused_whatever_its_name(tmp_path):
    (tmp_path / "wall").write_text("not an image")
    doc = json.loads(json.dumps(GOOD))
    doc["world"]["wall_textures"] = {"front": {"image": "wall", "m_per_px": 0.01}}
    with pytest.raises(InputError, match="wall: not an image"):
        load_scenario(_scenario(tmp_path, yaml.safe_dump(doc)))


def test_a_scenario_read_from_a_pipe(tmp_path):
    import os
    import threading

    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    text = yaml.safe_dump(GOOD)
    writer = threading.Thread(target=lambda: fifo.write_text(text))
    writer.start()
    assert load_scenario(fifo).name == "ok"
    writer.join()


@pytest.mark.parametrize("field, value", [("episodes", 10**23), ("episodes", 0), ("workers", 10**6)])
def test_campaign_sizes_are_bounded(tmp_path, field, value):
    cfg = CampaignConfig(**{"episodes": 10, "seed": 1, "out": tmp_path / "c", field: value})
    with pytest.raises(InputError, match=f"--{field}"):
        cfg.check()


def test_mavlink_urls_that_cannot_open_are_one_line():
    pytest.importorskip("pymavlink")
    from inspect_pipe.flight.mavlink_endpoint import MavlinkEndpoint

    with pytest.raises(InputError, match="port 99999 is not in 0..65535"):
        MavlinkEndpoint("udp:127.0.0.1:99999", system_id=255, component_id=190)
    try:
        import serial  # noqa: F401
    except ImportError:
        with pytest.raises(InputError, match="needs pyserial"):
            MavlinkEndpoint("/dev/ttyUSB0", system_id=255, component_id=190)


def _png_claiming(width: int, height: int) -> bytes:
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b""))


def test_an_image_claiming_more_pixels_than_opencv_decodes_is_unreadable_everywhere(tmp_path):
    import cv2

    from inspect_pipe._images import imread
    from inspect_pipe.mosaic._io import FrameError, read_image

    p = tmp_path / "huge.png"
    p.write_bytes(_png_claiming(100000, 100000))
    with pytest.raises(cv2.error):  # what OpenCV itself does with it
        cv2.imread(str(p))
    assert imread(p) is None
    with pytest.raises(FrameError, match="unreadable"):
        read_image(p)


def test_merge_keys_override_as_yaml_means_them_and_other_value_errors_say_theirs():
    doc = load_yaml("base: &b {a: 1, b: 2}\nd: {<<: *b, b: 3}\ne: {<<: [{a: 1}, {a: 2}]}\n", "x")
    assert doc["d"] == {"a": 1, "b": 3} and doc["e"] == {"a": 1}
    with pytest.raises(InputError, match="day is out of range"):
        load_yaml("date: 2024-02-30\n", "x")
    assert load_yaml("a: -.5e3\n", "x") == {"a": -500.0}


def test_an_opencv_camera_file_goes_through_the_same_reader(tmp_path):
    from inspect_pipe.capture._calibration import load_camera

    p = tmp_path / "camera.yaml"
    p.write_text("%YAML:1.0\n---\ncamera_matrix: " + "[" * 2000 + "]" * 2000 + "\n")
    with pytest.raises(InputError, match="not a readable OpenCV FileStorage file .*nested too deeply"):
        load_camera(p)
