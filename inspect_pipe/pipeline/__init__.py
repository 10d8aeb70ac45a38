"""The batch pipeline: one ordered list of steps (capture -> mosaic -> detect -> report), one
RunStore for a run directory, resume by artifact presence, many sweeps on Dask."""

from ._runner import RunOutcome, StepOutcome, plan, run_many, run_pipeline
from ._steps import STEP_NAMES, STEPS, DetectConfig, RunConfig, Step, input_kind, select_keyframes
from ._store import RUN_FORMAT, RunStore

__all__ = [
    "DetectConfig", "RUN_FORMAT", "RunConfig", "RunOutcome", "RunStore", "STEPS", "STEP_NAMES", "Step", "StepOutcome",
    "input_kind", "plan", "run_many", "run_pipeline", "select_keyframes",
]
