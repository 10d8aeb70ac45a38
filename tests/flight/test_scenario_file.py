"""Scenario files: every example loads; bad input names the file, the field and what is expected."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from inspect_pipe.errors import InputError
from inspect_pipe.flight import load_scenario
from inspect_pipe.flight.scenario import ButtonEvent, FaultKind, SensorName, StickEvent
from inspect_pipe.flight_stack.messages import Button

GOOD = {
    "format": "inspect_pipe.scenario/1",
    "name": "ok",
    "duration_s": 10,
    "seed": 1,
    "world": {"hold": {"length_m": 12, "width_m": 10, "height_m": 16}, "boxes": [{"min": [4, -1, 0], "max": [6, 1, 1.0]}]},
    "vehicle": {"start": {"position": [2, 0, 0], "yaw": 0}, "battery": {"start_percent": 100, "drain_percent_per_min": 4}},
    "camera": {"fps": 10, "width": 752, "height": 480, "hfov_deg": 60},
    "operator": [{"t": 1.0, "button": "takeoff"}, {"t": 6.0, "stick": {"vx": 0.4, "vy": 0, "vz": 0, "yaw_rate": 0}}],
    "faults": [{"t": 5.0, "duration_s": 3, "fault": "sensor_dropout", "sensor": "front_flow"}, {"t": 7, "duration_s": 1, "fault": "link_loss"}],
}


def _write(tmp_path: Path, doc) -> Path:
    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump(doc))
    return p


def test_every_shipped_scenario_loads(scenarios_dir):
    files = sorted(scenarios_dir.glob("*.yaml"))
    assert len(files) >= 10
    for f in files:
        assert load_scenario(f).name == f.stem


def test_spec_example_is_typed(tmp_path):
    s = load_scenario(_write(tmp_path, GOOD))
    assert s.world.boxes[0].max_m == (6.0, 1.0, 1.0)
    assert isinstance(s.operator[0], ButtonEvent) and s.operator[0].button is Button.TAKEOFF
    assert isinstance(s.operator[1], StickEvent) and s.operator[1].stick.vx_m_s == 0.4
    assert s.faults[0].kind is FaultKind.SENSOR_DROPOUT and s.faults[0].sensor is SensorName.FRONT_FLOW
    assert s.faults[1].sensor is None
    assert s.max_height_m == 12.0


def _mutate(path, value):
    doc = copy.deepcopy(GOOD)
    *parents, last = path
    node = doc
    for k in parents:
        node = node[k]
    if value is KeyError:
        del node[last]
    else:
        node[last] = value
    return doc


@pytest.mark.parametrize(
    "path, value, field, expected",
    [
        (("duration_s",), KeyError, "duration_s", "missing"),
        (("world", "hold", "width_m"), "ten", "world.hold.width_m", "a number"),
        (("world", "hold", "widht_m"), 10, "world.hold.widht_m", "unknown field"),
        (("world", "boxes", 0, "max"), [13, 1, 1], "world.boxes[0]", "outside the hold"),
        (("world", "boxes", 0, "min"), [4, -1], "world.boxes[0].min", "a list of 3 numbers"),
        (("vehicle", "start", "position"), [5, 0, 0], "vehicle.start.position", "inside obstacle"),
        (("vehicle", "start", "position"), [0.1, 0, 0], "vehicle.start.position", "within 0.35 m of a wall"),
        (("operator", 0, "button"), "jump", "operator[0].button", "takeoff"),
        (("faults", 0, "sensor"), "camera", "faults[0].sensor", "bottom_flow"),
        (("faults", 0, "fault"), "explode", "faults[0].fault", "sensor_dropout"),
        (("format",), "inspect_pipe.scenario/2", "format", "inspect_pipe.scenario/1"),
        # the expectation is read from the schema (ScenarioDoc): type, range, allowed values
        (("world", "hold", "width_m"), 1, "world.hold.width_m", "a number in [2, 500]"),
        (("seed",), 1.5, "seed", "an integer >= 0"),
        (("faults", 1, "rate"), 0.3, "faults[1].rate", "link_loss takes no rate"),
        (("world", "wall_textures"), {"top": {"image": "x.png", "m_per_px": 0.01}}, "world.wall_textures.top", "one of front, back, left, right"),
        (("operator", 1, "t"), 11.0, "operator[1].t", "within the flight's duration_s 10"),
        (("faults", 0, "t"), 800.0, "faults[0].t", "within the flight's duration_s 10"),
    ],
)
def test_bad_scenario_names_file_field_and_expectation(tmp_path, path, value, field, expected):
    p = _write(tmp_path, _mutate(path, value))
    with pytest.raises(InputError) as err:
        load_scenario(p)
    msg = str(err.value)
    assert str(p) in msg and f"'{field}'" in msg and expected in msg
    assert "\n" not in msg


def test_not_yaml_and_missing_file(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text("world: [unclosed")
    with pytest.raises(InputError, match="not valid YAML"):
        load_scenario(p)
    with pytest.raises(InputError, match="not found"):
        load_scenario(tmp_path / "nope.yaml")


@pytest.mark.parametrize("content, problem", [(b"", "empty file"), (None, "truncated JPEG"), ("dir", "is not a file")])
def test_a_wall_texture_that_cannot_be_whole_is_refused_before_the_flight(tmp_path, content, problem):
    # GIVEN a scenario whose front wall texture is empty, cut short, or a folder
    import cv2
    import numpy as np

    tex = tmp_path / "wall.jpg"
    if content == "dir":
        tex.mkdir()
    else:
        ok, buf = cv2.imencode(".jpg", np.full((64, 64, 3), 90, np.uint8))
        tex.write_bytes(content if content is not None else buf.tobytes()[: len(buf) // 2])
    doc = copy.deepcopy(GOOD)
    doc["world"]["front_wall_texture"] = {"image": "wall.jpg", "m_per_px": 0.01}
    # THEN loading it names the field and the problem: nothing is flown only to fail at the end
    with pytest.raises(InputError) as err:
        load_scenario(_write(tmp_path, doc))
    assert "'world.front_wall_texture.image'" in str(err.value) and problem in str(err.value)
