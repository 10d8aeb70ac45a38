"""The detection engines by name: the one place that maps ``saliency`` | ``onnx`` | ``fused`` to a
loaded model and the functions that use it. ``inspect-pipe detect`` and the pipeline's detect
step both go through :func:`load_engine`.

    >>> eng = load_engine("onnx")                 # the shipped model of that engine
    >>> eng.check_kinds(("corrosion", "crack"))
    >>> det = eng.detect(bgr_image, kinds=("corrosion", "crack"))
    >>> eng.decide(det.class_probs["crack"], "crack")   # one class's decision mask
    >>> eng.model_doc(("corrosion", "crack"))          # what defects.json records as "model"

Loading errors are :class:`~inspect_pipe.errors.InputError` with the file, the problem and what
to do (``--engine saliency`` needs neither onnxruntime nor the network file).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from inspect_pipe.errors import InputError

from ._core import TILE_PX
from ._detect import Detection

ENGINES = ("saliency", "onnx", "fused")
#: What ``inspect-pipe detect``, ``run`` and ``demo`` use without ``--engine``: chosen on the
#: VALIDATION images, never on eval (``_fused.default_engine_on_validation``: the fastest engine
#: whose mean validation figure is within 0.01 of the best; a test checks the two agree).
DEFAULT_ENGINE = "onnx"
#: Model file suffix of each engine (``--model``): a file of another engine's kind is named as such.
SUFFIX = {"saliency": ".npz", "onnx": ".onnx", "fused": ".json"}


@dataclass(frozen=True)
class DetectorEngine:
    """A loaded engine. ``model`` is the engine's own model object (DefectModel, OnnxModel or
    FusedModel); ``batch`` how many equal-size images one :meth:`detect_batch` call runs at once."""

    name: str
    model_path: Path
    model: object
    tile_multiple: int = 64
    batch: int = 1

    @property
    def version(self) -> str:
        return str(self.model.version)

    @property
    def classes(self) -> tuple[str, ...]:
        return tuple(self.model.classes)

    def check_kinds(self, kinds) -> None:
        """InputError naming the model file when it has no class of ``kinds``."""
        for k in kinds:
            if k not in self.classes:
                raise InputError(self.model_path, f"model has no class {k!r}", f"has {', '.join(self.classes)}")

    def check_tile(self, tile_px: int) -> None:
        if tile_px % self.tile_multiple:
            raise InputError("--tile-px", f"{tile_px} is not a multiple of {self.tile_multiple}")

    def check_image(self, image: np.ndarray) -> None:
        """ValueError for an image :meth:`detect_batch` cannot take (checked before a batch is
        formed, so one bad frame does not fail the others)."""

    def detect(self, image: np.ndarray, *, kinds, tile_px: int = TILE_PX) -> Detection:
        """Probability maps, decision and regions of one 8-bit BGR (or grey) image. ValueError
        for an unusable image."""
        raise NotImplementedError

    def detect_batch(self, images: list[np.ndarray], *, kinds, tile_px: int = TILE_PX) -> list[Detection]:
        return [self.detect(im, kinds=kinds, tile_px=tile_px) for im in images]

    def decide(self, prob_u8: np.ndarray, cls: str) -> np.ndarray:
        """Decision mask (bool) of class ``cls`` on its probability map (uint8)."""
        raise NotImplementedError

    def model_doc(self, kinds) -> dict:
        """The ``model`` record of defects.json: file, engine, version, operating points."""
        raise NotImplementedError


class _Saliency(DetectorEngine):
    def detect(self, image, *, kinds, tile_px=TILE_PX):
        from ._detect import detect

        return detect(image, self.model, kinds=tuple(kinds), tile_px=tile_px)

    def decide(self, prob_u8, cls):
        from ._detect import decide

        return decide(prob_u8, self.model.classes[cls])[0]

    def model_doc(self, kinds):
        cm = self.model.classes
        return {"file": str(self.model_path), "engine": self.name, "version": self.version,
                "operating_points": {k: cm[k].threshold for k in kinds},
                "min_area_px": {k: cm[k].min_area_px for k in kinds}}


class _Onnx(DetectorEngine):
    def check_image(self, image):
        from ._onnx_detect import _check

        _check(image)

    def detect(self, image, *, kinds, tile_px=TILE_PX):
        from ._onnx_detect import detect_onnx

        return detect_onnx(image, self.model, kinds=tuple(kinds), tile_px=tile_px)

    def detect_batch(self, images, *, kinds, tile_px=TILE_PX):
        from ._onnx_detect import detect_onnx_batch

        return detect_onnx_batch(images, self.model, kinds=tuple(kinds), batch=self.batch, tile_px=tile_px)

    def decide(self, prob_u8, cls):
        from ._core import decide_u8

        return decide_u8(prob_u8, self.model.thresholds_u8[cls], self.model.min_area_px[cls])[0]

    def model_doc(self, kinds):
        m = self.model
        doc = {"file": str(self.model_path), "engine": self.name, "version": self.version,
               "operating_points": {k: round(m.thresholds_u8[k] / 255, 4) for k in kinds},
               "min_area_px": {k: m.min_area_px[k] for k in kinds}}
        sm = getattr(m, "states_model", None) or getattr(getattr(m, "onnx", None), "states_model", None)  # onnx or fused
        if sm is not None and "corrosion" in kinds:
            doc["condition_states"] = {"file": str(sm.path), "version": sm.version}
        return doc


class _Fused(_Onnx):
    """Both engines' maps mixed per class; decided like the onnx engine (thresholds, speckle)."""

    @property
    def classes(self):
        return tuple(self.model.weights)

    def detect(self, image, *, kinds, tile_px=TILE_PX):
        from ._fused import detect_fused

        return detect_fused(image, self.model, kinds=tuple(kinds), tile_px=tile_px)

    def detect_batch(self, images, *, kinds, tile_px=TILE_PX):
        return [self.detect(im, kinds=kinds, tile_px=tile_px) for im in images]

    def model_doc(self, kinds):
        m = self.model
        return {**super().model_doc(kinds),
                "engines": {"saliency": m.saliency.version, "onnx": m.onnx.version},
                "weights_saliency": {k: m.weights[k] for k in kinds}}


def _need_onnxruntime(engine: str) -> None:
    try:
        import onnxruntime  # noqa: F401
    except ImportError as err:
        what = "not installed" if isinstance(err, ModuleNotFoundError) else \
            f"cannot be loaded ({str(err).strip().splitlines()[0][:120] if str(err).strip() else type(err).__name__})"
        raise InputError("onnxruntime", what, f"the {engine} engine needs it: pip install onnxruntime "
                         "(a dependency of inspect-pipe), or use --engine saliency") from None


def _check_suffix(engine: str, path: Path) -> None:
    """A model file of another engine's kind, named as such (``detect --model my.npz`` without
    ``--engine saliency`` now that the default is onnx)."""
    suf = path.suffix.lower()
    for other, s in SUFFIX.items():
        if other != engine and suf == s:
            article = "an" if other[0] in "aeiou" else "a"
            if not path.is_file():
                raise InputError(path, "not found", f"a {s} file is {article} {other} engine model: add --engine {other} and give an existing file")
            raise InputError(path, f"{article} {other} engine model ({s}), not one for --engine {engine}", f"add --engine {other}")


def default_path(engine: str) -> Path:
    """The shipped model file of ``engine``."""
    from . import default_model_path
    from ._fused import default_fused_path
    from ._onnx_detect import default_onnx_path

    return {"saliency": default_model_path, "onnx": default_onnx_path, "fused": default_fused_path}[engine]()


@contextlib.contextmanager
def _quiet():
    """stdout and stderr silenced, Python's and the C++ runtime's (file descriptors 1 and 2)."""
    from inspect_pipe.importer._logs import _silenced

    with _silenced():
        yield


def load_engine(engine: str, model: str | Path | None = None, *, threads: int = 1) -> DetectorEngine:
    """Load ``engine`` with its model file ``model`` (default: the shipped one; for ``fused`` the
    parameter .json, with the shipped saliency and onnx models). ``threads``: onnxruntime
    intra-op threads (0: its default, every core). Raises InputError (one line) for an unknown
    engine, a missing onnxruntime, or a missing, damaged or mismatched model file."""
    if engine not in ENGINES:
        raise InputError("--engine", f"{engine!r} unknown", f"one of {', '.join(ENGINES)}")
    path = Path(model) if model else default_path(engine)
    _check_suffix(engine, path)
    if engine == "saliency":
        from ._model import load_model

        if not path.is_file():
            raise InputError(path, "model file not found" if not path.exists() else "is a directory, not a model file",
                             "train one with 'inspect-pipe detect train'")
        try:
            return _Saliency(engine, path, load_model(path), tile_multiple=64)
        except ValueError as err:
            raise InputError(path, str(err)) from None
    _need_onnxruntime(engine)
    if engine == "onnx":
        from ._onnx_detect import MULTIPLE_OF, condition_state_onnx_path, load_onnx_model, with_condition_states

        try:
            # onnxruntime prints a banner ("EP Error ...") to stdout and its C++ log lines to
            # stderr when a file is damaged: the user sees the one line below instead
            with _quiet():
                model_ = load_onnx_model(path, threads=threads)
        except ValueError as err:
            raise InputError(path, str(err), "use --engine saliency, or train one with "
                             "'inspect-pipe detect train --engine onnx'") from None
        try:  # the corrosion it decides gets the states network's (v6's) states; v6 itself keeps its own head
            with _quiet():
                model_ = with_condition_states(model_, threads=threads)
        except ValueError as err:
            raise InputError(condition_state_onnx_path(), str(err), "reinstall inspect-pipe (a shipped model "
                             "file is damaged), or use --engine saliency") from None
        return _Onnx(engine, path, model_, tile_multiple=MULTIPLE_OF, batch=4)
    from ._fused import load_fused_model

    try:
        with _quiet():  # onnxruntime's banner and log lines, as above
            model_ = load_fused_model(path, threads=threads)
        return _Fused(engine, path, model_, tile_multiple=64, batch=1)
    except ValueError as err:
        raise InputError(path, str(err), "use --engine saliency or --engine onnx") from None
