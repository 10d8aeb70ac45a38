"""The pipeline's steps, declared once, in order: capture -> mosaic -> detect -> report.

Each step is ``run(store, config, progress)`` plus ``done(store)`` (its artifacts exist) and the
part of the config it depends on (``keys``): a finished step is skipped when its artifacts exist
and the saved copy of those options is unchanged; otherwise it and every later step run again.
"""

from __future__ import annotations

import json
import logging
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from inspect_pipe.errors import InputError
from inspect_pipe.saliency_defects._core import TILE_PX
from inspect_pipe.saliency_defects._engines import DEFAULT_ENGINE, ENGINES

from ._store import DEFECTS_FORMAT, RunStore, write_json, write_png

log = logging.getLogger("inspect_pipe")

Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class DetectConfig:
    """Options of the detect step. ``engine`` is a name of ``saliency_defects.ENGINES`` (the
    default is ``DEFAULT_ENGINE``, as for ``inspect-pipe detect``); ``model`` that engine's model
    file (None: the shipped one)."""

    kinds: tuple[str, ...] = ("corrosion", "crack")
    model: str | None = None  # default: the shipped model of the engine
    keyframe_spacing: float = 0.5  # keyframes' centres at least this many frame widths apart; 0 = no keyframes
    tile_px: int = TILE_PX  # the detection core's tile size
    engine: str = DEFAULT_ENGINE

    def __post_init__(self) -> None:
        if self.engine not in ENGINES:
            raise InputError("--engine", f"{self.engine!r} unknown", f"one of {', '.join(ENGINES)}")


@dataclass(frozen=True)
class RunConfig:
    """Effective options of a run (saved per step in run.json)."""

    input: str = ""  # sweep dir, image folder, or fly:SCENARIO
    survey: dict = field(default_factory=dict)  # for a capture step: vessel, hold, wall, frame spacing ...
    mosaic_detector: str = "sift"
    mosaic_seed: int = 0
    focal_px: float | None = None  # folder input only
    detect: DetectConfig = field(default_factory=DetectConfig)
    report: dict = field(default_factory=dict)  # ReportParams as a dict (see report_params)
    report_out: str | None = None  # default RUN/report
    threads: int = 0  # threads for one sweep (0: every core); results do not depend on it
    verify: bool = False  # mosaic step: check the sweep's files against COMPLETE's sha256 (differing frames unplaced)
    survey_plan: dict | None = None  # --survey: the survey plan (inspect_pipe.ship), stored in a captured sweep, used by mosaic and report
    camera: dict | None = None  # --camera: the calibrated CameraModel.to_json() (K, dist, calibration source and sha256)

    def camera_model(self):
        """The --camera calibration as a ``CameraModel`` (None without one)."""
        if self.camera is None:
            return None
        from inspect_pipe.capture import CameraModel

        c = self.camera
        return CameraModel(np.asarray(c["K"], float), np.asarray(c["dist"], float), int(c["width"]), int(c["height"]),
                           str(c.get("name", "camera")), calibration=c.get("calibration"))

    def plan(self):
        """The survey plan as ``inspect_pipe.ship.SurveyPlan`` (None without one)."""
        if self.survey_plan is None:
            return None
        from inspect_pipe.ship import parse_survey_plan

        return parse_survey_plan(self.survey_plan, "--survey")

    def report_params(self):
        from inspect_pipe.report import CoverageParams, RatingParams, RegisterParams, ReportParams

        r = dict(self.report)
        return ReportParams(
            register=RegisterParams(**r.get("register", {})), coverage=CoverageParams(**r.get("coverage", {})),
            rating=RatingParams(**r.get("rating", {})), m_per_px=r.get("m_per_px"),
            region_wall_m=tuple(r["region_wall_m"]) if r.get("region_wall_m") else None, pdf=r.get("pdf", True),
            survey_plan=self.plan(),
        )


def input_kind(spec: str) -> str:
    """'fly' (a scenario to fly: capture step), 'sweep', or 'folder'."""
    if spec.startswith("fly:") or spec.endswith((".yaml", ".yml")):
        return "fly"
    p = Path(spec)
    if not p.exists():
        raise InputError(spec, "not found", "give a sweep directory, a folder of images, or fly:SCENARIO.yaml")
    if (p / "sweep.json").is_file():
        return "sweep"
    if p.is_dir():
        return "folder"
    raise InputError(spec, "not a sweep directory or folder of images")


def check_input(spec: str) -> str:
    """The input's kind, after the checks that need no step to run: the scenario loads, the folder has images,
    the sweep has readable frames. A run directory is made only for an input that passes (an empty folder or
    a missing scenario left a run.json behind)."""
    kind = input_kind(spec)
    if kind == "fly":
        from inspect_pipe.flight.scenario import load_scenario

        load_scenario(spec[4:] if spec.startswith("fly:") else spec)
    elif kind == "folder":
        from inspect_pipe.mosaic import FolderSource

        FolderSource(Path(spec))
    else:
        from inspect_pipe.capture import read_sweep

        sweep = read_sweep(spec)
        if not sweep.frames:
            why = f" ({sweep.problems[0]})" if sweep.problems else ""
            raise InputError(str(Path(spec) / "frames.jsonl"), f"no readable frames{why}", "nothing to mosaic")
    return kind


# ---------------------------------------------------------------------------------- capture


def run_capture_step(store: RunStore, cfg: RunConfig, progress: Progress | None) -> None:
    """Fly the scenario in the simulator and record its 10 Hz sweep into RUN/sweep."""
    import shutil

    from inspect_pipe.capture import CaptureConfig, ManualClock, run_capture
    from inspect_pipe.capture.sources.sim import SimSource, TrajectoryRecorder
    from inspect_pipe.flight.runner import run_scenario
    from inspect_pipe.flight.scenario import load_scenario

    path = cfg.input[4:] if cfg.input.startswith("fly:") else cfg.input
    sc = load_scenario(path)
    if store.sweep_dir.exists():
        shutil.rmtree(store.sweep_dir)
    rec = TrajectoryRecorder(sc)
    if progress:
        progress("fly", 0, 1)
    run_scenario(sc, on_tick=rec)
    clock = ManualClock(0.0)
    src = SimSource(sc, trajectory=rec.feed, clock=clock, camera=cfg.camera_model())
    n = int(sc.duration_s * sc.camera.fps)
    ccfg = CaptureConfig(rate_hz=sc.camera.fps, time_base="simulation_s", wait_for_writer=True, survey=dict(cfg.survey),
                         survey_plan=cfg.survey_plan, camera=cfg.camera_model())
    res = run_capture(src, store.sweep_dir, clock=clock, config=ccfg,
                      on_progress=(lambda p: progress("capture", min(p.frames, n), n)) if progress else None)
    if res.writer_error:
        raise InputError(str(store.sweep_dir), res.writer_error)


def capture_done(store: RunStore) -> bool:
    return store.sweep_exists()


# ---------------------------------------------------------------------------------- mosaic


class EarlierRunKept(InputError):
    """A step refused bad input rather than replace the earlier run's output, which is untouched:
    the run record (``run.json``) goes back to what it said before this run."""


def run_mosaic_step(store: RunStore, cfg: RunConfig, progress: Progress | None) -> None:
    from inspect_pipe import mosaic as M

    sweep = store.input_sweep()
    params = M.MosaicParams(register=M.RegisterParams(detector=cfg.mosaic_detector, seed=cfg.mosaic_seed, focal_px=cfg.focal_px, workers=cfg.threads))
    if sweep is not None:
        out = M.run_mosaic_sweep(sweep, store.mosaic_dir, params=params, progress=progress, verify=cfg.verify,
                                 survey_plan=cfg.plan(), camera=cfg.camera_model())
    else:
        out = M.run_mosaic_folder(Path(cfg.input), store.mosaic_dir, params=params, progress=progress, camera=cfg.camera_model())
    if not out.published:  # bad input over the good mosaic of an earlier run: that run is kept
        raise EarlierRunKept(cfg.input, out.problems[0])
    if not out.H:
        raise InputError(cfg.input, out.problems[0] if out.problems else "no frame could be placed")
    # what `inspect-pipe mosaic` prints, the run prints too: frames left out (unreadable, cut short) and a mosaic
    # that stands but is not what was asked (one frame only, no overlap): the later steps go on with it
    if out.warnings:
        more = f" (and {len(out.warnings) - 1} more, listed in mosaic/mosaic.json)" if len(out.warnings) > 1 else ""
        log.warning(f"mosaic: {out.warnings[0]}{more}")
    for problem in out.problems:
        log.warning(f"mosaic: {problem}")
    doc = store.load_mosaic_json()
    if sweep is None and "frame_size_wh" not in doc:  # frame sizes for coverage of a folder mosaic
        img = M.read_image(M.FolderSource(Path(cfg.input)).path(0))
        doc["frame_size_wh"] = [int(img.shape[1]), int(img.shape[0])]
        write_json(store.mosaic_dir / "mosaic.json", doc)


def mosaic_done(store: RunStore) -> bool:
    return store.mosaic_exists()


# ---------------------------------------------------------------------------------- detect


def select_keyframes(views, spacing: float) -> list[int]:
    """Frames whose mosaic centres are at least ``spacing`` frame widths from every earlier pick."""
    if spacing <= 0:
        return []
    picked, centres = [], []
    for idx, H, (w, h) in views:
        c = H @ np.array([w / 2, h / 2, 1.0])
        c = c[:2] / c[2]
        scale = np.sqrt(abs(np.linalg.det(H[:2, :2]))) if abs(H[2, 2]) > 0 else 1.0
        if all(np.linalg.norm(c - q) >= spacing * w * scale for q in centres):
            picked.append(idx)
            centres.append(c)
    return picked


def run_detect_step(store: RunStore, cfg: RunConfig, progress: Progress | None) -> None:
    """Detect on the mosaic (transparent pixels are not wall) and on keyframes, with the engine
    of ``cfg.detect`` (loaded as ``inspect-pipe detect`` loads it, ``load_engine``)."""
    from inspect_pipe.saliency_defects import load_engine

    dc = cfg.detect
    eng = load_engine(dc.engine, dc.model, threads=cfg.threads)
    eng.check_kinds(dc.kinds)
    eng.check_tile(dc.tile_px)
    bgra = store.load_mosaic_image()
    valid = bgra[:, :, 3] > 0
    doc = store.load_mosaic_json()
    sweep = store.load_sweep()
    views = []
    if sweep is not None:
        w, h = sweep.meta.width, sweep.meta.height
        views = [(int(f["index"]), np.asarray(f["H"], float), (w, h)) for f in doc["frames"] if f.get("group", 0) == 0]
    keyframes = select_keyframes(views, dc.keyframe_spacing) if sweep is not None else []
    total = 1 + len(keyframes)
    if progress:
        progress("detect", 0, total)
    mosaic_png = str(store.mosaic_dir / "mosaic.png")
    try:
        det = eng.detect(np.ascontiguousarray(bgra[:, :, :3]), kinds=dc.kinds, tile_px=dc.tile_px)
    except ValueError as err:
        raise InputError(mosaic_png, str(err)) from None
    regions, images = [], []
    for k in dc.kinds:
        p = np.where(valid, det.class_probs[k], 0).astype(np.uint8)
        m = eng.decide(p, k)
        store.save_class_map("mosaic", k, "prob", p)
        store.save_class_map("mosaic", k, "mask", (m & valid).astype(np.uint8) * 255)
    if getattr(det, "severity", None) is not None:  # condition states of the decided corrosion (onnx / fused)
        store.save_class_map("mosaic", "corrosion", "severity", np.where(valid, det.severity, 0).astype(np.uint8))
    prob = np.where(valid, det.prob, 0).astype(np.uint8)
    mask = det.mask & valid
    write_png(store.detect_dir / "mosaic.prob.png", prob)
    write_png(store.detect_dir / "mosaic.mask.png", mask.astype(np.uint8) * 255)
    for r in det.regions:
        x, y = r.polygon_px[0]
        if valid[y, x]:
            regions.append({"id": len(regions) + 1, "image": "mosaic", "file": mosaic_png, **r.to_json()})
    images.append({"name": "mosaic", "file": mosaic_png, "width": int(bgra.shape[1]),
                   "height": int(bgra.shape[0]), "prob": "mosaic.prob.png", "mask": "mosaic.mask.png",
                   "defect_fraction": round(float(mask.mean()), 6)})
    if progress:
        progress("detect", 1, total)
    if keyframes:
        from inspect_pipe.mosaic import SweepSource

        src = SweepSource(sweep)
        for start in range(0, len(keyframes), eng.batch):  # a sweep's frames share one network call
            part = keyframes[start:start + eng.batch]
            imgs = [src.load(idx) for idx in part]  # undistorted, as the mosaic's H expects; indices are positions in the sweep's frame list
            try:
                dets = eng.detect_batch(imgs, kinds=dc.kinds, tile_px=dc.tile_px)
            except ValueError as err:
                raise InputError(sweep.frames[part[0]].image, str(err)) from None
            for idx, fd in zip(part, dets):
                for k in dc.kinds:
                    store.save_class_map(str(idx), k, "mask", eng.decide(fd.class_probs[k], k).astype(np.uint8) * 255)
                for r in fd.regions:
                    regions.append({"id": len(regions) + 1, "image": f"frame {idx}", "file": sweep.frames[idx].image, **r.to_json()})
            if progress:
                progress("detect", 1 + start + len(part), total)
    write_json(store.detect_dir / "defects.json", {
        "format": DEFECTS_FORMAT,
        "model": eng.model_doc(dc.kinds),
        "kinds": list(dc.kinds), "images": images, "regions": regions, "errors": [],
        "keyframes": keyframes, "keyframe_spacing": dc.keyframe_spacing,
    })


def detect_done(store: RunStore) -> bool:
    return store.detect_exists()


# ---------------------------------------------------------------------------------- report


def report_out(store: RunStore, cfg: RunConfig) -> Path:
    return Path(cfg.report_out) if cfg.report_out else store.report_dir


def run_report_step(store: RunStore, cfg: RunConfig, progress: Progress | None, log=print) -> dict:
    from inspect_pipe.report import report_from_run, write_report

    out = report_out(store, cfg)
    if progress:
        progress("report", 0, 1)
    rep = report_from_run(store, out, cfg.report_params())
    written = write_report(rep, out, log=log)
    if progress:
        progress("report", 1, 1)
    return written


def report_done(store: RunStore) -> bool:
    return store.report_exists()


# ---------------------------------------------------------------------------------- the list


@dataclass(frozen=True)
class Step:
    name: str
    run: Callable
    done: Callable[[RunStore], bool]
    keys: tuple[str, ...]  # RunConfig fields this step depends on


STEPS: tuple[Step, ...] = (
    Step("capture", run_capture_step, capture_done, ("input", "survey", "survey_plan", "camera")),
    Step("mosaic", run_mosaic_step, mosaic_done, ("input", "mosaic_detector", "mosaic_seed", "focal_px", "verify", "survey_plan", "camera")),
    Step("detect", run_detect_step, detect_done, ("detect",)),
    Step("report", run_report_step, report_done, ("report", "report_out", "survey_plan")),
)
STEP_NAMES = tuple(s.name for s in STEPS)


def step_options(step: Step, cfg: RunConfig) -> dict:
    d = asdict(cfg)
    # runs recorded before --verify / --survey existed keep their steps when those are not given
    opts = {k: d[k] for k in step.keys if not (k in ("verify", "survey_plan") and not d[k])}
    return json.loads(json.dumps(opts, default=str))
