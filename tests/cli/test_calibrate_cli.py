"""``inspect-pipe calibrate`` as a user runs it: the table, camera.yaml, one-line errors."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from inspect_pipe.capture._calibration import load_camera
from tests.capture.test_calibration import FIXTURES, chessboard_views

runner = CliRunner()


@pytest.fixture(scope="module")
def shots(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("shots")
    for k, v in enumerate(chessboard_views(8, seed=3)):
        cv2.imwrite(str(d / f"view{k:02d}.png"), v)
    cv2.imwrite(str(d / "view99_blank.png"), np.full((300, 400), 180, np.uint8))  # no board in it
    return d


def test_calibrate_writes_camera_yaml_and_names_dropped_views(tmp_path, shots):
    out = tmp_path / "camera.yaml"
    res = runner.invoke(app, ["calibrate", str(shots), "-o", str(out), "--board", "9x6", "--square-m", "0.03"])
    assert res.exit_code == 0, res.output
    assert "8 of 9 views used" in res.output
    assert "view99_blank.png" in res.output and "board not found" in res.output
    assert "RMS reprojection error" in res.output
    cam = load_camera(out)
    assert abs(cam.K[0, 0] - 430.0) < 0.005 * 430.0 and (cam.width, cam.height) == (400, 300)
    assert out.read_text().startswith("%YAML:1.0")


def test_two_real_views_are_too_few_and_nothing_is_written(tmp_path):
    out = tmp_path / "camera.yaml"
    res = runner.invoke(app, ["calibrate", str(FIXTURES / "left01.jpg"), str(FIXTURES / "left12.jpg"), "-o", str(out),
                              "--board", "9x6", "--square-m", "0.025"])
    assert res.exit_code == 2
    assert "found in only 2 of 2 images" in res.output and "Traceback" not in res.output
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_unreadable_image_is_one_line_exit_2(tmp_path, shots):
    bad = tmp_path / "broken.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n not really")
    out = tmp_path / "camera.yaml"
    res = runner.invoke(app, ["calibrate", str(shots / "view00.png"), str(bad), "-o", str(out), "--board", "9x6", "--square-m", "0.03"])
    assert res.exit_code == 2
    # (the reason, not the test's folder name, which holds "unreadable" too)
    assert "broken.png: truncated PNG (no IEND chunk)" in res.output and len(res.output.strip().splitlines()) == 1
    assert not out.exists()


def test_images_of_different_sizes_refused(tmp_path, shots):
    d = tmp_path / "mixed"
    d.mkdir()
    for p in sorted(shots.glob("view0*.png"))[:3]:
        shutil.copy(p, d / p.name)
    shutil.copy(FIXTURES / "left01.jpg", d / "z.jpg")
    res = runner.invoke(app, ["calibrate", str(d), "-o", str(tmp_path / "c.yaml"), "--board", "9x6", "--square-m", "0.03"])
    assert res.exit_code == 2 and "z.jpg" in res.output and "640x512" in res.output


@pytest.mark.parametrize("args, message", [
    (["--board", "9by6", "--square-m", "0.03"], "not COLSxROWS"),
    (["--board", "9x6", "--square-m", "-1"], "not a positive length"),
    (["--board", "9x6", "--square-m", "0.03", "--pattern", "circles"], "'circles' is not one of 'chessboard', 'charuco'"),
    (["--board", "7x5", "--square-m", "0.04", "--pattern", "charuco"], "needs the side of its markers"),
])
def test_bad_options_are_one_line_exit_2(tmp_path, shots, args, message):
    res = runner.invoke(app, ["calibrate", str(shots), "-o", str(tmp_path / "c.yaml"), *args])
    assert res.exit_code == 2 and message in res.output
    assert not (tmp_path / "c.yaml").exists()


def test_output_that_is_a_directory_is_one_line_exit_2(tmp_path, shots):
    res = runner.invoke(app, ["calibrate", str(shots), "-o", str(tmp_path), "--board", "9x6", "--square-m", "0.03"])
    assert res.exit_code == 2 and "is a directory" in res.output and "Traceback" not in res.output


def test_views_that_do_not_determine_the_camera_are_one_line_exit_2(tmp_path):
    # the same view three times: OpenCV returns a camera, but not a real one (fx/fy far from 1)
    d = tmp_path / "same"
    d.mkdir()
    view = chessboard_views(1, seed=4)[0]
    for k in range(3):
        cv2.imwrite(str(d / f"s{k}.png"), view)
    res = runner.invoke(app, ["calibrate", str(d), "-o", str(tmp_path / "c.yaml"), "--board", "9x6", "--square-m", "0.03"])
    assert res.exit_code == 2 and res.output.count("\n") == 1
    assert "the views do not determine the camera" in res.output and "tilted differently" in res.output
    assert not (tmp_path / "c.yaml").exists()


def test_charuco_board_from_the_command_line(tmp_path):
    from inspect_pipe.capture._calibration import Board
    from inspect_pipe.capture.synthetic_board import random_poses, render_view
    from tests.capture.test_calibration import TRUE

    board = Board(7, 5, 0.04, kind="charuco", marker_m=0.03, dictionary="DICT_5X5_100")
    img = board.charuco().generateImage((280, 200), marginSize=0, borderBits=1)
    rng = np.random.default_rng(8)
    for k, (r, t) in enumerate(random_poses(8, (0.28, 0.20), TRUE, distance_m=0.6, tilt_deg=30, rng=rng)):
        cv2.imwrite(str(tmp_path / f"c{k}.png"), render_view(TRUE, img, 0.001, r, t, origin_px=(-0.5, -0.5), supersample=2, rng=rng))
    out = tmp_path / "out" / "camera.yaml"
    res = runner.invoke(app, ["calibrate", str(tmp_path), "-o", str(out), "--pattern", "charuco", "--board", "7x5",
                              "--square-m", "0.04", "--marker-m", "0.03", "--dictionary", "DICT_5X5_100"])
    assert res.exit_code == 0, res.output
    cam = load_camera(out)
    assert abs(cam.K[0, 0] - 430.0) < 0.005 * 430.0 and abs(cam.K[1, 2] - 148.0) < 0.01 * 148.0
    text = out.read_text()
    assert "board_kind: charuco" in text and "aruco_dictionary: DICT_5X5_100" in text
    res = runner.invoke(app, ["calibrate", str(tmp_path), "-o", str(out), "--pattern", "charuco", "--board", "7x5",
                              "--square-m", "0.04", "--marker-m", "0.03", "--dictionary", "DICT_NOPE"])
    assert res.exit_code == 2 and "DICT_NOPE" in res.output


def test_outlier_view_dropped_unless_keep_outliers(tmp_path, shots):
    # GIVEN the views plus one whose upper half is shifted 3 px sideways (as a rolling shutter in motion)
    d = tmp_path / "views"
    shutil.copytree(shots, d)
    bad = cv2.imread(str(shots / "view03.png"), cv2.IMREAD_GRAYSCALE)
    bad[:150] = np.roll(bad[:150], 3, axis=1)
    cv2.imwrite(str(d / "view50_sheared.png"), bad)
    out = tmp_path / "c.yaml"
    res = runner.invoke(app, ["calibrate", str(d), "-o", str(out), "--board", "9x6", "--square-m", "0.03"])
    assert res.exit_code == 0, res.output
    row = next(line for line in res.output.splitlines() if "view50_sheared.png" in line)
    assert "dropped: outlier" in row and "8 of 10 views used" in res.output
    assert "view50_sheared.png: outlier" in out.read_text()
    res = runner.invoke(app, ["calibrate", str(d), "-o", str(out), "--board", "9x6", "--square-m", "0.03", "--keep-outliers"])
    assert res.exit_code == 0, res.output
    assert "9 of 10 views used" in res.output and "dropped: outlier" not in res.output
