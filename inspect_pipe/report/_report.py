"""From a run directory's mosaic and detections to the surveyor's report files."""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

import inspect_pipe
from inspect_pipe._images import imread
from inspect_pipe.errors import InputError
from inspect_pipe.ship import locate

from ._coverage import Coverage, CoverageParams, WallGrid, compute_coverage, sharpness
from ._geo import Survey, WallMap, parse_survey
from ._rating import SCHEMES, RatingParams, WallRating, rate_wall
from ._screen import Precision, screen_defects
from ._register import (
    Defect, FrameView, KeyframeDetection, RegisterParams, assign_ids, build_defects, merged_masks, read_register,
    register_csv, register_json,
)

REPORT_FORMAT = "inspect_pipe.report/1"


@dataclass(frozen=True)
class ReportParams:
    register: RegisterParams = field(default_factory=RegisterParams)
    coverage: CoverageParams = field(default_factory=CoverageParams)
    rating: RatingParams = field(default_factory=RatingParams)
    m_per_px: float | None = None  # for a mosaic without wall_from_mosaic (plain folder input)
    region_wall_m: tuple[float, float, float, float] | None = None  # u0, v0, u1, v1; default: survey / texture / footprints
    pdf: bool = True
    survey_plan: object | None = None  # inspect_pipe.ship.SurveyPlan (--survey); default: the one stored in the sweep


@dataclass
class ReportInputs:
    mosaic_doc: dict
    mosaic_where: str
    mosaic: np.ndarray  # BGRA
    detections: dict
    class_masks: dict[str, np.ndarray]  # mosaic-sized bool
    class_probs: dict[str, np.ndarray]  # mosaic-sized uint8
    keyframes: list[KeyframeDetection]
    sweep: object | None = None  # inspect_pipe.capture.Sweep
    previous: list[Defect] = field(default_factory=list)
    checksums: dict[str, str] = field(default_factory=dict)
    severity: np.ndarray | None = None  # mosaic-sized condition state of corrosion (0 none, 1 fair, 2 poor, 3 severe)


@dataclass
class Report:
    defects: list[Defect]
    wall: WallMap
    survey: Survey
    coverage: Coverage
    rating: WallRating
    views: list[FrameView]
    inputs: ReportInputs
    params: ReportParams
    trace: dict
    unplaced: list[dict]
    suppressed: list = field(default_factory=list)  # _screen.Suppressed: candidates left out, with the rule
    precision: object = None  # _screen.Precision
    crop_info: dict = field(default_factory=dict)  # defect id -> {frame, sharpness, of}: where its crop was cut (render_all)
    separate: list[dict] = field(default_factory=list)  # separate_mosaics(): placed frames this report does not inspect


def separate_mosaics(mosaic_doc: dict) -> list[dict]:
    """The mosaics besides the main one (``mosaic_group<k>.png``): frames that registered to each other but
    that no image pair ties to the main mosaic. The report inspects and places only the main one (its wall
    map is the main group's), so these are listed, never left out in silence: [{group, image, n_frames,
    frames}]."""
    by_group: dict[int, list[int]] = {}
    images: dict[int, str] = {}
    for f in mosaic_doc.get("frames") or []:
        if isinstance(f, dict) and isinstance(f.get("group"), int) and f["group"] != 0 and isinstance(f.get("index"), int):
            by_group.setdefault(f["group"], []).append(f["index"])
            images[f["group"]] = str(f.get("image") or f"mosaic_group{f['group']}.png")
    return [{"group": g, "image": images[g], "n_frames": len(fr), "frames": sorted(fr)} for g, fr in sorted(by_group.items())]


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def frame_views(mosaic_doc: dict, where: str, sweep=None) -> list[FrameView]:
    """Placed frames of the main mosaic image (group 0)."""
    size = None
    if sweep is not None:
        size = (int(sweep.meta.width), int(sweep.meta.height))
    size = tuple(mosaic_doc.get("frame_size_wh") or size or (0, 0))
    views = []
    for i, f in enumerate(mosaic_doc["frames"]):
        if not isinstance(f, dict):
            raise InputError(where, f"frames[{i}]: not an object")
        if f.get("group", 0) != 0:
            continue
        try:
            H = np.asarray(f["H"], float)
            idx = int(f["index"])
        except (KeyError, TypeError, ValueError):
            raise InputError(where, f"frames[{i}]: field 'H' or 'index' missing or malformed") from None
        if H.shape != (3, 3) or not np.all(np.isfinite(H)):
            raise InputError(where, f"frames[{i}]: field 'H' is not a 3x3 matrix of numbers")
        fs = tuple(f.get("size_wh") or size)
        views.append(FrameView(idx, H, (int(fs[0]), int(fs[1]))))
    return views


def _region(params: ReportParams, survey_raw: dict, sweep, views, wall: WallMap, mosaic_alpha) -> tuple[float, float, float, float]:
    if params.region_wall_m is not None:
        return params.region_wall_m
    r = (survey_raw or {}).get("region_wall_m")
    if isinstance(r, list) and len(r) == 4 and all(isinstance(x, (int, float)) for x in r):
        return tuple(float(x) for x in r)  # type: ignore[return-value]
    tex = getattr(getattr(sweep, "meta", None), "wall_texture", None)
    if tex is not None:  # simulated wall: the textured part is the wall under survey
        img = imread(str(tex.image), cv2.IMREAD_UNCHANGED)
        if img is not None:
            u0, v1 = tex.origin_uv
            return (u0, v1 - img.shape[0] * tex.m_per_px, u0 + img.shape[1] * tex.m_per_px, v1)
    ys, xs = np.nonzero(mosaic_alpha)
    if len(xs) == 0:
        raise InputError("mosaic.png", "no covered pixel")
    pts = wall.to_wall(np.array([[xs.min(), ys.min()], [xs.max(), ys.min()], [xs.max(), ys.max()], [xs.min(), ys.max()]], float))
    return (float(pts[:, 0].min()), float(pts[:, 1].min()), float(pts[:, 0].max()), float(pts[:, 1].max()))


def _frame_sharpness(path: Path) -> float | None:
    g = imread(str(path), cv2.IMREAD_REDUCED_GRAYSCALE_2)
    return None if g is None else sharpness(cv2.resize(g, (g.shape[1] * 2, g.shape[0] * 2)))


def build_report(inp: ReportInputs, params: ReportParams = ReportParams()) -> Report:
    """Everything the report shows, computed in memory (no file written)."""
    doc, where = inp.mosaic_doc, inp.mosaic_where
    sweep = inp.sweep
    survey_raw = dict(getattr(getattr(sweep, "meta", None), "survey", None) or {})
    survey_where = str(Path(sweep.path) / "sweep.json") if sweep is not None else where
    survey = parse_survey(survey_raw, survey_where)
    wall = WallMap.from_mosaic_json(doc, where, m_per_px_override=params.m_per_px, mosaic_hw=inp.mosaic.shape[:2])
    views = frame_views(doc, where, sweep)
    if views and views[0].size_wh == (0, 0):
        raise InputError(where, "frame size unknown", "mosaic.json of a sweep, or frames with 'size_wh'")
    valid = inp.mosaic[:, :, 3] > 0
    masks, warped = merged_masks(inp.class_masks, inp.keyframes, params=params.register)
    candidates = build_defects(masks, inp.class_probs, wall, views, survey, keyframe_masks=warped, valid=valid, params=params.register)
    region = _region(params, survey_raw, sweep, views, wall, valid)
    new, suppressed = screen_defects(candidates, masks, inp.class_probs, wall.m_per_px, region, survey.tank_top_v_m, valid, params=params.register)
    defects = assign_ids(new, inp.previous, params=params.register)
    plan, wall_frame = survey_plan_of(sweep, params.survey_plan)
    if plan is not None:
        defects = [replace(d, location=locate(plan, wall_frame, d.centroid_wall_m).to_json()) for d in defects]
    if inp.severity is not None:
        defects = [replace(d, severity=entry_severity(d, inp.severity)) if d.cls == "corrosion" else d for d in defects]
    precision = Precision.of(wall.m_per_px, wall.fit_rms_m)

    # sharpness of every placed frame, for coverage (decoding the frames is most of the step's
    # time: on every core, OpenCV releases the GIL)
    sharp: dict[int, float] = {}
    if sweep is not None:
        for v in views:  # mosaic.json indices are positions in the sweep's frame list
            if not 0 <= v.index < len(sweep.frames):
                raise InputError(where, f"frame index {v.index} is not in the sweep ({len(sweep.frames)} frames)")
        with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
            found = pool.map(_frame_sharpness, [sweep.frames[v.index].image_path for v in views])
            sharp = {v.index: s for v, s in zip(views, found) if s is not None}
    grid = WallGrid.around(*region, params.coverage.cell_m)
    coverage = compute_coverage(views, wall, grid, sharp, params=params.coverage)

    # rating rasters: corrosion of every entry not rejected, warped onto the wall grid
    keep = np.zeros(valid.shape, np.uint8)
    for d in defects:
        if d.cls == "corrosion" and d.status != "rejected" and d.redetected:
            cv2.fillPoly(keep, [np.asarray(d.polygon_mosaic_px, np.int32)], 1)
    corr = masks.get("corrosion", np.zeros(valid.shape, bool)) & (keep > 0)
    prob = inp.class_probs.get("corrosion", np.zeros(valid.shape, np.uint8))
    sev_g = None
    if inp.severity is not None:  # hard rust scale = condition state poor or severe
        hard = corr & (inp.severity >= 2)
        sev_g = grid.from_mosaic(np.where(corr, inp.severity, 0).astype(np.uint8), wall)
        cs = (inp.detections.get("model") or {}).get("condition_states")
        hard_rule = "corrosion in condition state poor or severe (the condition-state head of " + (
            f"{Path(str(cs.get('file', ''))).name} v{cs.get('version')})" if isinstance(cs, dict) else "the deciding network)")
    else:
        hard = corr & (prob >= int(round(params.rating.hard_rust_prob * 255)))
        hard_rule = f"corrosion at least {params.rating.hard_rust_prob:g} probable (the engine has no condition states)"
    hard_rule += f"; under {params.rating.hard_rust_none_below_pct:g} % of an area (shown as 0.0) counts as none"
    corr_g = grid.from_mosaic(corr.astype(np.uint8), wall) > 0
    hard_g = grid.from_mosaic(hard.astype(np.uint8), wall) > 0
    rating = rate_wall(coverage.usable, corr_g, hard_g, origin_uv_m=(grid.u0_m, grid.v_top_m), cell_m=grid.cell_m, params=params.rating,
                       severity=sev_g, u_edges_m=plate_field_edges(plan, wall_frame, grid.u0_m, grid.u0_m + grid.shape[1] * grid.cell_m))

    model = inp.detections.get("model") or {}
    separate = separate_mosaics(doc)
    trace = {
        "software": f"inspect_pipe {inspect_pipe.__version__}",
        # detections written before the engines had names came from the saliency engine
        "detector_engine": (model.get("engine") or "saliency") if model else None,
        "detector_engines": model.get("engines"),  # fused: the versions of the two engines it mixes
        "model_version": model.get("version"), "model_file": Path(str(model.get("file", ""))).name or None,
        # the network whose head gave the condition states, when it is not the deciding one
        "condition_states_model": (f"{Path(str(model['condition_states'].get('file', ''))).name} v{model['condition_states'].get('version')}"
                                   if isinstance(model.get("condition_states"), dict) else None),
        "operating_points": model.get("operating_points"), "min_area_px": model.get("min_area_px"),
        "kinds": inp.detections.get("kinds"),
        "sweep_id": None if sweep is None else f"{Path(sweep.path).name} ({sweep.meta.created_utc or 'no date'})",
        "sweep_path": None if sweep is None else str(sweep.path),
        "sweep_complete": None if sweep is None else bool(sweep.complete),
        "wall_map": wall.source, "wall_fit_rms_m": wall.fit_rms_m, "wall_fit_max_m": wall.fit_max_m,
        "m_per_px": wall.m_per_px,
        "checksums_sha256": inp.checksums,
        "survey_plan": None if plan is None else plan.to_json(),
        "limitations": _limitations(sweep, plan, ((doc.get("input") or {}).get("camera") or {}).get("calibration"))
        + [f"separate mosaic: {g['n_frames']} placed frames ({g['frames'][0]}-{g['frames'][-1]}) form {g['image']}, which no image "
           "pair ties to the main mosaic: not inspected in this report and no wall position (Coverage); fly across the gap "
           "again, or inspect it with inspect-pipe detect" for g in separate],
        "area_imaging": area_imaging(rating.areas, views, wall, sweep),
        "hard_rust_rule": hard_rule,
        "scheme_thresholds": {k: v for k, v in asdict(SCHEMES[params.rating.scheme]).items() if isinstance(v, float)},
        "areas_rule": ("plate fields between " + ("ship frames" if rating.areas and rating.areas[0].label.startswith("Fr.") else "stiffeners")
                       + f", in {params.rating.area_size_m:g} m bands up from the tank top (survey plan)")
        if any(a.label for a in rating.areas) else f"{params.rating.area_size_m:g} m squares (no frames or stiffeners in a survey plan)",
        "precision": precision.to_json(),
        "separate_mosaics": [{k: v for k, v in g.items() if k != "frames"} for g in separate],
        "screening": {"candidates": len(candidates), "kept": len(new), "left_out": [x.to_json() for x in suppressed],
                      "region_wall_m": [round(x, 3) for x in region], "tank_top_v_m": survey.tank_top_v_m},
        "params": json.loads(json.dumps(asdict(params), default=str)),
        "created_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
    }
    return Report(defects, wall, survey, coverage, rating, views, inp, params, trace, list(doc.get("unplaced") or []), suppressed,
                  precision, separate=separate)


def entry_severity(d: Defect, severity: np.ndarray) -> dict | None:
    """A corrosion entry's condition state: the state of most of its decided pixels, with the
    share of each (from the mosaic's severity map inside the entry's polygon)."""
    from inspect_pipe.saliency_defects._detect import SEVERITY_STATES

    if not d.polygon_mosaic_px:
        return None
    m = np.zeros(severity.shape, np.uint8)
    cv2.fillPoly(m, [np.asarray(d.polygon_mosaic_px, np.int32)], 1)
    vals = severity[(m > 0) & (severity > 0)]
    if vals.size == 0:
        return None
    counts = np.bincount(vals, minlength=4)[1:4].astype(float)
    return {"state": SEVERITY_STATES[int(np.argmax(counts))],
            "fractions": {k: round(float(c / counts.sum()), 3) for k, c in zip(SEVERITY_STATES, counts)}}


def plate_field_edges(plan, frame, u_lo: float, u_hi: float) -> list[tuple[float, str]] | None:
    """Wall u of the plate field boundaries the survey plan gives, with the name of the field that
    begins at each: ship frames on a side shell ("Fr. 143-144"), stiffeners on a bulkhead
    ("stiff. 2-3 P"); None without a plan, or for a wall it has neither for."""
    if plan is None or frame is None:
        return None
    from inspect_pipe.ship import ShipFrames

    wall = plan.wall.name
    edges: list[tuple[float, str]] = []
    if wall.is_side_shell:
        frames = ShipFrames.from_plan(plan)
        xs = [frame.to_hold(np.array([[u, 0.0]]))[0, 0] for u in (u_lo, u_hi)]
        f_lo, f_hi = sorted(frames.frame_at(x) for x in xs)
        for n in range(int(np.floor(f_lo)), int(np.ceil(f_hi)) + 1):
            u = frame.to_wall(np.array([[frames.x_of(n), 0.0, 0.0]]))[0, 0]
            a, b = (n, n + 1) if frame.e_u[0] > 0 else (n - 1, n)
            edges.append((float(u), f"Fr. {a}-{b}"))
    elif wall.is_bulkhead and plan.wall.stiffener_spacing_m:
        sp = plan.wall.stiffener_spacing_m
        ys = [frame.to_hold(np.array([[u, 0.0]]))[0, 1] for u in (u_lo, u_hi)]
        k_lo, k_hi = int(np.floor(min(ys) / sp)), int(np.ceil(max(ys) / sp))
        for k in range(k_lo, k_hi + 1):
            u = frame.to_wall(np.array([[0.0, k * sp, 0.0]]))[0, 0]
            # the field that begins at this stiffener, going right (+u)
            y_next = k * sp + sp * np.sign(frame.e_u[1] or 1.0)
            lo, hi = sorted((k, int(round(y_next / sp))))
            side = lambda j: "CL" if j == 0 else f"{abs(j)}{'P' if j > 0 else 'S'}"  # noqa: E731
            edges.append((float(u), f"stiff. {side(lo)}-{side(hi)}"))
    else:
        return None
    edges.sort()
    return edges


def area_imaging(areas, views, wall: WallMap, sweep) -> dict[str, dict]:
    """Per rating area, how it was imaged (the survey record's stand-off and achieved resolution):
    over the placed frames whose footprint holds the area's centre, the median distance to the wall
    (forward range, less the camera's offset) and the median wall millimetres per frame pixel at
    the centre (the frame -> wall map's Jacobian)."""
    out: dict[str, dict] = {}
    cam_dx = float(sweep.meta.cam_to_body.t[0]) if sweep is not None else 0.0
    for a in areas:
        cm = wall.to_mosaic(np.array([[(a.u0_m + a.u1_m) / 2, (a.v0_m + a.v1_m) / 2]]))[0]
        res, dist = [], []
        for v in views:
            q = np.linalg.solve(v.H, np.array([cm[0], cm[1], 1.0]))
            if abs(q[2]) < 1e-12:
                continue
            x, y = q[:2] / q[2]
            if not (0 <= x < v.size_wh[0] and 0 <= y < v.size_wh[1]):
                continue
            pts = np.array([[x - 0.5, y, 1], [x + 0.5, y, 1], [x, y - 0.5, 1], [x, y + 0.5, 1]]) @ v.H.T
            wm = wall.to_wall(pts[:, :2] / pts[:, 2:3])
            res.append(1000 * np.sqrt(abs(np.linalg.det(np.c_[wm[1] - wm[0], wm[3] - wm[2]]))))
            if sweep is not None and 0 <= v.index < len(sweep.frames) and sweep.frames[v.index].dist_front_m is not None:
                dist.append(sweep.frames[v.index].dist_front_m - cam_dx)
        out[a.name] = {"frames": len(res), "mm_per_px": round(float(np.median(res)), 2) if res else None,
                       "standoff_m": round(float(np.median(dist)), 2) if dist else None}
    return out


def _limitations(sweep, plan, calibration: dict | None = None) -> list[str]:
    """What the inputs lacked, as the report states it (doctor --sweep's findings that failed).
    ``calibration``: of the camera the mosaic used (mosaic.json input.camera; --camera)."""
    if sweep is None:
        return [f"no sweep (a plain image folder): no vehicle state, {'' if calibration else 'uncalibrated camera, '}no survey plan; positions are "
                "metres from the mosaic's lower-left corner at the given scale"]
    from inspect_pipe.pipeline._readiness import sweep_readiness

    return [f"{f.what}: {f.detail}; {f.consequence}" for f in sweep_readiness(sweep, plan)
            if not f.ok and not (calibration and f.what == "calibration")]


def survey_plan_of(sweep, override=None):
    """(plan, wall frame) of a report: ``override`` (--survey) or the plan stored in the sweep,
    with the hold's dimensions from the plan or the simulation; (None, None) without a plan."""
    meta = getattr(sweep, "meta", None)
    plan = override if override is not None else getattr(meta, "survey_plan", None)
    if plan is None:
        return None, None
    if meta is not None:
        return plan, replace(meta, survey_plan=plan).wall_frame()
    from inspect_pipe.ship import plan_wall_frame

    try:
        return plan, plan_wall_frame(plan)
    except ValueError as err:
        raise InputError("survey plan", str(err), "add the hold's length_m / width_m to the plan") from None


def load_previous(out_dir: Path) -> list[Defect]:
    j, c = out_dir / "defects.json", out_dir / "defects.csv"
    if not j.exists():
        if c.exists():
            raise InputError(str(c), "found without defects.json", "keep both files of a register together")
        return []
    return read_register(j, c)


def report_from_run(store, out_dir: Path, params: ReportParams = ReportParams()) -> Report:
    """Load a run directory's artifacts (RunStore) and the previous register in ``out_dir``."""
    out_dir = Path(out_dir)
    previous = load_previous(out_dir)  # first: a hand-edited register with a bad status stops before anything is written
    doc = store.load_mosaic_json()
    mosaic = store.load_mosaic_image()
    det = store.load_detections()
    kinds = [k for k in det["kinds"] if isinstance(k, str)]
    masks, probs = {}, {}
    for k in kinds:
        m = store.load_class_map("mosaic", k, "mask")
        if m.shape != mosaic.shape[:2]:
            raise InputError(str(store.class_map_path("mosaic", k, "mask")), f"size {m.shape[::-1]} is not the mosaic's {mosaic.shape[1::-1]}")
        masks[k] = m > 0
        probs[k] = store.load_class_map("mosaic", k, "prob")
    sweep = store.load_sweep()
    views = {v.index: v for v in frame_views(doc, str(store.mosaic_dir / "mosaic.json"), sweep)}
    keyframes = []
    for idx in det.get("keyframes") or []:
        if idx in views:
            keyframes.append(KeyframeDetection(views[idx], {k: store.load_class_map(str(idx), k, "mask") > 0 for k in kinds}))
    checksums = {}
    for name, p in [("mosaic.json", store.mosaic_dir / "mosaic.json"), ("mosaic.png", store.mosaic_dir / "mosaic.png"),
                    ("detect/defects.json", store.detect_dir / "defects.json")]:
        checksums[name] = sha256_file(p)
    if sweep is not None:
        for name in ("sweep.json", "frames.jsonl"):
            checksums[f"sweep/{name}"] = sha256_file(Path(sweep.path) / name)
    sev_path = store.class_map_path("mosaic", "corrosion", "severity")
    severity = store.load_class_map("mosaic", "corrosion", "severity") if "corrosion" in kinds and sev_path.exists() else None
    if severity is not None and severity.shape != mosaic.shape[:2]:
        raise InputError(str(sev_path), f"size {severity.shape[::-1]} is not the mosaic's {mosaic.shape[1::-1]}")
    inp = ReportInputs(doc, str(store.mosaic_dir / "mosaic.json"), mosaic, det, masks, probs, keyframes, sweep, previous, checksums,
                       severity)
    rep = build_report(inp, params)
    from ._review import AUDIT_NAME, review_summary

    rep.trace["review"] = review_summary(out_dir / AUDIT_NAME)  # inspect-pipe review's audit log, when there is one
    return rep


def write_report(report: Report, out_dir: Path, *, log=print) -> dict[str, Path | None]:
    """Write report.html, report.pdf (when WeasyPrint can), defects.json/.csv, coco.json,
    coverage.json, rating.json and the images under assets/. Returns what was written."""
    from ._render import render_all

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    return render_all(report, out_dir, log=log)


def register_files(report: Report) -> tuple[dict, str]:
    extra = {
        "report": REPORT_FORMAT,
        "wall_rating": report.rating.to_json(),
        "survey": report.survey.to_json(),
        "traceability": report.trace,
    }
    dec = report.precision.position_decimals if report.precision is not None else 4
    return register_json(report.defects, extra), register_csv(report.defects, dec)
