"""Calibration benchmark.

    python -m bench --only calibration

* The shared real views (``calibration/chessboard_9x6``, 25 views, 640x512): ``inspect-pipe
  calibrate``'s figures (RMS, fx, fy, cx, cy) against OpenCV's own ``calibrateCamera`` on the
  same detections (goal: within 0.5 %, RMS <= 0.3 px), and against OpenCV's reference pipeline
  of the data's SOURCE.md (cornerSubPix 11x11; RMS 0.149, fx 519.4, fy 519.6, cx 315.7, cy 249.7).
* Validation on synthetic views with ground truth (a known camera, rendered chessboards): the
  cornerSubPix window (OpenCV's fixed 11 px half-window vs. the spacing-capped one we ship) and
  the outlier rule (factor x median and a floor) with 0-2 misdetected views per set.
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from inspect_pipe.capture._calibration import (
    OUTLIER_FACTOR,
    OUTLIER_FLOOR_PX,
    SUBPIX_CRITERIA,
    Board,
    calibrate,
    calibrate_images,
    detect_board,
)
from inspect_pipe.capture._geometry import CameraModel
from inspect_pipe.capture.synthetic_board import chessboard_image, random_poses, render_view

REFERENCE = {"rms": 0.149, "fx": 519.4, "fy": 519.6, "cx": 315.7, "cy": 249.7}  # SOURCE.md


def _figures(rms: float, K: np.ndarray) -> dict:
    return {"rms": float(rms), "fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2])}


def _opencv_reference(paths: list[Path]) -> dict:
    """OpenCV's pipeline as the data's SOURCE.md ran it (cornerSubPix 11x11, default flags)."""
    objp = np.zeros((54, 3), np.float32)
    objp[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2)
    O, I, size = [], [], None
    for p in paths:
        g = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        size = g.shape[::-1]
        ok, c = cv2.findChessboardCorners(g, (9, 6), None)
        if ok:
            O.append(objp)
            I.append(cv2.cornerSubPix(g, c, (11, 11), (-1, -1), SUBPIX_CRITERIA))
    rms, K, *_ = cv2.calibrateCamera(O, I, size, None, None)
    return _figures(rms, K)


def _real(data: Path) -> list[str]:
    folder = data / "calibration" / "chessboard_9x6"
    paths = sorted(folder.glob("*.jpg"))
    board = Board(9, 6, 1.0)
    t0 = time.perf_counter()
    cal = calibrate_images([folder], board)
    t_ours = time.perf_counter() - t0
    ours = _figures(cal.rms_px, cal.camera.K)
    # OpenCV's own calibrateCamera (its default criteria) on exactly our detections
    obj = [board.object_points()] * len(cal.image_points)
    rms, K, *_ = cv2.calibrateCamera(obj, [p.reshape(-1, 1, 2) for p in cal.image_points], (cal.camera.width, cal.camera.height), None, None)
    same = _figures(rms, K)
    t0 = time.perf_counter()
    ref = _opencv_reference(paths)
    t_ref = time.perf_counter() - t0
    out = [
        "### Real views: `calibration/chessboard_9x6` (25 views, 640x512)\n",
        f"`inspect-pipe calibrate` kept {len(cal.kept)} of {len(cal.views)} views "
        f"({sum(v.status == 'no board' for v in cal.views)} without the board, {sum(v.status == 'outlier' for v in cal.views)} outliers) "
        f"in {t_ours:.2f} s (OpenCV's reference pipeline: {t_ref:.2f} s).\n",
        "| | RMS (px) | fx | fy | cx | cy |",
        "|---|---|---|---|---|---|",
    ]

    def row(name, f):
        return f"| {name} | {f['rms']:.3f} | {f['fx']:.2f} | {f['fy']:.2f} | {f['cx']:.2f} | {f['cy']:.2f} |"

    def pct(name, f, g):
        return f"| {name} | | " + " | ".join(f"{100 * (f[k] - g[k]) / g[k]:+.3f} %" for k in ("fx", "fy", "cx", "cy")) + " |"

    out += [
        row("inspect-pipe calibrate", ours),
        row("OpenCV calibrateCamera on the same detections", same),
        row("OpenCV reference pipeline (cornerSubPix 11x11), re-run", ref),
        row("SOURCE.md reference figures", REFERENCE),
        pct("ours vs. OpenCV on the same detections", ours, same),
        pct("ours vs. SOURCE.md reference", ours, REFERENCE),
    ]
    worst = max(abs(ours[k] - same[k]) / same[k] for k in ("fx", "fy", "cx", "cy"))
    worst_ref = max(abs(ours[k] - REFERENCE[k]) / REFERENCE[k] for k in ("fx", "fy", "cx", "cy"))
    out.append(f"\nGoals: RMS <= 0.3 px: **{ours['rms']:.3f} px, {'met' if ours['rms'] <= 0.3 else 'NOT met'}**; "
               f"fx, fy, cx, cy within 0.5 % of OpenCV's calibrateCamera on the same detections: "
               f"**worst {100 * worst:.4f} %, {'met' if worst <= 0.005 else 'NOT met'}** "
               f"(and {100 * worst_ref:.3f} % from the SOURCE.md reference, whose corners were refined in the fixed 11 px window).\n")
    return out


# ------------------------------------------------------------------------------ synthetic validation

TRUE = CameraModel(np.array([[520.0, 0.0, 318.0], [0.0, 521.0, 252.0], [0.0, 0.0, 1.0]]),
                   np.array([-0.06, 0.11, 0.0002, 0.002, -0.05]), 640, 512, "truth")


def _views(n: int, distance_m: float, seed: int, square_m: float = 0.025, sq_px: int = 30):
    img, margin = chessboard_image(9, 6, sq_px)
    origin = (margin * sq_px + sq_px - 0.5,) * 2
    rng = np.random.default_rng(seed)
    poses = random_poses(n, (8 * square_m, 5 * square_m), TRUE, distance_m=distance_m, rng=rng)
    return [render_view(TRUE, img, square_m / sq_px, r, t, origin_px=origin, supersample=2, blur_sigma_px=0.8, rng=rng) for r, t in poses]


def _k_error(K: np.ndarray) -> float:
    """Worst relative error of fx, fy, cx, cy (%)."""
    T = TRUE.K
    return 100 * max(abs(K[0, 0] - T[0, 0]) / T[0, 0], abs(K[1, 1] - T[1, 1]) / T[1, 1], abs(K[0, 2] - T[0, 2]) / T[0, 2], abs(K[1, 2] - T[1, 2]) / T[1, 2])


def _window_study() -> list[str]:
    board = Board(9, 6, 0.025)
    rows = ["### Validation: the cornerSubPix window (synthetic, known camera)\n",
            "Twelve chessboard views per set, 640x512, blur 0.8 px, read noise 2 DN; worst error of fx, fy, cx, cy (%) and RMS (px).\n",
            "| board distance (corner spacing) | OpenCV 11 px half-window | capped at half the corner spacing (shipped) |",
            "|---|---|---|"]
    for dist in (0.45, 0.65, 0.9):
        res = {"fixed": [], "capped": []}
        for seed in (0, 1):
            views = _views(12, dist, seed)
            O, fixed, capped = [], [], []
            for v in views:
                ok, c = cv2.findChessboardCorners(v, (9, 6), flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
                if not ok:
                    continue
                O.append(board.object_points())
                fixed.append(cv2.cornerSubPix(v, c.copy(), (11, 11), (-1, -1), SUBPIX_CRITERIA))
                capped.append(detect_board(v, board)[0].reshape(-1, 1, 2))
            for key, pts in (("fixed", fixed), ("capped", capped)):
                rms, K, *_ = cv2.calibrateCamera(O, pts, (640, 512), None, None)
                res[key].append((rms, _k_error(K)))
        spacing = 520 * 0.025 / dist
        cell = {k: f"{max(e for _, e in v):.3f} % (RMS {max(r for r, _ in v):.3f})" for k, v in res.items()}
        rows.append(f"| {dist:.2f} m (~{spacing:.0f} px) | {cell['fixed']} | {cell['capped']} |")
    return rows + [""]


RULES = [(f, fl) for fl in (0.1, 0.15, 0.25, 0.5) for f in (1.5, 2.0, 3.0)] + [(None, None)]


def _outlier_study() -> list[str]:
    """Candidate rules (factor x median, floor px) on synthetic sets: clean corners (view RMS
    ~0.03 px) or with 0.6-1.4 x 0.15 px of added corner noise per view (view RMS ~0.15 px, like
    the shared real views), 0-2 views per set misdetected (half their corners shifted 0.3-3 px)."""
    board = Board(9, 6, 0.025)
    stats = {r: {"err": [], "false": 0, "missed": 0} for r in RULES}
    n_sets = n_bad_total = 0
    for seed in range(4):
        views = _views(15, 0.55, 100 + seed)
        det0 = [(f"v{k}", detect_board(v, board)) for k, v in enumerate(views)]
        for noise in (0.0, 0.15):
            for n_bad in (0, 1, 2):
                rng = np.random.default_rng(1000 * seed + 10 * n_bad + int(noise * 100))
                # views differ in quality as real ones do (their errors spread 0.09-0.22 px on the shared set)
                d = [(n, (p + rng.normal(0, noise * rng.uniform(0.6, 1.4), p.shape).astype(np.float32), o)) for n, (p, o) in det0]
                bad_idx = [int(i) for i in rng.choice(len(d), n_bad, replace=False)] if n_bad else []
                for i in bad_idx:  # a misdetection: one end of the board shifted
                    pts, obj = d[i][1]
                    pts = pts.copy()
                    shift = rng.uniform(0.3, 3.0) * np.array([np.cos(a := rng.uniform(0, 2 * np.pi)), np.sin(a)])
                    pts[: len(pts) // 2] += shift.astype(np.float32)
                    d[i] = (d[i][0], (pts, obj))
                n_sets += 1
                n_bad_total += n_bad
                for r in RULES:
                    f, fl = r
                    cal = calibrate(d, (640, 512), board, outlier_factor=f or 1e9, outlier_floor_px=fl or 1e9)
                    dropped = {int(v.name[1:]) for v in cal.views if v.status == "outlier"}
                    stats[r]["err"].append(_k_error(cal.camera.K))
                    stats[r]["false"] += len(dropped - set(bad_idx))
                    stats[r]["missed"] += len(set(bad_idx) - dropped)
    rows = ["### Validation: the outlier rule (synthetic, known camera)\n",
            f"{n_sets} sets of 15 views (4 seeds; corners as detected, or with 0.6-1.4 x 0.15 px of added noise per view; 0, 1 or 2 views "
            f"misdetected: half their corners shifted 0.3-3 px, {n_bad_total} in all). Rule: a view is dropped when its RMS "
            "error exceeds factor x the median view's and the floor. "
            f"Shipped: {OUTLIER_FACTOR:g} x median and {OUTLIER_FLOOR_PX:g} px.\n",
            "| factor | floor (px) | mean / worst error of fx, fy, cx, cy (%) | good views dropped | misdetected views kept |",
            "|---|---|---|---|---|"]
    for r in RULES:
        e = stats[r]["err"]
        f, fl = r
        rows.append(f"| {'no rejection' if f is None else f'{f:g}'} | {'' if fl is None else f'{fl:g}'} | "
                    f"{np.mean(e):.3f} / {np.max(e):.3f} | {stats[r]['false']} | {stats[r]['missed']} |")
    return rows + [""]


def run(data: Path) -> str:
    parts = ["## Calibration (`inspect-pipe calibrate`)\n"]
    parts += _real(data)
    parts += _window_study()
    parts += _outlier_study()
    return "\n".join(parts)


if __name__ == "__main__":  # pragma: no cover
    import sys

    print(run(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[2] / "shared" / "data"))
