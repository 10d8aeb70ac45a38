"""Camera calibration: a known camera recovered from rendered chessboard and ChArUco views, the
outlier rule, the camera file (OpenCV FileStorage and ROS camera_info), resolution checks."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from inspect_pipe.capture._calibration import (
    Board,
    calibrate,
    calibrate_images,
    detect_board,
    fit_camera,
    load_camera,
    parse_board,
    write_camera_yaml,
)
from inspect_pipe.capture._geometry import CameraModel
from inspect_pipe.capture.synthetic_board import chessboard_image, random_poses, render_view
from inspect_pipe.errors import InputError

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures" / "calibration"
TRUE = CameraModel(np.array([[430.0, 0.0, 203.0], [0.0, 431.5, 148.0], [0.0, 0.0, 1.0]]),
                   np.array([-0.12, 0.09, 0.0008, -0.0006, 0.0]), 400, 300, "truth")
SQUARE_M = 0.03
SQ_PX = 30


def chessboard_views(n: int, seed: int = 1) -> list[np.ndarray]:
    """``n`` views of a 9x6 (inner corners) chessboard, 3 cm squares, seen by TRUE."""
    img, margin = chessboard_image(9, 6, SQ_PX)
    origin = (margin * SQ_PX + SQ_PX - 0.5,) * 2  # first inner corner = board origin
    rng = np.random.default_rng(seed)
    poses = random_poses(n, (8 * SQUARE_M, 5 * SQUARE_M), TRUE, distance_m=0.5, rng=rng)
    return [render_view(TRUE, img, SQUARE_M / SQ_PX, r, t, origin_px=origin, supersample=2, rng=rng) for r, t in poses]


@pytest.fixture(scope="module")
def views() -> list[np.ndarray]:
    return chessboard_views(12)


def test_known_camera_is_recovered_from_rendered_chessboards(views):
    # GIVEN 12 chessboard views rendered through a known camera (blur 0.6 px, read noise 2 DN)
    board = Board(9, 6, SQUARE_M)
    det = [(f"v{k}", detect_board(v, board)) for k, v in enumerate(views)]
    assert all(d is not None and len(d[0]) == 54 for _, d in det)
    # WHEN calibrated
    cal = calibrate(det, (400, 300), board)
    # THEN every view is kept, the RMS is well under a tenth of a pixel, K within 0.3 %
    assert [v.status for v in cal.views] == ["kept"] * 12
    assert cal.rms_px < 0.1
    K = cal.camera.K
    for got, want in [(K[0, 0], 430.0), (K[1, 1], 431.5), (K[0, 2], 203.0), (K[1, 2], 148.0)]:
        assert abs(got - want) < 0.003 * want, (got, want)
    assert abs(cal.camera.dist[0] - (-0.12)) < 0.02


def test_outlier_view_is_named_and_dropped(views):
    # GIVEN one view whose corners are displaced as a misdetection would (2.5 px on half of them)
    board = Board(9, 6, SQUARE_M)
    det = [(f"v{k}", detect_board(v, board)) for k, v in enumerate(views)]
    pts, obj = det[4][1]
    bad = pts.copy()
    bad[:27] += 2.5
    det[4] = ("v4", (bad, obj))
    cal = calibrate(det, (400, 300), board)
    # THEN it alone is dropped and the camera is as good as without it
    assert [v.name for v in cal.views if v.status == "outlier"] == ["v4"]
    assert cal.views[4].error_px > 0.5
    assert cal.rms_px < 0.1
    assert abs(cal.camera.K[0, 0] - 430.0) < 0.003 * 430.0


def test_no_board_views_are_dropped_and_too_few_views_refused(views):
    board = Board(9, 6, SQUARE_M)
    blank = np.full((300, 400), 200, np.uint8)
    det = [("blank", detect_board(blank, board))] + [(f"v{k}", detect_board(v, board)) for k, v in enumerate(views[:4])]
    assert det[0][1] is None
    cal = calibrate(det, (400, 300), board)
    assert cal.views[0].status == "no board" and len(cal.kept) == 4
    with pytest.raises(InputError, match="found in only 2 of 3"):
        calibrate(det[:3], (400, 300), board, where="x")
    with pytest.raises(InputError, match="found in none"):
        calibrate(det[:1], (400, 300), board, where="x")


def test_charuco_board_calibrates():
    # GIVEN a ChArUco board (7 x 5 squares of 4 cm, 3 cm markers) rendered through the known camera
    board = Board(7, 5, 0.04, kind="charuco", marker_m=0.03, dictionary="DICT_5X5_100")
    px_per_sq = 40
    img = board.charuco().generateImage((7 * px_per_sq, 5 * px_per_sq), marginSize=0, borderBits=1)
    rng = np.random.default_rng(5)
    poses = random_poses(10, (0.28, 0.20), TRUE, distance_m=0.6, tilt_deg=30, rng=rng)
    det = []
    for k, (r, t) in enumerate(poses):
        v = render_view(TRUE, img, 0.04 / px_per_sq, r, t, origin_px=(-0.5, -0.5), supersample=2, rng=rng)
        det.append((f"c{k}", detect_board(v, board)))
    assert sum(d is not None for _, d in det) >= 8
    cal = calibrate(det, (400, 300), board)
    assert cal.rms_px < 0.2
    assert abs(cal.camera.K[0, 0] - 430.0) < 0.005 * 430.0
    assert abs(cal.camera.K[0, 2] - 203.0) < 0.01 * 203.0


def test_real_views_corners_found():
    board = Board(9, 6, 1.0)
    for name in ("left01.jpg", "left12.jpg"):
        g = cv2.imread(str(FIXTURES / name), cv2.IMREAD_GRAYSCALE)
        pts, obj = detect_board(g, board)
        assert pts.shape == (54, 2) and obj.shape == (54, 3)
        assert np.all((pts > 0) & (pts < [640, 512]))
    with pytest.raises(InputError, match="found in only 2 of 2"):
        calibrate_images([FIXTURES], board)


# ----------------------------------------------------------------------------- the camera file


@pytest.fixture(scope="module")
def cal(views):
    board = Board(9, 6, SQUARE_M)
    return calibrate([(f"v{k}.png", detect_board(v, board)) for k, v in enumerate(views)], (400, 300), board, name="cam A")


def test_camera_yaml_is_opencv_filestorage_and_reads_back(tmp_path, cal):
    path = tmp_path / "sub" / "camera.yaml"
    write_camera_yaml(path, cal)
    text = path.read_text()
    assert text.startswith("%YAML:1.0\n")
    assert "camera_matrix: !!opencv-matrix" in text and "distortion_coefficients: !!opencv-matrix" in text
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert int(fs.getNode("image_width").real()) == 400 and int(fs.getNode("image_height").real()) == 300
    assert abs(fs.getNode("avg_reprojection_error").real() - cal.rms_px) < 1e-9
    assert fs.getNode("per_view_reprojection_errors").mat().shape == (12, 1)
    fs.release()
    cam = load_camera(path)
    np.testing.assert_allclose(cam.K, cal.camera.K, rtol=1e-12)
    np.testing.assert_allclose(cam.dist, cal.camera.dist, rtol=1e-12)
    assert (cam.width, cam.height, cam.name) == (400, 300, "cam A")
    import hashlib

    assert cam.calibration["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    assert cam.calibration["source"] == str(path.resolve())
    assert abs(cam.calibration["rms_px"] - cal.rms_px) < 1e-5
    assert [p.name for p in tmp_path.joinpath("sub").iterdir()] == ["camera.yaml"]  # no temporary left


ROS = """image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [612.5, 0, 321.2, 0, 611.9, 239.4, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.41, 0.19, 0.001, -0.002, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [612.5, 0, 321.2, 0, 0, 611.9, 239.4, 0, 0, 0, 1, 0]
"""


def test_ros_camera_info_reads(tmp_path):
    p = tmp_path / "ost.yaml"
    p.write_text(ROS)
    cam = load_camera(p)
    assert (cam.width, cam.height, cam.name) == (640, 480, "narrow_stereo")
    assert cam.K[0, 0] == 612.5 and cam.K[1, 2] == 239.4
    np.testing.assert_allclose(cam.dist, [-0.41, 0.19, 0.001, -0.002, 0])
    assert cam.calibration["rms_px"] is None and len(cam.calibration["sha256"]) == 64


@pytest.mark.parametrize("text, message", [
    ("image_width: [640\n", "not valid YAML"),
    ("foo: 1\n", "not a camera calibration"),
    (ROS.replace("plumb_bob", "equidistant"), "distortion_model 'equidistant' not supported"),
    (ROS.replace("data: [612.5, 0, 321.2, 0, 611.9, 239.4, 0, 0, 1]", "data: [612.5, 0, 321.2]"), "'camera_matrix' has 3 values"),
    (ROS.replace("image_width: 640", "image_width: -640"), "must be positive integers"),
    ("%YAML:1.0\n---\nimage_width: 640\n", "'camera_matrix' missing"),
    ("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: [\n", "not a readable OpenCV FileStorage"),
])
def test_malformed_camera_file_is_one_line_error(tmp_path, text, message):
    p = tmp_path / "camera.yaml"
    p.write_text(text)
    with pytest.raises(InputError, match=message.replace("[", r"\[").replace("(", r"\(")) as err:
        load_camera(p)
    assert str(p) in str(err.value) and "\n" not in str(err.value)


def test_missing_camera_file(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_camera(tmp_path / "none.yaml")


def test_fit_camera_scales_same_aspect_and_refuses_another(cal):
    cam = cal.camera
    assert fit_camera(cam, 400, 300) is cam
    half = fit_camera(cam, 200, 150)
    assert half.K[0, 0] == pytest.approx(cam.K[0, 0] / 2) and half.K[0, 2] == pytest.approx((cam.K[0, 2] + 0.5) / 2 - 0.5)
    np.testing.assert_array_equal(half.dist, cam.dist)
    assert half.calibration["scaled_from_wh"] == [400, 300]
    # a point projects to the same place in the scaled image (half the coordinates, pixel centres)
    X = np.array([[0.1, -0.05, 1.0]])
    p_full = cv2.projectPoints(X, np.zeros(3), np.zeros(3), cam.K, cam.dist)[0].ravel()
    p_half = cv2.projectPoints(X, np.zeros(3), np.zeros(3), half.K, half.dist)[0].ravel()
    np.testing.assert_allclose((p_full + 0.5) / 2 - 0.5, p_half, atol=1e-9)
    with pytest.raises(InputError, match="calibrated at 400x300, but the frames are 640x360"):
        fit_camera(cam, 640, 360)


def test_parse_board():
    assert parse_board("9x6") == (9, 6) and parse_board(" 7 X 5 ") == (7, 5)
    for bad in ("9", "ax6", "9x6x2", ""):
        with pytest.raises(InputError):
            parse_board(bad)


def test_detected_corners_match_cv2_projectpoints():
    # GIVEN a chessboard view rendered at a known pose; WHEN its corners are detected
    img, margin = chessboard_image(9, 6, SQ_PX)
    origin = (margin * SQ_PX + SQ_PX - 0.5,) * 2
    rng = np.random.default_rng(11)
    (rvec, tvec), = random_poses(1, (8 * SQUARE_M, 5 * SQUARE_M), TRUE, distance_m=0.5, rng=rng)
    view = render_view(TRUE, img, SQUARE_M / SQ_PX, rvec, tvec, origin_px=origin, supersample=3, rng=rng)
    board = Board(9, 6, SQUARE_M)
    pts, obj = detect_board(view, board)
    # THEN they lie where OpenCV projects the board's corners through the true camera (to 0.1 px)
    truth = cv2.projectPoints(obj.astype(np.float64), rvec, tvec, TRUE.K, TRUE.dist)[0].reshape(-1, 2)
    err = min(np.linalg.norm(pts - truth, axis=1).mean(), np.linalg.norm(pts[::-1] - truth, axis=1).mean())  # 180-degree symmetric grid
    assert err < 0.1, err


def test_charuco_board_of_the_legacy_layout_is_detected():
    # GIVEN a 7x6 ChArUco board printed with OpenCV < 4.6's layout (even number of rows)
    board = Board(7, 6, 0.04, kind="charuco", marker_m=0.03, dictionary="DICT_5X5_100")
    img = board.charuco(legacy=True).generateImage((280, 240), marginSize=0, borderBits=1)
    rng = np.random.default_rng(2)
    (r, t), = random_poses(1, (0.28, 0.24), TRUE, distance_m=0.6, tilt_deg=20, rng=rng)
    view = render_view(TRUE, img, 0.001, r, t, origin_px=(-0.5, -0.5), supersample=2, rng=rng)
    # THEN its 30 inner corners are found where the true camera puts them
    pts, obj = detect_board(view, board)
    assert len(pts) == 30
    truth = cv2.projectPoints(obj.astype(np.float64), r, t, TRUE.K, TRUE.dist)[0].reshape(-1, 2)
    assert np.linalg.norm(pts - truth, axis=1).mean() < 0.2
