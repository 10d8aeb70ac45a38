"""A sweep as mosaic input: undistortion, metric scale and placement on the wall in metres."""

from __future__ import annotations

import json

import cv2
import numpy as np

from inspect_pipe.mosaic import run_mosaic_sweep
from inspect_pipe.mosaic.synthetic import render_frame, textured_wall

F_PX, W, H = 300.0, 256, 192
CX, CY = (W - 1) / 2, (H - 1) / 2
M_TEX = 0.002  # texture metres per pixel
U0, V0 = 3.0, 3.0  # wall (u, v) of the texture's top-left corner
HOLD_L, HOLD_W = 12.0, 10.0
CAM_T = np.array([0.1, 0.0, 0.0])  # camera 10 cm ahead of the vehicle centre


def _frame_to_texture(u_c: float, v_c: float, d: float) -> np.ndarray:
    m = d / F_PX
    return np.array([
        [m / M_TEX, 0, (u_c - CX * m - U0) / M_TEX],
        [0, m / M_TEX, (V0 - v_c - CY * m) / M_TEX],
        [0, 0, 1.0],
    ])


def _write_sweep(root, rng, dist=(0.0, 0.0, 0.0, 0.0, 0.0), odometry_sigma_m=0.01):
    wall = textured_wall(900, 700, rng)
    (root / "images").mkdir(parents=True)
    K = [[F_PX, 0, CX], [0, F_PX, CY], [0, 0, 1]]
    meta = {
        "format": "inspect_pipe.sweep/1", "software_version": "test", "created_utc": None, "image_format": "png",
        "rate_hz": 10.0, "time_base": "simulation_s", "source": {"kind": "test"},
        "camera": {"model": "pinhole_opencv", "name": "test", "width": W, "height": H, "K": K, "dist": list(dist)},
        "cam_to_body": {"R": np.eye(3).tolist(), "t_m": CAM_T.tolist()},
        "survey": {"vessel": None, "hold": None, "wall": None, "frame_spacing_m": None, "reference_frame": None},
        "simulation": {"scenario": "test", "hold": {"length_m": HOLD_L, "width_m": HOLD_W, "height_m": 16}},
    }
    (root / "sweep.json").write_text(json.dumps(meta))
    truth = {}
    lines = []
    d = 0.8
    k = 0
    drift = 0.0
    for p, v_c in enumerate([2.55, 2.4, 2.25]):
        us = np.linspace(3.35, 4.15, 9)
        for u_c in (us if p % 2 == 0 else us[::-1]):
            Ht = _frame_to_texture(u_c, v_c, d)
            img = render_frame(wall, Ht, (W, H))
            if np.any(dist):
                # distort: the sweep stores what a real lens would give
                mx, my = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
                pts = np.stack([mx.ravel(), my.ravel()], 1).reshape(-1, 1, 2)
                und = cv2.undistortPoints(pts, np.array(K), np.array(dist), P=np.array(K)).reshape(H, W, 2)
                img = cv2.remap(img, und[..., 0], und[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
            name = f"images/{k:06d}.png"
            cv2.imwrite(str(root / name), img)
            drift += 0.001
            y_c = HOLD_W / 2 - u_c
            pos = [HOLD_L - d - CAM_T[0], y_c + drift + rng.normal(0, odometry_sigma_m), v_c + rng.normal(0, odometry_sigma_m)]
            lines.append(json.dumps({"index": k, "image": name, "t_s": 0.1 * k, "exposure_s": 0.004,
                                     "state": {"t_s": 0.1 * k, "position_m": pos, "dist_front_m": d + CAM_T[0],
                                               "height_m": v_c, "velocity_m_s": [0, 0, 0], "est_mode": 0,
                                               "fsm": "flying", "inspection_mode": True}}))
            truth[k] = Ht
            k += 1
    (root / "frames.jsonl").write_text("\n".join(lines) + "\n")
    return truth


def _apply(M, xy):
    p = M @ np.array([xy[0], xy[1], 1.0])
    return p[:2] / p[2]


def test_sweep_mosaic_is_placed_on_the_wall_in_metres(tmp_path):
    # GIVEN a 3-pass sweep 0.8 m from the wall, with odometry noise (1 cm) and drift (1 mm a frame, 1 cm/s)
    truth = _write_sweep(tmp_path / "sweep", np.random.default_rng(3))
    # WHEN it is mosaicked
    res = run_mosaic_sweep(tmp_path / "sweep", tmp_path / "out")
    doc = json.loads((tmp_path / "out" / "mosaic.json").read_text())
    assert not res.problems and len(doc["frames"]) == len(truth)
    # THEN the scale is the camera's: distance / focal length
    assert abs(doc["m_per_px"] - 0.8 / F_PX) / (0.8 / F_PX) < 0.01
    # AND a wall point seen in any frame maps, through the mosaic, to its true wall position
    A = np.array(doc["wall_from_mosaic"])
    errs = []
    for f in doc["frames"]:
        Hf = np.array(f["H"])
        for xy in ([20, 20], [W - 20, H / 2], [W / 2, H - 20]):
            col, row = _apply(truth[f["index"]], xy)
            true_uv = np.array([U0 + col * M_TEX, V0 - row * M_TEX])
            errs.append(np.linalg.norm(_apply(A, _apply(Hf, xy)) - true_uv))
    # odometry drifts by 2.7 cm over the sweep; the mosaic keeps the shape, the fit only places it
    assert np.max(errs) < 0.03, np.max(errs)
    assert doc["wall_fit"]["rms_m"] < 0.05
    assert all("t_s" in f for f in doc["frames"])
    # AND the odometry tied each frame to the next in the pose adjustment (1 cm of noise against the 4 mm the prior
    # assumes: the fit sits that many sigmas from it)
    odo = doc["groups"][0]["odometry_prior"]
    assert odo["used"] and odo["displacements"] == len(truth) - 1 and 1.0 < odo["rms_sigma"] < 5.0, odo


def test_lens_distortion_is_removed_before_registration(tmp_path):
    truth = _write_sweep(tmp_path / "sweep", np.random.default_rng(4), dist=(-0.25, 0.08, 0.0, 0.0, 0.0))
    run_mosaic_sweep(tmp_path / "sweep", tmp_path / "out")
    doc = json.loads((tmp_path / "out" / "mosaic.json").read_text())
    assert len(doc["frames"]) == len(truth)
    g = doc["groups"][0]
    assert g["rms_px"] < 0.5, g  # barrel distortion left in would leave pixels of disagreement


def test_truncated_manifest_still_mosaics_and_reports(tmp_path):
    _write_sweep(tmp_path / "sweep", np.random.default_rng(5))
    p = tmp_path / "sweep" / "frames.jsonl"
    data = p.read_bytes()
    p.write_bytes(data[: len(data) - 40])  # a capture killed in the middle of a line
    res = run_mosaic_sweep(tmp_path / "sweep", tmp_path / "out")
    doc = json.loads((tmp_path / "out" / "mosaic.json").read_text())
    assert len(doc["frames"]) == 26  # the whole frames before the cut
    assert not res.problems and res.warnings and "frames.jsonl" in res.warnings[0]  # the mosaic stands: a warning


def test_frames_taken_while_landed_are_not_mosaicked(tmp_path):
    _write_sweep(tmp_path / "sweep", np.random.default_rng(6))
    p = tmp_path / "sweep" / "frames.jsonl"
    lines = p.read_text().splitlines()
    first = json.loads(lines[0])
    first["state"]["fsm"] = "landed"
    lines[0] = json.dumps(first)
    p.write_text("\n".join(lines) + "\n")
    run_mosaic_sweep(tmp_path / "sweep", tmp_path / "out")
    doc = json.loads((tmp_path / "out" / "mosaic.json").read_text())
    assert [u["index"] for u in doc["unplaced"]] == [0]
    assert "landed" in doc["unplaced"][0]["reason"]


def test_sweep_without_frames_is_one_line_exit_2(tmp_path):
    from typer.testing import CliRunner

    from cli.main import app

    _write_sweep(tmp_path / "sweep", np.random.default_rng(7))
    (tmp_path / "sweep" / "frames.jsonl").write_text("")
    res = CliRunner().invoke(app, ["mosaic", str(tmp_path / "sweep"), "-o", str(tmp_path / "out"), "-q"])
    assert res.exit_code == 2
    assert "frames.jsonl" in res.output and "no readable frames" in res.output
    assert "Traceback" not in res.output


def test_frames_taken_while_taking_off_are_registered_for_the_wall_map_only(tmp_path):
    # GIVEN a sweep that starts on the ground: 3 frames landed, 6 taking off (climbing 4 cm a frame; the oldest
    # two see a plain wall, as a camera near the floor sees the paint below a hold's texture), then the 3-pass
    # survey
    rng = np.random.default_rng(7)
    truth = _write_sweep(tmp_path / "sweep", rng)
    p = tmp_path / "sweep" / "frames.jsonl"
    survey = [json.loads(x) for x in p.read_text().splitlines()]
    wall = textured_wall(900, 700, np.random.default_rng(7))
    pre = []
    u_c, d = 3.35, 0.8
    for k in range(9):
        v_c = 2.55 - 0.04 * max(0, 8 - k) if k >= 3 else 2.55 - 0.04 * 6
        fsm = "landed" if k < 3 else "taking_off"
        img = render_frame(wall, _frame_to_texture(u_c, v_c, d), (W, H))
        if k < 5:
            img[:] = 128  # plain paint: nothing to register
        name = f"images/pre{k:03d}.png"
        cv2.imwrite(str(tmp_path / "sweep" / name), img)
        pos = [HOLD_L - d - CAM_T[0], HOLD_W / 2 - u_c, 2.31 if k < 3 else min(v_c, 2.40)]
        pre.append({"index": k, "image": name, "t_s": 0.1 * k, "exposure_s": 0.004,
                    "state": {"t_s": 0.1 * k, "position_m": pos, "dist_front_m": d + CAM_T[0], "height_m": pos[2],
                              "velocity_m_s": [0, 0, 0], "est_mode": 0, "fsm": fsm, "inspection_mode": False}})
    for i, x in enumerate(survey):
        x["index"] = 9 + i
        x["t_s"] = x["state"]["t_s"] = 0.9 + 0.1 * i
    p.write_text("\n".join(json.dumps(x) for x in pre + survey) + "\n")
    # WHEN it is mosaicked
    run_mosaic_sweep(tmp_path / "sweep", tmp_path / "out")
    doc = json.loads((tmp_path / "out" / "mosaic.json").read_text())
    # THEN the textured take-off frames (5-8) are registered for the wall map's fit, back to the first plain one; they
    # are not blended into the mosaic, nor are the landed ones
    assert doc["wall_fit"]["take_off_frames"] == [5, 6, 7, 8]
    assert sorted(f["index"] for f in doc["frames"]) == list(range(9, 9 + len(truth)))
    assert "from zero at take-off" in doc["wall_fit"]["method"]


def test_a_control_point_on_an_image_outside_the_sweep_is_a_warning_not_silence(tmp_path):
    # GIVEN the sweep and a survey plan with two control points: one on frame 4, one naming an image the sweep lacks
    from inspect_pipe.ship import parse_survey_plan

    truth = _write_sweep(tmp_path / "sweep", np.random.default_rng(3))
    col, row = _apply(truth[4], (CX, CY))
    plan = parse_survey_plan({
        "format": "inspect_pipe.survey_plan/1", "vessel": {"name": "MV Test"}, "survey": {"type": "annual survey", "date": "2026-11-29"},
        "compartment": {"name": "Hold 1"}, "hold": {"aft_bulkhead_frame": 100, "frame_spacing_m": 0.8, "length_m": HOLD_L, "width_m": HOLD_W},
        "wall": "fore_transverse_bulkhead",
        "control_points": [{"image": "images/000004.png", "pixel": [CX, CY], "wall_m": [U0 + col * M_TEX, V0 - row * M_TEX]},
                           {"image": "images/999999.png", "pixel": [10.0, 10.0], "wall_m": [1.0, 1.0]}]}, "plan.yaml")
    # WHEN it is mosaicked with that plan
    res = run_mosaic_sweep(tmp_path / "sweep", tmp_path / "out", survey_plan=plan)
    # THEN the missing image's point is named in a warning, and the other still places the mosaic
    assert any("control_points.1: image 'images/999999.png' is not a frame of the sweep" in w for w in res.warnings), res.warnings
    doc = json.loads((tmp_path / "out" / "mosaic.json").read_text())
    assert "offset from 1 control point" in doc["wall_fit"]["method"]
