"""Any wall of the hold, in ship terms: the simulator textures the wall the vehicle faces, the
mosaic is placed in that wall's frame, and a survey plan turns wall points into frame numbers
(side shells) or distances from the centreline (bulkheads)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from inspect_pipe.capture import read_sweep
from inspect_pipe.capture.sources.sim import capture_flight, trajectory_from_ticks
from inspect_pipe.flight import load_scenario
from inspect_pipe.flight.runner import run_scenario
from inspect_pipe.mosaic import run_mosaic_sweep
from inspect_pipe.pipeline._demo import SHIPPED_WALL
from inspect_pipe.ship import ShipFrames, locate, parse_survey_plan, plan_wall_frame

HOLD_L, HOLD_W = 12.0, 10.0

# The vehicle takes off 1.5 m from the wall it faces and flies right along it in inspection mode.
WALLS = {
    # wall: (start position, yaw, texture origin (u, v) of its top-left corner)
    "left": ([4.5, HOLD_W / 2 - 1.5, 0.0], math.pi / 2, [3.0, 2.6]),
    "back": ([1.5, -1.0, 0.0], math.pi, [3.0, 2.6]),
}


_FLOWN: dict[str, Path] = {}


def _fly_sweep(tmp_path: Path, wall: str) -> Path:
    """Fly once per wall and test session (the sweep is only read afterwards)."""
    if wall not in _FLOWN:
        _FLOWN[wall] = _fly(tmp_path, wall)
    return _FLOWN[wall]


def _fly(tmp_path: Path, wall: str) -> Path:
    start, yaw, origin = WALLS[wall]
    sc = {
        "format": "inspect_pipe.scenario/1", "name": f"sweep_{wall}", "duration_s": 11.0, "seed": 3,
        "world": {"hold": {"length_m": HOLD_L, "width_m": HOLD_W, "height_m": 16},
                  "wall_textures": {wall: {"image": str(SHIPPED_WALL), "m_per_px": 0.003, "origin_uv": origin}}},
        "vehicle": {"start": {"position": start, "yaw": yaw}},
        "camera": {"fps": 10, "width": 376, "height": 240, "hfov_deg": 60},
        "operator": [{"t": 0.5, "button": "takeoff"}, {"t": 3.0, "button": "inspection_mode_on"},
                     {"t": 3.5, "stick": {"vx": 0, "vy": -0.3, "vz": 0, "yaw_rate": 0}},
                     {"t": 10.5, "stick": {"vx": 0, "vy": 0, "vz": 0, "yaw_rate": 0}}],
    }
    path = tmp_path / f"{wall}.yaml"
    path.write_text(yaml.safe_dump(sc))
    scenario = load_scenario(path)
    ticks = []
    run_scenario(scenario, on_tick=ticks.append)
    sweep = tmp_path / f"sweep_{wall}"
    capture_flight(scenario, trajectory_from_ticks(scenario, ticks), sweep)
    return sweep


def _wall_errors(sweep_dir: Path, out: Path) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) wall (u, v) where the mosaic's wall map puts each placed frame's centre, and the
    (N, 2) wall point the simulator's truth homography shows there."""
    sweep = read_sweep(sweep_dir)
    doc = json.loads((out / "mosaic.json").read_text())
    W = np.array(doc["wall_from_mosaic"])
    K = sweep.meta.K
    c = np.array([K[0, 2], K[1, 2], 1.0])
    by_name = {f.image: f for f in sweep.frames}
    found, true = [], []
    for fr in doc["frames"]:
        f = by_name[fr["file"]]
        m = np.array(fr["H"]) @ c
        w = W @ (m / m[2])
        t = np.linalg.inv(f.truth.H_wall_m_to_frame) @ c
        found.append(w[:2] / w[2])
        true.append(t[:2] / t[2])
    return np.array(found), np.array(true)


PLAN_WALL = {"left": "port_side_shell", "back": "aft_transverse_bulkhead"}


@pytest.mark.slow
@pytest.mark.skipif(not SHIPPED_WALL.is_file(), reason="scenario asset missing")
@pytest.mark.parametrize("wall", ["left", "back"])
def test_sweep_of_any_wall_is_placed_in_that_walls_frame(tmp_path, wall):
    # GIVEN an inspection flight facing the {wall} wall, its texture seen by the simulated camera
    sweep = _fly_sweep(tmp_path, wall)
    assert read_sweep(sweep).meta.sim_wall == wall
    # WHEN it is mosaicked
    run_mosaic_sweep(sweep, tmp_path / "mosaic")
    # THEN every placed frame's centre lies within 5 cm of the wall point the truth shows
    found, true = _wall_errors(sweep, tmp_path / "mosaic")
    assert len(found) >= 40
    err = np.linalg.norm(found - true, axis=1).max()
    assert err <= 0.05, f"{wall}: {err:.3f} m"
    # AND in ship terms: on the side shell the frame number (0.8 m spacing), on the bulkhead the
    # distance from the centreline, agree with the truth's within 5 cm
    doc = yaml.safe_load(PLAN)
    doc["wall"] = PLAN_WALL[wall]
    plan = parse_survey_plan(doc, "plan.yaml")
    frame = plan_wall_frame(plan)
    for f_uv, t_uv in zip(found, true):
        a, b = locate(plan, frame, tuple(f_uv)), locate(plan, frame, tuple(t_uv))
        if wall == "left":
            assert abs(a.frame - b.frame) * 0.8 <= 0.05
        else:
            signed = lambda loc: loc.from_centreline_m * (1 if loc.side == "port" else -1)  # noqa: E731
            assert abs(signed(a) - signed(b)) <= 0.05
        assert abs(a.above_tank_top_m - b.above_tank_top_m) <= 0.05


PLAN = """
format: inspect_pipe.survey_plan/1
vessel: {name: MV Example, imo: "9074729", class_society: ABS}
survey: {type: special survey, date: "2026-11-20", rit_provider: Hold Drones Ltd, pilot: A. Pilot, surveyor: B. Surveyor}
compartment: {name: Cargo hold No. 2}
hold: {aft_bulkhead_frame: 140, frame_spacing_m: 0.8, tank_top_above_baseline_m: 1.6, length_m: 12, width_m: 10}
wall: port_side_shell
"""


def test_side_shell_location_is_a_frame_number_and_height():
    # GIVEN a plan for the port side shell (aft bulkhead at Fr. 140, frames 0.8 m apart)
    plan = parse_survey_plan(yaml.safe_load(PLAN), "plan.yaml")
    frame = plan_wall_frame(plan)
    # WHEN a point 2.48 m forward of the aft bulkhead, 2.35 m up, is located
    loc = locate(plan, frame, (2.48, 2.35))
    # THEN it is 3.1 frame spaces forward: Fr. 143 + 80 mm
    assert loc.frame == pytest.approx(143.1)
    assert loc.above_tank_top_m == pytest.approx(2.35)
    assert loc.text == "Fr. 143 + 80 mm, 2.35 m above tank top"
    assert loc.from_centreline_m is None


def test_starboard_shell_counts_u_from_forward():
    doc = yaml.safe_load(PLAN)
    doc["wall"] = "starboard_side_shell"
    plan = parse_survey_plan(doc, "plan.yaml")
    # u = L - x: a point 1.6 m from the starboard wall's left (forward) edge is at x = 10.4 m
    loc = locate(plan, plan_wall_frame(plan), (1.6, 1.0))
    assert loc.frame == pytest.approx(140 + 10.4 / 0.8)


@pytest.mark.parametrize("wall,u,side", [("fore_transverse_bulkhead", 3.8, "port"), ("aft_transverse_bulkhead", 3.8, "starboard")])
def test_bulkhead_location_is_distance_from_centreline(wall, u, side):
    doc = yaml.safe_load(PLAN)
    doc["wall"] = {"name": wall, "stiffener_spacing_m": 0.6}
    plan = parse_survey_plan(doc, "plan.yaml")
    loc = locate(plan, plan_wall_frame(plan), (u, 2.0))
    # fore: u = W/2 - y -> y = +1.2 (port); aft: u = W/2 + y -> y = -1.2 (starboard)
    assert loc.from_centreline_m == pytest.approx(1.2) and loc.side == side
    assert loc.stiffener == pytest.approx(2.0)
    assert loc.text == f"1.20 m to {side} of CL (stiffener 2{side[0].upper()}), 2.00 m above tank top"


def test_irregular_frame_spacing_table():
    doc = yaml.safe_load(PLAN)
    doc["hold"]["frame_spacing_m"] = [{"from_frame": 140, "spacing_m": 0.8}, {"from_frame": 145, "spacing_m": 0.6}]
    frames = ShipFrames.from_plan(parse_survey_plan(doc, "plan.yaml"))
    assert frames.frame_at(4.0) == pytest.approx(145.0)
    assert frames.frame_at(4.9) == pytest.approx(146.5)
    assert frames.x_of(146.5) == pytest.approx(4.9, abs=1e-6)


@pytest.mark.parametrize("change,message", [
    ({"wall": "forepeak"}, "field 'wall.name': 'forepeak' is not one of"),
    ({"hold": {"aft_bulkhead_frame": 140, "frame_spacing_m": -0.8}}, "field 'hold.frame_spacing_m': -0.8"),
    ({"colour": "red"}, "field 'colour': unknown key"),
    ({"vessel": {"name": "X", "imo": "12"}}, "field 'vessel.imo': '12' is not an IMO number"),
    ({"format": "inspect_pipe.survey_plan/9"}, "field 'format'"),
    ({"takeoff": {"position_m": [1.0, 0.5, 0.0], "heading_deg": float("nan")}}, "field 'takeoff.heading_deg': Input should be a finite number"),
    ({"hold": {"aft_bulkhead_frame": float("inf"), "frame_spacing_m": 0.8}}, "field 'hold.aft_bulkhead_frame': Input should be a finite number"),
    ({"hold": {"aft_bulkhead_frame": 140, "frame_spacing_m": 0.8, "length_m": 12, "width_m": 10},
      "takeoff": {"position_m": [1000.0, 0.5, 0.0], "heading_deg": 0}}, "takeoff.position_m x = 1000 m lies outside the hold (0 to 12 m)"),
    ({"hold": {"aft_bulkhead_frame": 140, "frame_spacing_m": 0.8, "length_m": 12, "width_m": 10},
      "takeoff": {"position_m": [1.0, -7.0, 0.0], "heading_deg": 0}}, "takeoff.position_m y = -7 m lies outside the hold (-5 to 5 m)"),
    ({"control_points": [{"image": "images/000001.png", "pixel": [-3.0, 10.0], "wall_m": [1.0, 1.0]}]},
     "field 'control_points.0.pixel.0': -3.0: input should be greater than or equal to 0"),
    ({"control_points": [{"image": "images/000001.png", "pixel": [3.0, 10.0], "wall_m": [float("inf"), 1.0]}]},
     "field 'control_points.0.wall_m.0': Input should be a finite number"),
])
def test_nonsense_plans_get_one_line_naming_the_field(change, message):
    doc = yaml.safe_load(PLAN)
    doc.update(change)
    with pytest.raises(Exception) as err:
        parse_survey_plan(doc, "plan.yaml")
    text = str(err.value)
    assert text.startswith("plan.yaml: ") and message in text and "\n" not in text


@pytest.mark.slow
@pytest.mark.skipif(not SHIPPED_WALL.is_file(), reason="scenario asset missing")
def test_control_points_place_footage_without_vehicle_state(tmp_path):
    # GIVEN the left-wall sweep stripped of every vehicle state (footage without a log) and a plan
    # with two control points: a pixel of two frames and the wall point each shows
    import shutil

    from inspect_pipe.capture._geometry import distort_points

    flown = _fly_sweep(tmp_path, "left")
    sweep_dir = tmp_path / "no_state"
    shutil.copytree(flown, sweep_dir)
    lines = [json.loads(x) for x in (sweep_dir / "frames.jsonl").read_text().splitlines()]
    for x in lines:
        x["state"] = None
    (sweep_dir / "frames.jsonl").write_text("\n".join(json.dumps(x) for x in lines) + "\n")
    (sweep_dir / "COMPLETE").unlink(missing_ok=True)
    sweep = read_sweep(sweep_dir)
    cps = []
    for i, und in ((40, (120.0, 90.0)), (100, (250.0, 150.0))):
        f = sweep.frames[i]
        w = np.linalg.inv(f.truth.H_wall_m_to_frame) @ np.array([*und, 1.0])
        px = distort_points(sweep.meta.camera, np.array([und]))[0]
        cps.append({"image": f.image, "pixel": [float(px[0]), float(px[1])], "wall_m": [float(w[0] / w[2]), float(w[1] / w[2])]})
    doc = yaml.safe_load(PLAN)
    doc["control_points"] = cps
    plan = parse_survey_plan(doc, "plan.yaml")
    # WHEN it is mosaicked with the plan
    run_mosaic_sweep(sweep_dir, tmp_path / "mosaic", survey_plan=plan)
    # THEN the control points alone place every frame within 5 cm of the truth
    m = json.loads((tmp_path / "mosaic" / "mosaic.json").read_text())
    assert m["wall_fit"]["method"].startswith("similarity fitted to 2 control points")
    found, true = _wall_errors(sweep_dir, tmp_path / "mosaic")
    err = np.linalg.norm(found - true, axis=1).max()
    assert err <= 0.05, err


@pytest.mark.slow
@pytest.mark.skipif(not SHIPPED_WALL.is_file(), reason="scenario asset missing")
def test_report_of_a_side_shell_survey_speaks_ship_terms(tmp_path):
    # GIVEN the left-wall sweep and a plan for the port side shell
    from inspect_pipe.pipeline import run_pipeline
    from inspect_pipe.pipeline._steps import DetectConfig, RunConfig

    sweep = _fly_sweep(tmp_path, "left")
    plan = yaml.safe_load(PLAN)
    plan["limitations"] = ["hopper plating not surveyed (ladder access)"]
    from inspect_pipe.saliency_defects._onnx_detect import condition_state_onnx_path

    cfg = RunConfig(input=str(sweep), detect=DetectConfig(keyframe_spacing=1.0, model=str(condition_state_onnx_path())),
                    report={"pdf": False}, survey_plan=plan)
    # WHEN the pipeline runs (with the network that has condition states)
    run_pipeline(tmp_path / "run", cfg, log=lambda s: None)
    # THEN every entry carries its location in frames and height, consistent with its wall point
    reg = json.loads((tmp_path / "run" / "report" / "defects.json").read_text())
    assert reg["defects"]
    for d in reg["defects"]:
        loc = d["location"]
        u, v = d["centroid_wall_m"]
        assert loc["wall"] == "port_side_shell" and loc["frame"] == pytest.approx(140 + u / 0.8, abs=0.02)
        assert loc["above_tank_top_m"] == pytest.approx(v, abs=0.01) and loc["text"].startswith("Fr. ")
    csv_head = (tmp_path / "run" / "report" / "defects.csv").read_text().splitlines()[0]
    assert "location" in csv_head and "frame" in csv_head
    # AND the report carries the survey record, the limitations, and no raw dict text
    html = (tmp_path / "run" / "report" / "report.html").read_text()
    assert "Survey record" in html and "IMO 9074729" in html and "Hold Drones Ltd" in html
    assert "Limitations" in html and "hopper plating not surveyed" in html and "Signatures" in html
    assert reg["defects"][0]["location"]["text"] in html
    assert "{&#39;" not in html and "{'" not in html
    # AND hard rust is the corrosion in condition state poor or severe; corrosion entries carry their state
    assert "condition state poor or severe" in reg["traceability"]["hard_rust_rule"]
    corr = [d for d in reg["defects"] if d["class"] == "corrosion"]
    assert corr and all(d["severity"]["state"] in ("fair", "poor", "severe") for d in corr)
