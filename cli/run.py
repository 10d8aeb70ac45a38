"""``inspect-pipe run INPUT... -o OUT``: capture -> mosaic -> detect -> report, resumable."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from cli._common import SURVEY_HELP, StageProgress, choices, console, load_plan, note, one_line_errors, progress_enabled
from inspect_pipe._files import write_json
from inspect_pipe.capture import load_camera
from cli.detect import DEFAULT, ENGINE_HELP, Engine, Kind
from cli.mosaic import MAX_FOCAL_PX
from inspect_pipe.errors import InputError
from inspect_pipe.pipeline import STEP_NAMES
from inspect_pipe.report import SCHEMES
from inspect_pipe.saliency_defects._engines import DEFAULT_ENGINE

Step = choices("Step", STEP_NAMES)  # --rerun-from
Scheme = choices("Scheme", SCHEMES)  # --scheme of run and report

HELP = """Run the whole batch pipeline on one or many sweeps: capture (fly:SCENARIO.yaml only) ->
mosaic -> detect -> report.

One INPUT: OUT is its run directory (OUT/mosaic, OUT/detect, OUT/report/report.html ...).
Several: OUT/<input name>/ each, run in parallel on Dask (a local cluster of --workers
processes, or --scheduler tcp://HOST:8786); --workers 1 runs them one after the other without Dask.

A sweep cut by a crash (its last frames.jsonl line partial, its COMPLETE marker listing more
frames than the disk holds) is mosaicked from its whole frames; frames that cannot be read are
listed as unplaced with the reason in mosaic.json and the report. --verify also checks every
file against the sha256 in COMPLETE. With several sweeps, one that fails does not stop the
others: each failure is printed with its reason and recorded in OUT/runs.json, and the command
exits 2 after the others have finished.

Finished steps are skipped (their output exists and their options are unchanged); --force redoes
everything, --rerun-from STEP redoes STEP and what follows. A surveyor's statuses in
report/defects.json or defects.csv are kept.

The detect step uses --engine: onnx (default), the learned network;
saliency, the paper's saliency-and-Bayes detector; fused, both mixed.
Another engine than the last run's redoes detect and report; the report
names the engine and model version.

--camera camera.yaml (from `inspect-pipe calibrate`, or a ROS camera_info YAML): the mosaic
undistorts and rectifies with it, over a sweep's own camera model; a fly: input's simulated
camera renders through it. A changed camera file redoes capture (fly:) and mosaic. Without
one, a sweep that records no calibration gets a warning and the report says "uncalibrated".

Examples:

  inspect-pipe run out/sweep1 -o out/run1

  inspect-pipe run out/sweep1 out/sweep2 out/sweep3 -o out/runs --workers 2

  inspect-pipe run fly:scenarios/inspection_sweep_wall.yaml -o out/run_sim

  inspect-pipe run out/sweep1 -o out/run1 --rerun-from report --scheme MSC.1/Circ.1399

  inspect-pipe run out/sweep1 -o out/run1 --engine saliency     (the paper's detector)

  inspect-pipe run frames/ -o out/run2 --camera camera.yaml --m-per-px 0.002
"""


RichProgress = StageProgress  # the name demo and older code import


#: The smallest side of an area under consideration (--area-m): a finer grid rates nothing a surveyor reads and,
#: over a hold's wall, is millions of areas.
MIN_AREA_M = 0.1


def build_config(input: str, *, kinds: str, keyframe_spacing: float, scheme: str, area_m: float, no_pdf: bool,
                 m_per_px: Optional[float], focal_px: Optional[float], report_out: Optional[Path] = None, survey: dict | None = None,
                 engine: str = DEFAULT_ENGINE, verify: bool = False, survey_plan=None, camera=None, model: Optional[Path] = None):
    from inspect_pipe.pipeline import DetectConfig, RunConfig
    from inspect_pipe.report import SCHEMES

    if scheme not in SCHEMES:
        raise InputError("--scheme", f"{scheme!r} unknown", f"one of {', '.join(SCHEMES)}")
    if area_m <= 0:
        raise InputError("--area-m", f"{area_m} is not positive")
    if area_m < MIN_AREA_M:
        raise InputError("--area-m", f"{area_m:g} m is below {MIN_AREA_M:g} m", "areas under consideration are of the order of a metre")
    for name, value in (("--m-per-px", m_per_px), ("--focal-px", focal_px)):
        if value is not None and value <= 0:
            raise InputError(name, f"{value:g} is not positive")
    if focal_px is not None and focal_px > MAX_FOCAL_PX:
        raise InputError("--focal-px", f"{focal_px:g} px", f"at most {MAX_FOCAL_PX:g} px (a focal length in pixels, e.g. 618)")
    if keyframe_spacing < 0:
        raise InputError("--keyframe-spacing", f"{keyframe_spacing:g} is negative", "0: mosaic only")
    k = ("corrosion", "crack") if kinds == "all" else tuple(x.strip() for x in kinds.split(",") if x.strip())
    report = {"rating": {"scheme": scheme, "area_size_m": area_m}, "pdf": not no_pdf}
    if m_per_px:
        report["m_per_px"] = m_per_px
    return RunConfig(input=input, survey=survey or {}, focal_px=focal_px, detect=DetectConfig(kinds=k, keyframe_spacing=keyframe_spacing, engine=engine,
                                                                                                     model=str(shipped_or_given(model)) if model else None),
                     report=report, report_out=str(report_out) if report_out else None, verify=verify,
                     survey_plan=survey_plan.to_json() if survey_plan is not None else None,
                     camera=camera.to_json() if camera is not None else None)


def shipped_or_given(model: Path) -> Path:
    """``--model``: the file given, or a model shipped in the package by that name."""
    from inspect_pipe.saliency_defects._onnx_detect import default_onnx_path

    shipped = default_onnx_path().parent / Path(model).name
    return Path(model) if Path(model).exists() or not shipped.exists() else shipped


def check_engine(dc) -> None:
    """Load the detect step's engine (``DetectConfig``) once, so that a missing onnxruntime or a
    bad model file stops the command (one line, exit 2) before a flight or a mosaic is computed."""
    from inspect_pipe.saliency_defects import load_engine

    load_engine(dc.engine, dc.model).check_kinds(dc.kinds)


def warn_missing(sweep_dir: Path, plan, echo=None, camera=None) -> None:
    """One warning line per piece the sweep lacks for a report in metres and ship terms
    (``doctor --sweep`` says the same at length); the report lists them as limitations.
    ``camera`` (--camera) supplies the calibration a sweep may lack. A sweep with no readable
    frame is :class:`InputError` (the mosaic step's own line), before any warning."""
    from inspect_pipe.capture import read_sweep
    from inspect_pipe.pipeline._readiness import sweep_readiness

    sweep = read_sweep(sweep_dir)
    sweep.require_frames()  # nothing to run on: the one error, not warnings about what the frames lack
    for f in sweep_readiness(sweep, plan):
        if not f.ok and not (camera is not None and f.what == "calibration"):
            (echo or note)(f"warning: {sweep_dir}: {f.what}: {f.detail}")


def check_camera(spec: str, camera) -> str:
    """Fit ``camera`` (--camera) to INPUT's frame size before anything runs: a scaling note line
    (or ""), or :class:`InputError` for another aspect ratio."""
    from inspect_pipe.capture._calibration import fit_camera, scaled_note
    from inspect_pipe.pipeline import input_kind

    kind = input_kind(spec)
    if kind == "sweep":
        from inspect_pipe.capture import read_sweep

        meta = read_sweep(spec).meta
        w, h, frames = meta.width, meta.height, f"the frames of {spec}"
    elif kind == "folder":
        from inspect_pipe.mosaic import FolderSource, read_image

        img = read_image(FolderSource(Path(spec)).path(0))
        w, h, frames = img.shape[1], img.shape[0], f"the images of {spec}"
    else:
        from inspect_pipe.flight.scenario import load_scenario

        sc = load_scenario(spec[4:] if spec.startswith("fly:") else spec)
        w, h, frames = sc.camera.width, sc.camera.height, f"the camera frames of {spec}"
    return scaled_note(fit_camera(camera, w, h, frames=frames).to_json())


def _name(spec: str) -> str:
    p = Path(spec[4:] if spec.startswith("fly:") else spec)
    return p.stem if p.suffix in (".yaml", ".yml") else p.name


def print_outcome(o, echo=typer.echo) -> None:
    steps = ", ".join(f"{s.name} {s.action}" + (f" {s.seconds:.1f} s" if s.action == "ran" else "") for s in o.steps if s.action != "not needed")
    echo(f"{o.run_dir}: {steps}")
    if o.report:
        echo(f"  report: {o.report['html']}" + (f" and {o.report['pdf']}" if o.report.get("pdf") else " (no PDF)"))


@one_line_errors
def run(
    inputs: Annotated[list[str], typer.Argument(help="Sweep directories, image folders, or fly:SCENARIO.yaml.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Run directory (one input) or parent of run directories.")],
    force: Annotated[bool, typer.Option("--force", help="Redo every step.")] = False,
    rerun_from: Annotated[Optional[Step], typer.Option("--rerun-from", help="Redo this step and the following ones.")] = None,
    workers: Annotated[int, typer.Option("--workers", help="Parallel sweeps on a local Dask cluster; 1 = no Dask.", min=1)] = 2,
    scheduler: Annotated[Optional[str], typer.Option("--scheduler", help="Existing Dask scheduler, e.g. tcp://HOST:8786.")] = None,
    kind: Annotated[Kind, typer.Option("--kind", help="Defect classes: all = corrosion + crack.")] = Kind.all,
    keyframe_spacing: Annotated[float, typer.Option("--keyframe-spacing", help="Keyframes detected on their own, in frame widths apart (0: mosaic only).")] = 0.5,
    scheme: Annotated[Scheme, typer.Option("--scheme", help="Coating rating scheme.")] = Scheme("MSC.1/Circ.1330"),
    area_m: Annotated[float, typer.Option("--area-m", help="Side of an area under consideration, m.")] = 1.0,
    m_per_px: Annotated[Optional[float], typer.Option("--m-per-px", help="Folder input: metres per mosaic pixel.")] = None,
    focal_px: Annotated[Optional[float], typer.Option("--focal-px", help="Folder input: focal length in pixels.")] = None,
    no_pdf: Annotated[bool, typer.Option("--no-pdf", help="Do not render report.pdf.")] = False,
    engine: Annotated[Engine, typer.Option("--engine", help="Detect step: " + ENGINE_HELP)] = DEFAULT,
    verify: Annotated[bool, typer.Option("--verify", help="Sweep input: check every file against the sha256 in its COMPLETE marker; frames that differ are unplaced.")] = False,
    survey: Annotated[Optional[Path], typer.Option("--survey", help=SURVEY_HELP)] = None,
    camera: Annotated[Optional[Path], typer.Option("--camera", help="Camera calibration (camera.yaml from `inspect-pipe calibrate`, or ROS camera_info): the simulated camera of fly: inputs, and K and distortion for the mosaic (over a sweep's own).")] = None,
    model: Annotated[Optional[Path], typer.Option("--model", help="Detect step: the engine's model file, or the name of a shipped one (default: the shipped network, defects_unet_v5.onnx, whose condition-state head the report turns into hard rust and the fair / poor / severe breakdown; a network without a head borrows v5's states).")] = None,
) -> None:
    from inspect_pipe.pipeline import input_kind, run_many, run_pipeline

    plan = load_plan(survey)
    if camera is not None and focal_px:
        raise InputError("--focal-px", "given with --camera", "give one: the camera file has the focal length")
    cam = load_camera(camera) if camera is not None else None

    kinds, scheme = kind.value, scheme.value
    rerun_from = rerun_from.value if rerun_from is not None else None
    # Bad input is found before anything is written: one input, it is the error; several, each bad
    # one is a failure of its own (printed, in runs.json) and the others still run.
    cfg_of: dict[str, object] = {}
    bad: dict[str, str] = {}
    for spec in inputs:
        try:
            input_kind(spec)
            if cam is not None:
                line = check_camera(spec, cam)
                if line:
                    note(line)
            cfg_of[spec] = build_config(spec, kinds=kinds, keyframe_spacing=keyframe_spacing, scheme=scheme, area_m=area_m,
                                        no_pdf=no_pdf, m_per_px=m_per_px, focal_px=focal_px, engine=engine.value,
                                        verify=verify, survey_plan=plan, camera=cam, model=model)
            if input_kind(spec) == "sweep":
                warn_missing(Path(spec), plan, camera=cam)
        except InputError as err:
            if len(inputs) == 1:
                raise
            bad[spec] = str(err)
            cfg_of.pop(spec, None)
    if cfg_of:
        check_engine(next(iter(cfg_of.values())).detect)
    if len(inputs) == 1:
        prog = RichProgress(_name(inputs[0]))
        try:
            o = run_pipeline(out, cfg_of[inputs[0]], force=force, rerun_from=rerun_from, progress=prog, log=note)
        finally:
            prog.close()
        print_outcome(o)
        return
    names = [_name(s) for s in inputs]
    if len(set(names)) != len(names):
        raise InputError(inputs[0], "two inputs have the same name", "their run directories would collide")
    jobs = [(out / n, cfg_of[s]) for n, s in zip(names, inputs) if s in cfg_of]
    failed: list[str] = []
    errors: dict[str, str] = {}
    for n, spec in zip(names, inputs):
        if spec in bad:
            failed.append(bad[spec])
            errors[str(out / n)] = bad[spec]
            typer.echo(f"{out / n}: error: {bad[spec]}", err=True)
    bar = None
    if progress_enabled():
        from rich.progress import Progress

        bar = Progress(console=console)
        bar.start()
        task = bar.add_task("sweeps", total=len(jobs))

    def done(o):
        if bar:
            bar.advance(task)
        if o.error:
            failed.append(o.error)
            errors[str(o.run_dir)] = o.error
            typer.echo(f"{o.run_dir}: error: {o.error}", err=True)
        else:
            print_outcome(o)

    try:
        run_many(jobs, workers=workers, scheduler=scheduler, force=force, rerun_from=rerun_from, on_done=done)
    finally:
        if bar:
            bar.stop()
    summary = [{"run": str(out / n), "input": spec, "status": "failed" if str(out / n) in errors else "done",
                "error": errors.get(str(out / n))} for n, spec in zip(names, inputs)]
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "runs.json", {"format": "inspect_pipe.runs/1", "runs": summary})
    if failed:
        names = ", ".join(Path(r["run"]).name for r in summary if r["error"])
        others = "; the others finished" if len(failed) < len(inputs) else ""
        raise InputError(str(out / "runs.json"), f"{len(failed)} of {len(inputs)} sweeps failed ({names}){others}; first: {failed[0]}")
