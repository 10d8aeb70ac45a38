"""Run the steps on one run directory (resumable), or many sweeps in parallel on Dask."""

from __future__ import annotations

import json
import time
from dataclasses import replace, dataclass, field
from pathlib import Path
from typing import Callable

import inspect_pipe
from inspect_pipe.errors import InputError

from ._steps import STEP_NAMES, STEPS, EarlierRunKept, Progress, RunConfig, check_input, input_kind, step_options
from ._store import RunStore


@dataclass
class StepOutcome:
    name: str
    action: str  # "ran", "skipped", "not needed"
    seconds: float = 0.0
    why: str = ""


@dataclass
class RunOutcome:
    run_dir: Path
    steps: list[StepOutcome] = field(default_factory=list)
    report: dict | None = None
    error: str | None = None


def plan(store: RunStore, cfg: RunConfig, *, force: bool = False, rerun_from: str | None = None) -> list[tuple[str, str]]:
    """[(step, 'run' | 'skip' | 'n/a', why)] without running anything."""
    if rerun_from is not None and rerun_from not in STEP_NAMES:
        raise InputError("--rerun-from", f"{rerun_from!r} is not a step", f"one of {', '.join(STEP_NAMES)}")
    kind = input_kind(cfg.input)
    rec = store.load_run()
    out = []
    dirty = force
    for step in STEPS:
        if step.name == "capture" and kind != "fly":
            out.append((step.name, "n/a", f"input is a {kind}"))
            continue
        if rerun_from == step.name:
            dirty = True
        saved = rec["steps"].get(step.name)
        if dirty:
            out.append((step.name, "run", "forced" if force else f"--rerun-from {rerun_from}" if rerun_from else "an earlier step ran"))
        elif not step.done(store):
            out.append((step.name, "run", "output missing or damaged"))
            dirty = True
        elif saved is None or saved.get("options") != step_options(step, cfg):
            out.append((step.name, "run", "options changed" if saved else "no record of its options"))
            dirty = True
        else:
            out.append((step.name, "skip", "output exists"))
    return [(a, b, c) for a, b, c in out]


def run_pipeline(
    run_dir: str | Path,
    cfg: RunConfig,
    *,
    force: bool = False,
    rerun_from: str | None = None,
    progress: Progress | None = None,
    log: Callable[[str], None] = print,
) -> RunOutcome:
    """Run every step that is not done (see ``plan``) on ``run_dir``."""
    kind = check_input(cfg.input)  # before the run directory is made
    store = RunStore(run_dir)
    store.root.mkdir(parents=True, exist_ok=True)
    steps = plan(store, cfg, force=force, rerun_from=rerun_from)
    had_run = store.run_exists()
    doc = store.load_run()
    before = json.loads(json.dumps(doc))  # what run.json said, for a step that keeps the earlier run
    doc["input"] = {"spec": cfg.input, "kind": kind,
                    "sweep": str(Path(cfg.input).resolve()) if kind == "sweep" else None}
    doc["software"] = f"inspect_pipe {inspect_pipe.__version__}"
    store.save_run(doc)
    outcome = RunOutcome(store.root)
    by_name = {s.name: s for s in STEPS}
    for name, action, why in steps:
        step = by_name[name]
        if action != "run":
            if action == "skip":
                log(f"{store.root.name}: {name}: skipped ({why})")
            outcome.steps.append(StepOutcome(name, "skipped" if action == "skip" else "not needed", 0.0, why))
            continue
        store.forget_step(name)  # a crash mid-step leaves it not done
        t0 = time.monotonic()
        try:
            if name == "report":
                outcome.report = step.run(store, cfg, progress, log=log)
            else:
                step.run(store, cfg, progress)
        except EarlierRunKept:
            if had_run:
                store.save_run(before)
            else:
                store.run_json.unlink(missing_ok=True)
            raise
        dt = time.monotonic() - t0
        store.mark_step(name, {"options": step_options(step, cfg), "seconds": round(dt, 3),
                               "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())})
        outcome.steps.append(StepOutcome(name, "ran", dt, why))
    return outcome


def _one(args) -> RunOutcome:
    """Worker entry (Dask or local): one sweep's pipeline, errors as values."""
    run_dir, cfg, force, rerun_from = args
    if cfg.threads:
        import cv2

        cv2.setNumThreads(cfg.threads)
    try:
        return run_pipeline(run_dir, cfg, force=force, rerun_from=rerun_from, log=lambda s: None)
    except InputError as err:
        out = RunOutcome(Path(run_dir))
        out.error = str(err)
        return out
    except Exception as err:  # noqa: BLE001 - one sweep's failure must not stop the batch
        return _failed(run_dir, err)


def _failed(run_dir, err: BaseException) -> RunOutcome:
    """An unexpected failure as a value: the reason in one line, the traceback in RUN/error.txt."""
    import traceback

    from inspect_pipe._files import atomic_write

    out = RunOutcome(Path(run_dir))
    where = Path(run_dir) / "error.txt"
    try:
        atomic_write(where, "".join(traceback.format_exception(err)).encode(), fsync=False)
        more = f" (traceback in {where})"
    except OSError:
        more = ""
    out.error = f"{run_dir}: failed with {type(err).__name__}: {err}{more}"
    return out


def run_many(
    jobs: list[tuple[Path, RunConfig]],
    *,
    workers: int = 2,
    scheduler: str | None = None,
    force: bool = False,
    rerun_from: str | None = None,
    on_done: Callable[[RunOutcome], None] | None = None,
) -> list[RunOutcome]:
    """Many sweeps: one process and no Dask when ``workers == 1`` and no scheduler; otherwise a
    Dask distributed client on ``scheduler`` (tcp://HOST:8786) or a local cluster of ``workers``
    single-threaded processes (each sweep then runs on one thread: Dask spreads the sweeps, not
    the work inside one)."""
    if workers <= 1 and scheduler is None:
        args = [(str(d), c, force, rerun_from) for d, c in jobs]
        outs = []
        for a in args:
            o = _one(a)
            outs.append(o)
            if on_done:
                on_done(o)
        return outs
    args = [(str(d), replace(c, threads=1), force, rerun_from) for d, c in jobs]
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise InputError("--workers", "Dask distributed is not installed", "pip install 'inspect-pipe[dask]', or use --workers 1") from None
    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
        client = Client(cluster)
    else:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError) as err:
            raise InputError(scheduler, f"cannot reach the Dask scheduler ({err})") from None
    try:
        futs = [client.submit(_one, a, pure=False) for a in args]
        index = {f.key: i for i, f in enumerate(futs)}
        outs: list[RunOutcome | None] = [None] * len(futs)
        for f in as_completed(futs):
            try:
                o = f.result()
            except Exception as err:  # noqa: BLE001 - a worker that died (KilledWorker) or could not unpickle
                o = _failed(args[index[f.key]][0], err)
            outs[index[f.key]] = o
            if on_done:
                on_done(o)
        return [o for o in outs if o is not None]
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
