"""``inspect-pipe calibrate IMAGES... -o camera.yaml --board COLSxROWS --square-m S``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

import cv2

from cli._common import StageProgress, choices, one_line_errors
from inspect_pipe.errors import InputError
from inspect_pipe.capture._calibration import OUTLIER_RULE, Board, calibrate_images, parse_board, write_camera_yaml

HELP = f"""Calibrate a camera from views of a printed chessboard (or a ChArUco board) and write
camera.yaml, which capture, import, mosaic and run take as --camera.

Corners: OpenCV's findChessboardCorners + cornerSubPix (ChArUco: aruco.CharucoDetector);
camera: calibrateCamera, pinhole with distortion k1 k2 p1 p2 k3. A view whose board is not
found is named and dropped; so is an outlier: {OUTLIER_RULE} (--keep-outliers keeps them,
as OpenCV's sample does). A table gives every view's RMS
reprojection error, then the overall RMS.

camera.yaml is OpenCV FileStorage YAML as OpenCV's calibration sample writes it (%YAML:1.0,
camera_matrix, distortion_coefficients, image_width, image_height, avg_reprojection_error,
per_view_reprojection_errors ...). --camera also reads a ROS camera_info YAML.

--board counts a chessboard's INNER corners (a board of 10 x 7 squares is 9x6); for
--pattern charuco it counts squares, and --marker-m and --dictionary describe the markers.
The square size sets the unit of the board poses only: the intrinsics do not depend on it.

Examples:

  inspect-pipe calibrate ../shared/data/calibration/chessboard_9x6 -o camera.yaml --board 9x6 --square-m 0.025

  inspect-pipe calibrate shots/*.png -o camera.yaml --pattern charuco --board 7x5 --square-m 0.04 --marker-m 0.03

  inspect-pipe capture --source v4l2:/dev/video0 --camera camera.yaml -o out/sweep1

Exit 0 when camera.yaml is written; 2 on bad input (unreadable image, images of different
sizes, the board found in fewer than 3 images), with nothing written.
"""

Pattern = choices("Pattern", ("chessboard", "charuco"))
Dictionary = choices("Dictionary", sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_")))


def _table(cal, out: Path) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console(highlight=False, soft_wrap=True)
    con.print(f"{cal.board.describe()}: {len(cal.kept)} of {len(cal.views)} views used")
    t = Table()
    t.add_column("view")
    t.add_column("corners", justify="right")
    t.add_column("RMS error (px)", justify="right")
    t.add_column("note")
    for v in cal.views:
        err = "" if v.error_px is None else f"{v.error_px:.3f}"
        why = {"kept": "", "no board": "dropped: board not found", "outlier": "dropped: outlier"}[v.status]
        t.add_row(v.name, str(v.n_points) if v.n_points else "-", err, why)
    con.print(t)
    K = cal.camera.K
    con.print(f"RMS reprojection error {cal.rms_px:.3f} px over {sum(v.n_points for v in cal.kept)} corners; "
              + "; ".join(f"{n} {v:.2f}" + (f" +/- {sd:.2f}" if sd else "") for n, v, sd in
                          zip(("fx", "fy", "cx", "cy"), (K[0, 0], K[1, 1], K[0, 2], K[1, 2]), cal.std_px or (0.0,) * 4)) + " px; "
              f"dist {' '.join(f'{d:.5f}' for d in cal.camera.dist)}")
    con.print(f"wrote {out}")


@one_line_errors
def calibrate(
    images: Annotated[list[Path], typer.Argument(help="Calibration images, or folders of them (sorted by name).")],
    out: Annotated[Path, typer.Option("-o", "--out", help="Camera file to write (OpenCV FileStorage YAML).")],
    board: Annotated[str, typer.Option("--board", help="COLSxROWS: a chessboard's inner corners (ChArUco: squares), e.g. 9x6.")],
    square_m: Annotated[float, typer.Option("--square-m", help="Side of a board square, m.")],
    pattern: Annotated[Pattern, typer.Option("--pattern", help="Calibration target.")] = Pattern.chessboard,
    marker_m: Annotated[Optional[float], typer.Option("--marker-m", help="ChArUco: side of a marker, m.")] = None,
    dictionary: Annotated[Dictionary, typer.Option("--dictionary", help="ChArUco: OpenCV ArUco dictionary.")] = Dictionary("DICT_6X6_250"),
    name: Annotated[str, typer.Option("--name", help="Camera name written into the file.")] = "camera",
    keep_outliers: Annotated[bool, typer.Option("--keep-outliers", help="Keep outlier views (only views without the board are dropped), as OpenCV's sample does.")] = False,
) -> None:
    if out.is_dir():
        raise InputError(str(out), "is a directory", "give the camera file to write, e.g. -o camera.yaml")
    cols, rows = parse_board(board)
    b = Board(cols, rows, square_m, kind=pattern.value, marker_m=marker_m, dictionary=dictionary.value)
    kw = {"outlier_factor": float("inf"), "outlier_floor_px": float("inf")} if keep_outliers else {}
    progress = StageProgress()  # a bar on a terminal; none under -q
    try:
        cal = calibrate_images(images, b, name=name, progress=lambda k, n: progress("finding corners", k, n), **kw)
    finally:
        progress.close()
    write_camera_yaml(out, cal)
    _table(cal, out)
