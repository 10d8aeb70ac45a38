"""Camera calibration (Zhang's method through OpenCV) and the camera file every command reads.

- :func:`detect_board`: a chessboard's inner corners (``findChessboardCorners`` then
  ``cornerSubPix``, as OpenCV's calibration sample) or a ChArUco board's corners (``aruco``).
- :func:`calibrate`: ``calibrateCamera`` (pinhole, distortion k1 k2 p1 p2 k3) on the views whose
  board was found; views whose own reprojection error is an outlier are dropped and the camera
  re-estimated without them (rule: :data:`OUTLIER_RULE`).
- :func:`write_camera_yaml`: OpenCV FileStorage YAML as OpenCV's calibration sample writes it
  (``camera_matrix``, ``distortion_coefficients``, ``image_width``, ``image_height``,
  ``avg_reprojection_error`` ...), written to a temporary file and renamed into place.
- :func:`load_camera`: that file, or a ROS ``camera_info`` YAML (``plumb_bob``), as a
  :class:`CameraModel` that records where it came from (``calibration``: source, sha256, rms_px).
- :func:`fit_camera`: a calibration checked against the frames' resolution (scaled when only the
  resolution differs and the aspect ratio is the same; refused otherwise).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from inspect_pipe._files import atomic_write
from inspect_pipe._images import imread, truncation
from inspect_pipe.capture._geometry import CameraModel
from inspect_pipe.errors import InputError

__all__ = [
    "Board",
    "Calibration",
    "OUTLIER_RULE",
    "ViewResult",
    "calibrate",
    "calibrate_images",
    "detect_board",
    "fit_camera",
    "load_camera",
    "parse_board",
    "scaled_note",
    "write_camera_yaml",
]

# A view is an outlier when its RMS reprojection error is above OUTLIER_FACTOR x the median of
# the views' errors AND above OUTLIER_FLOOR_PX (a set of excellent views does not lose its
# merely good ones). Chosen on synthetic calibration sets with misdetected views, among the rules
# that dropped no good view (docs/calibration.md, bench/bench_calibration.py).
OUTLIER_FACTOR = 2.0
OUTLIER_FLOOR_PX = 0.1
OUTLIER_RULE = (f"a view is dropped when its RMS reprojection error exceeds {OUTLIER_FACTOR:g} x the median view's "
                f"and {OUTLIER_FLOOR_PX:g} px; the camera is then re-estimated without it")
MIN_VIEWS = 3  # Zhang: three views of a plane determine the five intrinsics in general
MIN_CHARUCO_CORNERS = 8
# Refused when OpenCV's standard deviation of fx, fy, cx or cy exceeds this share of the focal
# length (the views do not constrain the camera: too few, or all seen alike)
MAX_REL_STD = 0.05
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


# =========================================================================== the board


@dataclass(frozen=True)
class Board:
    """A calibration target. ``chessboard``: ``cols`` x ``rows`` inner corners; ``charuco``:
    ``cols`` x ``rows`` squares with ArUco markers of side ``marker_m`` from ``dictionary``."""

    cols: int
    rows: int
    square_m: float
    kind: str = "chessboard"
    marker_m: float | None = None
    dictionary: str = "DICT_6X6_250"

    def __post_init__(self) -> None:
        if self.kind not in ("chessboard", "charuco"):
            raise InputError("--pattern", f"{self.kind!r} unknown", "chessboard or charuco")
        if self.cols < 2 or self.rows < 2 or (self.kind == "chessboard" and self.cols == self.rows == 2):
            raise InputError("--board", f"{self.cols}x{self.rows} is too small", "e.g. 9x6 inner corners")
        if not (self.square_m > 0 and math.isfinite(self.square_m)):
            raise InputError("--square-m", f"{self.square_m} is not a positive length")
        if self.square_m > 1.0:  # a printed or plate board: millimetres to centimetres a square
            raise InputError("--square-m", f"{self.square_m:g} m a square", "the side of one square in metres, e.g. 0.025")
        if self.kind == "charuco":
            if self.marker_m is None or not (0 < self.marker_m < self.square_m):
                if self.marker_m is None:
                    raise InputError("--marker-m", "missing: a ChArUco board needs the side of its markers",
                                     f"give --marker-m, in m, smaller than the square's {self.square_m:g}")
                raise InputError("--marker-m", f"{self.marker_m:g}: a ChArUco marker must be smaller than the square "
                                 f"({self.square_m:g} m) and more than 0")
            if not hasattr(cv2.aruco, self.dictionary):
                raise InputError("--dictionary", f"{self.dictionary!r} is not an OpenCV ArUco dictionary", "e.g. DICT_6X6_250, DICT_5X5_100, DICT_4X4_50")

    @property
    def pattern_size(self) -> tuple[int, int]:
        return self.cols, self.rows

    def object_points(self) -> np.ndarray:
        """(N, 3) float32 corner positions on the board (m), in the detector's order."""
        if self.kind == "charuco":
            return np.asarray(self.charuco().getChessboardCorners(), np.float32).reshape(-1, 3)
        p = np.zeros((self.cols * self.rows, 3), np.float32)
        p[:, :2] = np.mgrid[0:self.cols, 0:self.rows].T.reshape(-1, 2) * self.square_m
        return p

    def charuco(self, legacy: bool = False):
        """OpenCV's board; ``legacy``: the layout OpenCV < 4.6 printed for an even number of rows."""
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        b = cv2.aruco.CharucoBoard((self.cols, self.rows), self.square_m, self.marker_m, d)
        if legacy:
            b.setLegacyPattern(True)
        return b

    def describe(self) -> str:
        if self.kind == "charuco":
            return f"ChArUco {self.cols}x{self.rows} squares of {self.square_m:g} m, markers {self.marker_m:g} m, {self.dictionary}"
        return f"chessboard {self.cols}x{self.rows} inner corners, squares of {self.square_m:g} m"


def parse_board(text: str) -> tuple[int, int]:
    """``"9x6"`` -> (9, 6)."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX*]\s*(\d+)\s*", text or "")
    if not m:
        raise InputError("--board", f"{text!r} is not COLSxROWS", "e.g. --board 9x6 (a chessboard's inner corners)")
    return int(m.group(1)), int(m.group(2))


# =========================================================================== detection


def detect_board(gray: np.ndarray, board: Board) -> tuple[np.ndarray, np.ndarray] | None:
    """Corners of ``board`` in a grey image: (image points (N, 2) float32, object points (N, 3)
    float32), or None when the board is not found."""
    if board.kind == "charuco":
        corners, ids, _, marker_ids = cv2.aruco.CharucoDetector(board.charuco()).detectBoard(gray)
        if (ids is None or len(ids) < MIN_CHARUCO_CORNERS) and marker_ids is not None and len(marker_ids) >= 4 and board.rows % 2 == 0:
            # markers seen but no corners interpolated: a board printed by OpenCV < 4.6 (legacy layout)
            corners, ids, _, _ = cv2.aruco.CharucoDetector(board.charuco(legacy=True)).detectBoard(gray)
        if corners is None or ids is None or len(ids) < MIN_CHARUCO_CORNERS:
            return None
        obj = board.object_points()[ids.ravel()]
        return np.asarray(corners, np.float32).reshape(-1, 2), obj
    found, corners = cv2.findChessboardCorners(gray, board.pattern_size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found:
        return None
    # OpenCV's sample refines in an 11x11 half-window; smaller where the squares are small, so the
    # window never reaches the next corner
    c = corners.reshape(-1, 2)
    grid = c.reshape(board.rows, board.cols, 2)
    spacing = min(np.linalg.norm(np.diff(grid, axis=1), axis=2).min(), np.linalg.norm(np.diff(grid, axis=0), axis=2).min())
    half = int(max(2, min(11, spacing * 0.5 - 1)))
    corners = cv2.cornerSubPix(gray, corners, (half, half), (-1, -1), SUBPIX_CRITERIA)
    return corners.reshape(-1, 2).astype(np.float32), board.object_points()


# =========================================================================== calibration


@dataclass(frozen=True)
class ViewResult:
    name: str
    status: str  # "kept", "no board", "outlier"
    n_points: int = 0
    error_px: float | None = None  # RMS reprojection error in the calibration that judged it


@dataclass(frozen=True)
class Calibration:
    camera: CameraModel
    rms_px: float  # over every point of the kept views (OpenCV's figure)
    views: tuple[ViewResult, ...]
    board: Board
    flags: int = 0
    rvecs: tuple[np.ndarray, ...] = field(default=(), repr=False)
    tvecs: tuple[np.ndarray, ...] = field(default=(), repr=False)
    image_points: tuple[np.ndarray, ...] = field(default=(), repr=False)  # kept views, in order
    std_px: tuple[float, ...] = ()  # OpenCV's standard deviations of fx, fy, cx, cy (px)

    @property
    def kept(self) -> list[ViewResult]:
        return [v for v in self.views if v.status == "kept"]


def _calibrate_once(obj: list[np.ndarray], img: list[np.ndarray], size_wh: tuple[int, int], flags: int, where: str):
    try:
        rms, K, dist, rvecs, tvecs, std, _, per_view = cv2.calibrateCameraExtended(
            obj, img, size_wh, None, None, flags=flags,
            criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12))
    except cv2.error as err:  # degenerate views (all parallel to the image plane, too few corners)
        why = (getattr(err, "err", None) or str(err)).strip().splitlines()[-1][:120]
        raise InputError(where, f"OpenCV could not calibrate from these views ({why})",
                         "take more views, tilted differently, covering the image") from None
    if not (np.all(np.isfinite(K)) and np.isfinite(rms) and K[0, 0] > 0 and K[1, 1] > 0):
        raise InputError(where, "the calibration diverged", "take more views, tilted differently, covering the image")
    std = np.asarray(std, float).ravel()[:4]  # fx, fy, cx, cy: OpenCV's standard deviations
    rel = std / np.array([K[0, 0], K[1, 1], K[0, 0], K[1, 1]])
    hint = "take more views, tilted differently (up to about 40 degrees), covering the image"
    if not (0.5 < K[0, 0] / K[1, 1] < 2.0):
        raise InputError(where, f"the views do not determine the camera (fx/fy came out {K[0, 0] / K[1, 1]:.2f})", hint)
    rel = np.nan_to_num(rel, nan=np.inf)
    if rel.max() > MAX_REL_STD:
        worst = ("fx", "fy", "cx", "cy")[int(np.argmax(rel))]
        raise InputError(where, f"the views do not determine the camera ({worst} uncertain by {100 * rel.max():.0f} % of the focal length)", hint)
    return float(rms), K, dist.ravel()[:5], rvecs, tvecs, per_view.ravel(), std


def calibrate(
    detections: list[tuple[str, tuple[np.ndarray, np.ndarray] | None]],
    size_wh: tuple[int, int],
    board: Board,
    *,
    flags: int = 0,
    outlier_factor: float = OUTLIER_FACTOR,
    outlier_floor_px: float = OUTLIER_FLOOR_PX,
    min_views: int = MIN_VIEWS,
    name: str = "camera",
    where: str = "calibration",
) -> Calibration:
    """Calibrate from named detections (None: board not found). Outlier views (see
    :data:`OUTLIER_RULE`) are dropped and the camera re-estimated, until none is left or only
    ``min_views`` remain. Raises :class:`InputError` when fewer than ``min_views`` views carry
    the board."""
    status = {n: ("no board" if d is None else "kept") for n, d in detections}
    errors: dict[str, float] = {}
    good = [(n, d) for n, d in detections if d is not None]
    if not good:
        raise InputError(where, f"the board ({board.describe()}) was found in none of the {len(detections)} images",
                         "check --board (inner corners for a chessboard) and that the whole board is in view")
    if len(good) < min_views:
        raise InputError(where, f"the board was found in only {len(good)} of {len(detections)} images",
                         f"at least {min_views} views of the board, tilted differently, are needed")
    while True:
        names = [n for n, _ in good]
        rms, K, dist, rvecs, tvecs, per_view, std = _calibrate_once([d[1] for _, d in good], [d[0] for _, d in good], size_wh, flags, where)
        for n, e in zip(names, per_view):
            errors[n] = float(e)
        med = float(np.median(per_view))
        limit = max(outlier_factor * med, outlier_floor_px)
        bad = [i for i, e in enumerate(per_view) if e > limit]
        if not bad or len(good) - len(bad) < min_views:
            break
        for i in bad:
            status[names[i]] = "outlier"
        good = [g for i, g in enumerate(good) if i not in set(bad)]
    w, h = size_wh
    cam = CameraModel(np.asarray(K, float), np.asarray(dist, float), int(w), int(h), name)
    views = tuple(ViewResult(n, status[n], 0 if d is None else len(d[0]), errors.get(n)) for n, d in detections)
    return Calibration(cam, rms, views, board, flags, tuple(rvecs), tuple(tvecs), tuple(d[0] for _, d in good), tuple(float(x) for x in std))


def read_grey(path: Path) -> np.ndarray:
    """An image file as 8-bit grey; :class:`InputError` when it cannot be read."""
    path = Path(path)
    if not path.is_file():
        raise InputError(str(path), "not found" if not path.exists() else "not a file", "give calibration images (PNG, JPEG ...)")
    why = truncation(path)
    if why:
        raise InputError(str(path), why, "copy the image again, or leave it out")
    img = imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None or img.size == 0:
        raise InputError(str(path), "unreadable or not an image", "give calibration images (PNG, JPEG ...)")
    return img


def expand_images(paths: list[Path]) -> list[Path]:
    """Files as given; a folder stands for its images, sorted by name."""
    out: list[Path] = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            found = sorted(q for q in p.iterdir() if q.is_file() and q.suffix.lower() in IMAGE_SUFFIXES)
            if not found:
                raise InputError(str(p), "no images in this folder", f"expected files ending in {', '.join(IMAGE_SUFFIXES)}")
            out.extend(found)
        else:
            out.append(p)
    if not out:
        raise InputError("IMAGES", "no calibration image given")
    return out


def calibrate_images(paths: list[Path], board: Board, *, progress=None, **kw) -> Calibration:
    """Detect the board in every image (all of the same size) and :func:`calibrate`."""
    paths = expand_images(paths)
    detections = []
    size = None
    for k, p in enumerate(paths):
        g = read_grey(p)
        if size is None:
            size, first = g.shape[::-1], p
        elif g.shape[::-1] != size:
            raise InputError(str(p), f"is {g.shape[1]}x{g.shape[0]}, but {first.name} is {size[0]}x{size[1]}",
                             "calibrate one camera at one resolution")
        detections.append((str(p), detect_board(g, board)))
        if progress:
            progress(k + 1, len(paths))
    names = [Path(n).name for n, _ in detections]
    if len(set(names)) == len(names):
        detections = [(Path(n).name, d) for n, d in detections]
    folders = sorted({str(p.parent) for p in paths})
    where = f"{folders[0]} ({len(paths)} images)" if len(folders) == 1 else f"{len(paths)} images in {len(folders)} folders"
    return calibrate(detections, size, board, where=where, **kw)


# =========================================================================== the camera file


def write_camera_yaml(path: Path, cal: Calibration) -> None:
    """``cal`` as OpenCV FileStorage YAML in the layout of OpenCV's calibration sample
    (``%YAML:1.0``, which every OpenCV version reads; OpenCV 5 itself would head it ``%YAML 1.2``),
    written to a temporary file beside ``path`` and renamed into place."""
    fs = cv2.FileStorage("camera.yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    cam = cal.camera
    kept = cal.kept
    fs.write("calibration_time", _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"))
    fs.write("nr_of_frames", len(kept))
    fs.write("image_width", int(cam.width))
    fs.write("image_height", int(cam.height))
    fs.write("board_width", int(cal.board.cols))
    fs.write("board_height", int(cal.board.rows))
    fs.write("square_size", float(cal.board.square_m))
    fs.write("board_kind", cal.board.kind)
    if cal.board.kind == "charuco":
        fs.write("marker_size", float(cal.board.marker_m))
        fs.write("aruco_dictionary", cal.board.dictionary)
    fs.write("flags", int(cal.flags))
    fs.write("camera_name", cam.name)
    fs.write("camera_matrix", np.asarray(cam.K, np.float64))
    fs.write("distortion_coefficients", np.asarray(cam.dist, np.float64).reshape(-1, 1))
    fs.write("avg_reprojection_error", float(cal.rms_px))
    fs.write("per_view_reprojection_errors", np.array([v.error_px for v in kept], np.float64).reshape(-1, 1))
    if cal.rvecs:
        ext = np.hstack([np.asarray(cal.rvecs, np.float64).reshape(-1, 3), np.asarray(cal.tvecs, np.float64).reshape(-1, 3)])
        fs.write("extrinsic_parameters", ext)
    fs.startWriteStruct("views", cv2.FileNode_SEQ)
    for v in kept:
        fs.write("", v.name)
    fs.endWriteStruct()
    fs.startWriteStruct("dropped_views", cv2.FileNode_SEQ)
    for v in cal.views:
        if v.status != "kept":
            fs.write("", f"{v.name}: {v.status}")
    fs.endWriteStruct()
    text = fs.releaseAndGetString()
    text = re.sub(r"\A%YAML[ :]1\.\d+\n", "%YAML:1.0\n", text)
    path = Path(path)
    if path.is_dir():
        raise InputError(str(path), "is a directory", "give the camera file to write, e.g. -o camera.yaml")
    try:
        atomic_write(path, text.encode())
    except OSError as err:
        raise InputError(str(path), f"cannot write ({err.strerror or err})", "choose a writable place") from None


def _sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _matrix(x, where: str, key: str, shape: tuple[int, ...] | None) -> np.ndarray:
    try:
        a = np.asarray(x, float)
    except (TypeError, ValueError):
        raise InputError(where, f"'{key}' is not a matrix of numbers") from None
    if shape is not None and a.size != int(np.prod(shape)):
        raise InputError(where, f"'{key}' has {a.size} values, expected {int(np.prod(shape))}")
    if not np.all(np.isfinite(a)):
        raise InputError(where, f"'{key}' has non-finite values")
    return a.reshape(shape) if shape is not None else a.ravel()


def _num_or_none(x) -> float | None:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if np.isfinite(v) and v >= 0 else None


def _camera(where: str, K, dist, w, h, name: str, rms) -> CameraModel:
    K = _matrix(K, where, "camera_matrix", (3, 3))
    dist = _matrix(dist, where, "distortion_coefficients", None)
    if not (isinstance(w, (int, float)) and isinstance(h, (int, float)) and w == int(w) and h == int(h) and w > 0 and h > 0):
        raise InputError(where, "'image_width' and 'image_height' must be positive integers")
    from inspect_pipe.formats import CameraCalibration, validate

    # the parsed values against the format's one declaration (pinhole K, plumb_bob distortion)
    validate(CameraCalibration, {"image_width": int(w), "image_height": int(h), "camera_matrix": K.tolist(),
                                 "distortion_coefficients": dist.tolist(), "camera_name": name or "camera",
                                 "avg_reprojection_error": _num_or_none(rms)}, where,
             "an OpenCV calibration file (%YAML:1.0) or a ROS camera_info YAML, pinhole with k1 k2 p1 p2 [k3] (plumb_bob)")
    d = np.zeros(5)
    d[: min(5, dist.size)] = dist[:5]
    calib = {"source": str(Path(where).resolve()), "sha256": _sha256(Path(where)),
             "rms_px": None if rms is None else round(float(rms), 6)}
    return CameraModel(K, d, int(w), int(h), name or "camera", calibration=calib)


_READ_HINT = "a camera.yaml written by `inspect-pipe calibrate` or OpenCV"


def _load_opencv_yaml(path: Path, text: str) -> CameraModel:
    """OpenCV FileStorage YAML (``%YAML:1.0``, ``!!opencv-matrix`` nodes) read with PyYAML: OpenCV's
    own reader can abort the process on a damaged matrix node (a missing ``cols``), where this
    gives one line."""
    from inspect_pipe._yaml import Loader, load_yaml

    where = str(path)

    class _Loader(Loader):
        pass

    _Loader.add_constructor("tag:yaml.org,2002:opencv-matrix", lambda loader, node: dict(loader.construct_mapping(node, deep=True)))
    body = re.sub(r"\A\s*%YAML:1\.0", "%YAML 1.1", text, count=1)
    try:
        doc = load_yaml(body, where, _READ_HINT, loader=_Loader)  # the project's reader, with one more mapping tag
    except InputError as err:
        raise InputError(where, f"not a readable OpenCV FileStorage file ({err.problem})", _READ_HINT) from None
    except TypeError:
        raise InputError(where, "not a readable OpenCV FileStorage file", _READ_HINT) from None
    if not isinstance(doc, dict):
        raise InputError(where, "not a readable OpenCV FileStorage file", _READ_HINT)
    for key in ("camera_matrix", "distortion_coefficients", "image_width", "image_height"):
        if doc.get(key) is None:
            raise InputError(where, f"'{key}' missing", "an OpenCV calibration file has camera_matrix, distortion_coefficients, image_width, image_height")

    def mat(key: str):
        m = doc[key]
        if not isinstance(m, dict) or not isinstance(m.get("data"), list):
            raise InputError(where, "'camera_matrix' or 'distortion_coefficients' is not an opencv-matrix")
        rows, cols = m.get("rows"), m.get("cols")
        if not (isinstance(rows, int) and isinstance(cols, int) and rows > 0 and cols > 0 and rows * cols == len(m["data"])):
            raise InputError(where, f"'{key}': rows x cols is not the number of values in data")
        return m["data"]

    K, dist = mat("camera_matrix"), mat("distortion_coefficients")
    name = doc.get("camera_name")
    rms = doc.get("avg_reprojection_error")
    return _camera(where, K, dist, doc["image_width"], doc["image_height"], name if isinstance(name, str) and name else path.stem,
                   rms if isinstance(rms, (int, float)) and not isinstance(rms, bool) else None)


def _load_opencv(path: Path) -> CameraModel:
    where = str(path)
    try:
        fs = cv2.FileStorage(where, cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError):  # OpenCV's parser error, surfacing through the binding
        raise InputError(where, "not a readable OpenCV FileStorage file", "a camera.yaml written by `inspect-pipe calibrate` or OpenCV") from None
    try:
        if not fs.isOpened():
            raise InputError(where, "not a readable OpenCV FileStorage file")

        def node(key: str, required: bool = True):
            n = fs.getNode(key)
            if n.empty() or n.isNone():
                if required:
                    raise InputError(where, f"'{key}' missing", "an OpenCV calibration file has camera_matrix, distortion_coefficients, image_width, image_height")
                return None
            return n

        K = node("camera_matrix").mat()
        dist = node("distortion_coefficients").mat()
        if K is None or dist is None:
            raise InputError(where, "'camera_matrix' or 'distortion_coefficients' is not an opencv-matrix")
        w, h = node("image_width").real(), node("image_height").real()
        name_node = node("camera_name", required=False)
        name = name_node.string() if name_node is not None and name_node.isString() else path.stem
        rms_node = node("avg_reprojection_error", required=False)
        rms = rms_node.real() if rms_node is not None and rms_node.isReal() else None
    except (cv2.error, SystemError):
        raise InputError(where, "not a readable OpenCV FileStorage file", "a camera.yaml written by `inspect-pipe calibrate` or OpenCV") from None
    finally:
        fs.release()
    return _camera(where, K, dist, w, h, name, rms)


def _load_ros(path: Path, text: str) -> CameraModel:
    from inspect_pipe._yaml import load_yaml

    where = str(path)
    doc = load_yaml(text, where, "an OpenCV calibration file (%YAML:1.0) or a ROS camera_info YAML")
    if not isinstance(doc, dict) or "camera_matrix" not in doc:
        raise InputError(where, "not a camera calibration", "an OpenCV calibration file (%YAML:1.0) or a ROS camera_info YAML with camera_matrix")

    def data(key: str):
        v = doc.get(key)
        if isinstance(v, dict) and "data" in v:
            return v["data"]
        if v is None:
            raise InputError(where, f"'{key}' missing", "a ROS camera_info YAML has camera_matrix and distortion_coefficients {rows, cols, data}")
        return v

    model = doc.get("distortion_model", "plumb_bob")
    if model != "plumb_bob":
        raise InputError(where, f"distortion_model {model!r} not supported", "plumb_bob (k1 k2 p1 p2 k3), as OpenCV's pinhole model")
    return _camera(where, data("camera_matrix"), data("distortion_coefficients"), doc.get("image_width"), doc.get("image_height"),
                   str(doc.get("camera_name") or path.stem), doc.get("avg_reprojection_error"))


def load_camera(path: str | Path) -> CameraModel:
    """A camera file: OpenCV FileStorage (YAML/XML/JSON, as ``inspect-pipe calibrate`` and OpenCV's
    calibration sample write it) or a ROS ``camera_info`` YAML. The model's ``calibration``
    records the file (resolved path), its sha256 and the calibration's RMS (px) when known.
    Raises :class:`InputError` (one line) on anything else."""
    path = Path(path)
    if not path.is_file():
        raise InputError(str(path), "not found" if not path.exists() else "not a file", "give a camera.yaml from `inspect-pipe calibrate`")
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(str(path), "not a text file", "give a camera.yaml from `inspect-pipe calibrate`") from None
    head = text.lstrip()[:64]
    if head.startswith("%YAML:") or (not head.startswith(("<?xml", "{")) and "!!opencv-matrix" in text):
        return _load_opencv_yaml(path, text)
    if head.startswith(("<?xml", "{")):
        return _load_opencv(path)  # FileStorage XML or JSON: OpenCV's reader
    return _load_ros(path, text)


def fit_camera(cam: CameraModel, width: int, height: int, *, where: str | None = None, frames: str = "the frames") -> CameraModel:
    """``cam`` for frames of ``width`` x ``height``: itself when the sizes agree; scaled (focal
    lengths and principal point; distortion is in normalised coordinates and stays) when only the
    resolution differs with the same aspect ratio, as a camera binning or resizing its sensor;
    :class:`InputError` otherwise."""
    if (cam.width, cam.height) == (width, height):
        return cam
    where = where or str((cam.calibration or {}).get("source") or "--camera")
    if cam.width * height != cam.height * width:
        raise InputError(where, f"calibrated at {cam.width}x{cam.height}, but {frames} are {width}x{height} (another aspect ratio)",
                         "calibrate the camera at the resolution it captures at")
    s = width / cam.width
    K = np.asarray(cam.K, float).copy()
    K[0, 0] *= s
    K[1, 1] *= s
    K[0, 1] *= s
    K[0, 2] = (K[0, 2] + 0.5) * s - 0.5
    K[1, 2] = (K[1, 2] + 0.5) * s - 0.5
    calib = dict(cam.calibration or {})
    calib["scaled_from_wh"] = [cam.width, cam.height]
    return replace(cam, K=K, width=int(width), height=int(height), calibration=calib)


def scaled_note(camera_json: dict | None) -> str:
    """The line saying a calibration was scaled to the frames' size (``CameraModel.to_json()``
    of the camera used), or ``""``."""
    cal = (camera_json or {}).get("calibration") or {}
    src = cal.get("scaled_from_wh")
    if not src:
        return ""
    return (f"note: {cal.get('source')} was calibrated at {src[0]}x{src[1]}; scaled to the frames' "
            f"{camera_json.get('width')}x{camera_json.get('height')} (same aspect ratio)")
