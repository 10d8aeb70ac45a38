"""Report and pipeline benchmark.

    python -m bench --only report

On simulated sweeps over the demo wall (known defects, ground-truth masks):
* geolocation: the true defect masks carried into the mosaic through each frame's exact
  texture-to-frame homography and the mosaic's H, then located by the report (wall map fitted to
  odometry) -> centroid error (goal <= 5 cm), area error (goal <= 15 %);
* the detector's register against the truth (recall, false alarms, centroid and area errors);
* coverage: imaged fraction of the wall from the mosaic vs from the true camera poses (goal <= 2 %);
* time of a 200-frame sweep from raw frames to report.pdf (goal <= 60 s on 2 cores);
* 8 small sweeps on a local Dask cluster of 2 workers vs 1 worker (goal >= 1.7x), and one process
  using every core without Dask for reference.
"""

from __future__ import annotations

import io
import json
import shutil
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import yaml

ROOT = Path(__file__).resolve().parent.parent


def _scenario(wall, path: Path, *, duration: float, operator: list, camera=None, seed: int = 11) -> Path:
    from inspect_pipe.pipeline._demo import demo_scenario

    demo_scenario(wall, path)
    doc = yaml.safe_load(path.read_text())
    doc.update(duration_s=duration, operator=operator, seed=seed)
    if camera:
        doc["camera"] = camera
    path.write_text(yaml.safe_dump(doc))
    return path


OP_200 = [{"t": 0.5, "button": "takeoff"}, {"t": 3.0, "button": "inspection_mode_on"},
          {"t": 3.5, "stick": {"vx": 0, "vy": -0.3, "vz": 0, "yaw_rate": 0}},
          {"t": 11.0, "stick": {"vx": 0, "vy": 0, "vz": 0.3, "yaw_rate": 0}},
          {"t": 14.5, "stick": {"vx": 0, "vy": 0.3, "vz": 0, "yaw_rate": 0}},
          {"t": 19.8, "stick": {"vx": 0, "vy": 0, "vz": 0, "yaw_rate": 0}}]
OP_SMALL = [{"t": 0.5, "button": "takeoff"}, {"t": 3.0, "button": "inspection_mode_on"},
            {"t": 3.5, "stick": {"vx": 0, "vy": -0.3, "vz": 0, "yaw_rate": 0}},
            {"t": 7.5, "stick": {"vx": 0, "vy": 0, "vz": 0, "yaw_rate": 0}}]


def true_wall_from_mosaic(run: Path) -> np.ndarray:
    """The mosaic -> wall map the simulator's truth gives (an affine map, least squares over the
    corners and centre of every placed frame: each frame's H and its true wall -> frame homography)."""
    from inspect_pipe.pipeline import RunStore

    sweep = RunStore(run).load_sweep()
    mdoc = json.loads((run / "mosaic" / "mosaic.json").read_text())
    w, h = sweep.meta.width, sweep.meta.height
    P, Q = [], []
    for f in mdoc["frames"]:
        tr = sweep.frames[int(f["index"])].truth
        if f.get("group", 0) != 0 or tr is None:
            continue
        for pt in ([0, 0, 1], [w, 0, 1], [0, h, 1], [w, h, 1], [w / 2, h / 2, 1]):
            a = np.asarray(f["H"], float) @ pt
            q = np.linalg.solve(tr.H_wall_m_to_frame, np.asarray(pt, float))
            P.append(a[:2] / a[2])
            Q.append(q[:2] / q[2])
    X, *_ = np.linalg.lstsq(np.c_[np.array(P), np.ones(len(P))], np.array(Q), rcond=None)
    return np.r_[X.T, [[0.0, 0.0, 1.0]]]


def pipeline_vs_detector(wall, run: Path, defects, engine: str = "onnx", wall_from_mosaic: np.ndarray | None = None) -> dict:
    """Does the pipeline keep the detector's quality? On the wall texture's pixels that the mosaic
    imaged: corrosion IoU of the register (entries not rejected, their wall polygons) against the
    true corrosion, beside the IoU of the same engine run on the wall texture itself at the
    mosaic's resolution; and the share of corrosion entries that touch true corrosion.
    ``wall_from_mosaic`` (e.g. ``true_wall_from_mosaic``) places the mosaic and the entries' mosaic
    polygons instead of the run's wall map: the figure without the georeferencing's error."""
    from inspect_pipe.capture._geometry import texture_px_to_wall
    from inspect_pipe.saliency_defects import load_engine

    img = cv2.imread(str(wall.image), cv2.IMREAD_COLOR)
    labels = cv2.imread(str(wall.labels), cv2.IMREAD_UNCHANGED)
    truth = np.isin(labels, [int(t.id[1:]) for t in wall.truth if t.cls == "corrosion"])
    mdoc = json.loads((run / "mosaic" / "mosaic.json").read_text())
    T = texture_px_to_wall(wall.m_per_px, wall.origin_uv)  # texture px -> wall m
    Wm = np.array(mdoc["wall_from_mosaic"], float) if wall_from_mosaic is None else np.asarray(wall_from_mosaic, float)
    M = np.linalg.inv(Wm) @ T  # texture px -> mosaic px
    alpha = cv2.imread(str(run / "mosaic" / "mosaic.png"), cv2.IMREAD_UNCHANGED)[:, :, 3]
    h, w = truth.shape
    imaged = cv2.warpPerspective(alpha, M, (w, h), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP) > 0
    Tinv = np.linalg.inv(T)
    pipe = np.zeros((h, w), np.uint8)
    entries = [d for d in defects if d.cls == "corrosion" and d.status != "rejected"]
    touching = 0
    for d in entries:
        if wall_from_mosaic is None:
            q = np.c_[np.asarray(d.polygon_wall_m, float), np.ones(len(d.polygon_wall_m))] @ Tinv.T
        else:
            q = np.c_[np.asarray(d.polygon_mosaic_px, float), np.ones(len(d.polygon_mosaic_px))] @ (Tinv @ Wm).T
        poly = np.round(q[:, :2] / q[:, 2:3]).astype(np.int32)
        one = np.zeros((h, w), np.uint8)
        cv2.fillPoly(one, [poly], 1)
        touching += bool((one.astype(bool) & truth).any())
        pipe |= one
    eng = load_engine(engine)
    s = wall.m_per_px / float(mdoc["m_per_px"])  # texture px -> mosaic px
    small = cv2.resize(img, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    det = eng.detect(small, kinds=("corrosion",))
    own = cv2.resize(eng.decide(det.class_probs["corrosion"], "corrosion").astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0

    def iou(m):
        m, t = m & imaged, truth & imaged
        return float((m & t).sum() / max(1, (m | t).sum()))

    ip, io_ = iou(pipe > 0), iou(own)
    return {"pipeline_iou": ip, "detector_iou": io_, "kept": ip / io_ if io_ > 0 else float("nan"),
            "entries": len(entries), "touching": touching}


def _truth_run(run: Path, wall, sweep) -> Path:
    """A copy of ``run`` whose detections are the true masks carried into the mosaic."""
    from inspect_pipe.pipeline import RunStore
    from inspect_pipe.pipeline._store import write_json

    src = RunStore(run)
    dst = RunStore(run.parent / (run.name + "_truth"))
    if dst.root.exists():
        shutil.rmtree(dst.root)
    dst.root.mkdir()
    shutil.copytree(src.mosaic_dir, dst.mosaic_dir)
    shutil.copy(src.run_json, dst.run_json)
    doc = src.load_mosaic_json()
    mosaic = src.load_mosaic_image()
    labels = cv2.imread(str(wall.labels), cv2.IMREAD_UNCHANGED)
    H = {f["index"]: np.asarray(f["H"], float) for f in doc["frames"] if f.get("group", 0) == 0}
    centres = {i: (h @ np.array([sweep.meta.width / 2, sweep.meta.height / 2, 1]))[:2] / (h @ np.array([sweep.meta.width / 2, sweep.meta.height / 2, 1]))[2] for i, h in H.items()}
    masks = {c: np.zeros(mosaic.shape[:2], np.uint8) for c in ("corrosion", "crack")}
    for k, t in enumerate(wall.truth, start=1):
        ys, xs = np.nonzero(labels == k)
        # texture px of the instance centre -> the frame whose centre is nearest in the mosaic
        best, T = None, None
        for i, h in H.items():
            tr = sweep.frames[i].truth
            if tr is None or tr.H_wall_px_to_frame is None:
                continue
            M = h @ tr.H_wall_px_to_frame
            p = M @ np.array([xs.mean(), ys.mean(), 1.0])
            d = np.linalg.norm(p[:2] / p[2] - centres[i])
            if best is None or d < best:
                best, T = d, M
        if T is None:
            continue
        inst = (labels == k).astype(np.uint8) * 255
        warped = cv2.warpPerspective(inst, T, (mosaic.shape[1], mosaic.shape[0]), flags=cv2.INTER_LINEAR)
        masks[t.cls] |= (warped >= 128).astype(np.uint8) * 255
    for c, m in masks.items():
        dst.save_class_map("mosaic", c, "mask", m)
        dst.save_class_map("mosaic", c, "prob", m)
    write_json(dst.detect_dir / "defects.json", {"format": "inspect_pipe.defects/1", "model": {"version": "truth"},
                                                "kinds": list(masks), "images": [], "regions": [], "errors": [], "keyframes": []})
    return dst.root


def _true_imaged_fraction(sweep, grid, placed: set[int]) -> float:
    img = np.zeros(grid.shape, np.uint8)
    G = grid.grid_from_wall()
    w, h = sweep.meta.width, sweep.meta.height
    for i, f in enumerate(sweep.frames):
        if i not in placed or f.truth is None:
            continue
        Hinv = np.linalg.inv(f.truth.H_wall_m_to_frame)
        c = np.array([[0, 0, 1], [w, 0, 1], [w, h, 1], [0, h, 1]], float) @ Hinv.T
        q = (c / c[:, 2:3]) @ G.T
        cv2.fillConvexPoly(img, np.round(q[:, :2] / q[:, 2:3] * 4).astype(np.int32), 1, shift=2)
    return float(img.mean())


def imaged_truth(wall, sweep, placed: set[int]) -> list:
    """Each true defect cut to the surveyed part of the wall: what the placed frames saw (their true
    poses) less the register's edge band: area and centroid of that part, on the wall's texture
    raster. Defects not surveyed are left out. The register measures an entry cut by the edge on its
    surveyed part (``beyond_survey``), so this is the reference of the geolocation rows."""
    from dataclasses import replace

    from inspect_pipe.report import RegisterParams

    labels = cv2.imread(str(wall.labels), cv2.IMREAD_UNCHANGED)
    seen = np.zeros(labels.shape, np.uint8)
    w, h = sweep.meta.width, sweep.meta.height
    rect = np.array([[0, 0, 1], [w, 0, 1], [w, h, 1], [0, h, 1]], float)
    for i, f in enumerate(sweep.frames):
        if i not in placed or f.truth is None or f.truth.H_wall_px_to_frame is None:
            continue
        c = rect @ np.linalg.inv(f.truth.H_wall_px_to_frame).T
        cv2.fillConvexPoly(seen, np.round(c[:, :2] / c[:, 2:3] * 4).astype(np.int32), 1, shift=2)
    # the register's surveyed region: the imaged wall less its edge band (RegisterParams.edge_margin_m)
    e = max(1, int(round(RegisterParams().edge_margin_m / wall.m_per_px)))
    seen = cv2.erode(seen, np.ones((2 * e + 1, 2 * e + 1), np.uint8), borderValue=0)
    out = []
    for t in wall.truth:
        ys, xs = np.nonzero((labels == int(t.id.lstrip("T"))) & (seen > 0))
        if len(xs) == 0:
            continue
        u = wall.origin_uv[0] + (xs.mean() + 0.5) * wall.m_per_px
        v = wall.origin_uv[1] - (ys.mean() + 0.5) * wall.m_per_px
        out.append(replace(t, centroid_wall_m=(float(u), float(v)), area_m2=float(len(xs) * wall.m_per_px ** 2)))
    return out


def run(data: Path) -> str:
    from inspect_pipe.pipeline import run_many, run_pipeline
    from inspect_pipe.pipeline._demo import DEMO_SURVEY, build_demo_wall, compare_with_truth
    from inspect_pipe.pipeline._steps import DetectConfig, RunConfig
    from inspect_pipe.pipeline import RunStore
    from inspect_pipe.report import ReportParams, read_register, report_from_run

    out = io.StringIO()
    w = out.write
    tmp = Path(tempfile.mkdtemp(prefix="bench_report_"))
    try:
        wall = build_demo_wall(tmp / "wall", data if (data / "defects").is_dir() else None)
        sc = _scenario(wall, tmp / "s200.yaml", duration=20.0, operator=OP_200)
        # a 200-frame sweep, captured first (not timed), then raw frames -> PDF timed
        cfg = RunConfig(input=f"fly:{sc}", survey=DEMO_SURVEY, detect=DetectConfig(keyframe_spacing=0.5))
        run_dir = tmp / "run200"
        from inspect_pipe.pipeline._steps import STEPS

        RunStore(run_dir).root.mkdir()
        STEPS[0].run(RunStore(run_dir), cfg, None)
        sweep = RunStore(run_dir).load_sweep()
        cfg2 = RunConfig(input=str(run_dir / "sweep"), survey=DEMO_SURVEY, detect=DetectConfig(keyframe_spacing=0.5))
        t0 = time.monotonic()
        o = run_pipeline(tmp / "run200b", cfg2, log=lambda s: None)
        t_pdf = time.monotonic() - t0
        steps_t = {s.name: s.seconds for s in o.steps if s.action == "ran"}
        run2 = tmp / "run200b"
        reg = read_register(run2 / "report" / "defects.json")
        det = compare_with_truth(reg, wall.truth, wall=wall)
        engine = json.loads((run2 / "detect" / "defects.json").read_text())["model"]["engine"]
        tr_dir = _truth_run(run2, wall, sweep)
        rep_t = report_from_run(RunStore(tr_dir), tr_dir / "report", ReportParams(pdf=False))
        geo_whole = compare_with_truth(rep_t.defects, wall.truth, wall=wall)
        mdoc = json.loads((run2 / "mosaic" / "mosaic.json").read_text())
        rep = report_from_run(RunStore(run2), tmp / "rep_cov", ReportParams(pdf=False))
        placed = {v.index for v in rep.views}
        est = float(rep.coverage.imaged.mean())
        true = _true_imaged_fraction(sweep, rep.coverage.grid, placed)
        seen_truth = imaged_truth(wall, sweep, placed)
        geo = compare_with_truth(rep_t.defects, seen_truth, wall=wall)

        w("## Defect report and pipeline\n\n")
        w(f"Simulated inspection sweep over the demo wall ({wall.source}; {len(wall.truth)} known defects: "
          f"{sum(t.cls == 'corrosion' for t in wall.truth)} corrosion, {sum(t.cls == 'crack' for t in wall.truth)} cracks), "
          f"{len(sweep.frames)} frames at 10 Hz, 752x480; mosaic-to-odometry fit residual "
          f"{mdoc.get('wall_fit', {}).get('rms_m', float('nan')):.3f} m RMS.\n\n")
        w("| measure | value | goal |\n|---|---:|---|\n")

        def errs(c):
            rows = [r for r in c["rows"] if r["found"]]
            ce = [r["centroid_error_m"] for r in rows]
            ae = [abs(r["area_error"]) for r in rows if r["class"] == "corrosion"]
            return rows, ce, ae

        rows, ce, ae = errs(geo)
        w(f"| geolocation: true masks found / imaged (of {len(wall.truth)} known) | {geo['matched']}/{geo['truth']} | all |\n")
        if ce:
            w(f"| geolocation: centroid error median / max (imaged part of each true mask) | {100 * np.median(ce):.1f} / {100 * max(ce):.1f} cm | <= 5 cm |\n")
        if ae:
            w(f"| geolocation: corrosion area error median / max (imaged part) | {100 * np.median(ae):.1f} / {100 * max(ae):.1f} % | <= 15 % |\n")
        _, ce_w, ae_w = errs(geo_whole)
        if ce_w and ae_w:
            w(f"| the same against each whole true mask (a defect only partly in view counts as mislocated) | "
              f"{100 * np.median(ce_w):.1f} / {100 * max(ce_w):.1f} cm; {100 * np.median(ae_w):.1f} / {100 * max(ae_w):.1f} % | |\n")
        w(f"| coverage: imaged fraction, mosaic vs true poses | {100 * est:.1f} % vs {100 * true:.1f} % (error {100 * abs(est - true):.2f} % of the wall) | <= 2 % |\n")
        rows, ce, ae = errs(det)
        w(f"| detector register ({engine} engine): known defects found | {det['matched']}/{det['truth']} ({det['false_alarms']} other entries) | |\n")
        if ce:
            w(f"| detector register: centroid error median | {100 * np.median(ce):.1f} cm | |\n")
        if ae:
            w(f"| detector register: corrosion area error median | {100 * np.median(ae):.0f} % | |\n")
        keep = pipeline_vs_detector(wall, run2, reg, engine)
        w(f"| pipeline keeps the detector: corrosion IoU of the register / of the {engine} engine on the wall texture (imaged part) | "
          f"{keep['pipeline_iou']:.3f} / {keep['detector_iou']:.3f} = **{100 * keep['kept']:.0f} %** | >= 90 % |\n")
        bound = pipeline_vs_detector(wall, run2, reg, engine, wall_from_mosaic=true_wall_from_mosaic(run2))
        w(f"| the same with the mosaic placed on the wall by the simulator's true map (what the wall map costs) | "
          f"{bound['pipeline_iou']:.3f} / {bound['detector_iou']:.3f} = {100 * bound['kept']:.0f} % | |\n")
        w(f"| corrosion entries touching true corrosion | {keep['touching']}/{keep['entries']} | >= 75 % |\n")
        w(f"| 200-frame sweep, raw frames -> report.pdf | {t_pdf:.1f} s ({', '.join(f'{k} {v:.1f} s' for k, v in steps_t.items())}) | <= 60 s |\n")

        # Dask: 8 small sweeps (40 frames, 376x240): a local cluster of 1 worker vs 2, and one process on every core
        jobs = []
        for k in range(8):
            s = _scenario(wall, tmp / f"small{k}.yaml", duration=8.0, operator=OP_SMALL,
                          camera={"fps": 5, "width": 376, "height": 240, "hfov_deg": 60}, seed=100 + k)
            d = tmp / f"small{k}"
            RunStore(d).root.mkdir()
            c = RunConfig(input=f"fly:{s}", survey=DEMO_SURVEY, detect=DetectConfig(keyframe_spacing=0.0), report={"pdf": False})
            STEPS[0].run(RunStore(d), c, None)
            jobs.append(d / "sweep")
        timings = {}

        def many(label: str, **kw) -> None:
            js = [(tmp / f"par_{label}_{k}", RunConfig(input=str(p), detect=DetectConfig(keyframe_spacing=0.0), report={"pdf": False}))
                  for k, p in enumerate(jobs)]
            t0 = time.monotonic()
            outs = run_many(js, **kw)
            timings[label] = time.monotonic() - t0
            errors = [o.error for o in outs if o.error]
            if errors:
                w(f"| {label}: errors | {errors[0]} | |\n")

        many("no Dask, one process on every core", workers=1)
        from dask.distributed import LocalCluster

        with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as one:
            many("Dask, 1 worker", scheduler=one.scheduler_address)
        many("Dask, 2 workers", workers=2)
        d1, d2, nd = timings["Dask, 1 worker"], timings["Dask, 2 workers"], timings["no Dask, one process on every core"]
        w(f"| 8 sweeps (40 frames each): Dask 1 worker / 2 workers (local cluster, one thread each) | {d1:.1f} s / {d2:.1f} s = **{d1 / d2:.2f}x** | >= 1.7x |\n")
        w(f"| same 8 sweeps, one process using every core (no Dask) | {nd:.1f} s (Dask 2 workers take {d2 / nd:.2f}x its time) | |\n")
        w("\nGeolocation isolates the mosaic and wall map: the true masks are carried into the mosaic through "
          "each frame's exact homography and located by the report like detections. The detector rows include "
          f"the detector's own errors (detect step: the {engine} engine, the default of `run`"
          + ("; it over-grows rust borders, and its cracks were learned on asphalt" if engine == "saliency" else "")
          + "). This machine's "
          "2 cores are shared with other benchmarks, so timings and the Dask speed-up are upper and lower bounds. "
          "A register entry counts for a known defect when its centroid lies within 15 cm of that defect's true "
          "mask (the entries of one defect are its pieces: their areas add up; `compare_with_truth`). The "
          "geolocation rows compare with the surveyed part of each true mask (seen by the placed frames at their true "
          "poses, less the register's 2 cm edge band; `imaged_truth`): an entry the edge cuts is measured on its "
          "surveyed part and marked as going on beyond the survey; "
          "the row after them gives the whole outlines. The detector rows use the whole outlines.\n")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out.getvalue()
