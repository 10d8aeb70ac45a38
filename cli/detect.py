"""``inspect-pipe detect``: defect probability maps, masks and regions; ``detect train``.

``inspect-pipe detect INPUT -o OUT`` is shorthand for ``inspect-pipe detect run INPUT -o OUT``:
the group routes anything that is not a sub-command name to ``run`` (click groups cannot have
a positional argument of their own in front of sub-commands).
"""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Annotated, Optional

import cv2
import numpy as np
import typer
from typer.core import TyperGroup

from cli._common import StageProgress, one_line_errors
from inspect_pipe._images import imread_checked, truncation
from inspect_pipe.errors import InputError
from inspect_pipe.saliency_defects._core import TILE_PX
from inspect_pipe.saliency_defects._detect import SEVERITY_STATES
from inspect_pipe.saliency_defects._engines import DEFAULT_ENGINE, ENGINES

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
DEFECTS_FORMAT = "inspect_pipe.defects/1"


class _DefaultToRun(TyperGroup):
    """A group whose first argument, when it is not a sub-command, goes to ``run``."""

    def parse_args(self, ctx, args: list[str]) -> list[str]:
        help_names = set(self.get_help_option_names(ctx))
        if args and args[0] not in self.commands and args[0] not in help_names:
            args = ["run", *args]
        return super().parse_args(ctx, args)


app = typer.Typer(
    cls=_DefaultToRun,
    help=(
        "Detect corrosion and cracks: per-pixel defect probability, mask and regions.\n\n"
        "INPUT alone is short for 'detect run INPUT'. Engines (--engine): onnx, the learned network "
        "(default); saliency, the paper's method; fused, a mix of both.\n\nExamples:\n\n"
        "  inspect-pipe detect wall.jpg -o out/det\n\n"
        "  inspect-pipe detect sweep_frames/ -o out/det --kind crack\n\n"
        "  inspect-pipe detect wall.jpg -o out/det --engine saliency\n\n"
        "  inspect-pipe detect out/mosaic -o out/det          (a mosaic output folder)\n\n"
        "  inspect-pipe detect train ../shared/data/defects -o my_model.npz"
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


Engine = Enum("Engine", {e: e for e in ENGINES}, type=str)
DEFAULT = Engine(DEFAULT_ENGINE)  # of detect, run and demo
ENGINE_HELP = ("onnx: the learned network on onnxruntime (the default, chosen on validation images; also gives "
               "corrosion condition states); saliency: Bayes on saliency features, the paper's explainable method, "
               "needs no onnxruntime, no condition states; fused: a per-class weighted mean of both (about twice "
               "the time).")


class Kind(str, Enum):
    all = "all"
    corrosion = "corrosion"
    crack = "crack"
    surface = "surface"


def _kinds(kind: Kind) -> tuple[str, ...]:
    from inspect_pipe.saliency_defects import KINDS

    return KINDS if kind is Kind.all else (kind.value,)


#: What detect writes beside each image (NAME.prob.png ...): never an input of a later run in the same folder.
OUTPUT_SUFFIXES = (".prob.png", ".mask.png", ".severity.png")


def _is_input(p: Path) -> bool:
    return p.is_file() and p.suffix.lower() in IMAGE_EXTS and not p.name.lower().endswith(OUTPUT_SUFFIXES)


def list_inputs(inp: Path) -> list[Path]:
    """Images to process: INPUT itself, the mosaic of a mosaic output folder, or a folder's images."""
    if not inp.exists():
        raise InputError(inp, "not found")
    if inp.is_file():
        return [inp]
    if (inp / "mosaic.json").exists() and (inp / "mosaic.png").exists():
        return [inp / "mosaic.png"]
    files = sorted(p for p in inp.iterdir() if _is_input(p))
    if not files:  # a sweep may keep its frames one level down
        files = sorted(p for d in sorted(inp.iterdir()) if d.is_dir() for p in d.iterdir() if _is_input(p))
    if not files:
        raise InputError(inp, "no images in folder", f"expected {', '.join(IMAGE_EXTS)} files")
    return files


def read_image(path: Path) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """(8-bit BGR or grey image, validity mask from an alpha channel or None). Raises InputError."""
    why = truncation(path)
    if why:
        raise InputError(path, why, "copy the image again" if why.startswith("truncated") else "give an image file")
    try:  # listening to the decoder: libjpeg decodes damaged data and only prints that it did
        img, said = imread_checked(path, cv2.IMREAD_UNCHANGED)
    except cv2.error as err:  # e.g. a header claiming more pixels than OpenCV decodes (2**30)
        raise InputError(path, f"unreadable image ({_cv_reason(err)})", "give an image of at most 1 gigapixel") from None
    if img is None or img.size == 0:
        raise InputError(path, "unreadable or empty image" + (f" ({said})" if said else ""))
    if said:
        raise InputError(path, f"damaged image data ({said})", "copy the image again from the camera or card")
    if img.dtype != np.uint8:
        raise InputError(path, f"{img.dtype} pixels are not supported", "convert to 8-bit")
    valid = None
    if img.ndim == 3 and img.shape[2] == 4:
        valid = img[:, :, 3] > 0
        img = np.ascontiguousarray(img[:, :, :3])
    elif img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    elif img.ndim == 3 and img.shape[2] != 3:
        raise InputError(path, f"{img.shape[2]}-channel image is not supported")
    return img, valid


def _cv_reason(err: Exception) -> str:
    """OpenCV's own reason, one short phrase, from its multi-line error text."""
    text = str(err)
    if "CV_IO_MAX_IMAGE_PIXELS" in text:
        return "its header claims more pixels than OpenCV decodes, 2**30"
    for line in text.splitlines():
        if "error:" in line:
            return line.split("error:", 1)[1].strip()[:120]
    return (text.strip().splitlines() or [type(err).__name__])[-1][:120]


def _write_png(path: Path, img: np.ndarray) -> None:
    """Atomic write (a reader sees the whole file or none); one line when it fails."""
    from inspect_pipe._files import write_png

    try:
        write_png(path, img)
    except OSError as err:
        raise InputError(path, f"cannot write output ({err.strerror or err})") from None


def _name_for(path: Path, used: set[str]) -> str:
    name = path.stem
    k = 2
    while name in used:  # a.jpg and a.png in one folder
        name = f"{path.stem}_{k}"
        k += 1
    used.add(name)
    return name


class _Outputs:
    """The outputs every engine writes: ``NAME.prob.png``, ``NAME.mask.png`` (and, for corrosion
    with an engine that has condition states, ``NAME.severity.png``) per image and one
    ``defects.json``; failed images are recorded and reported in one line after the others are
    written. When no image could be processed nothing is written (no folder, no defects.json).
    Each failure is one line: of a single input, only the final error; of several inputs, one
    line per failed image as it happens and a final count."""

    def __init__(self, out: Path, n_inputs: int = 1) -> None:
        self.out = out
        self.n_inputs = n_inputs
        self.images: list[dict] = []
        self.regions: list[dict] = []
        self.errors: list[dict] = []
        self._used: set[str] = set()
        self._written: list[Path] = []  # this run's files: removed again if defects.json cannot be written

    def _png(self, name: str, img: np.ndarray, done: list[Path]) -> None:
        path = self.out / name
        _write_png(path, img)
        done.append(path)

    def name_for(self, path: Path) -> str:
        return _name_for(path, self._used)

    def fail(self, path: Path, err: InputError) -> None:
        self.errors.append({"file": str(path), "problem": err.problem + (f" ({err.hint})" if err.hint else "")})
        if self.n_inputs > 1:
            typer.echo(f"error: {err}", err=True)

    def add(self, path: Path, name: str, img: np.ndarray, valid: Optional[np.ndarray], det) -> None:
        """Write one image's maps; a write that fails removes that image's other maps and raises
        InputError (the caller records the image as failed and goes on)."""
        done: list[Path] = []
        try:
            self._add(path, name, img, valid, det, done)
        except InputError:
            for p in done:
                p.unlink(missing_ok=True)
            raise
        self._written += done

    def _add(self, path: Path, name: str, img: np.ndarray, valid: Optional[np.ndarray], det, done: list[Path]) -> None:
        prob, mask = det.prob, det.mask
        if valid is not None:  # transparent pixels of a mosaic are not wall
            prob = np.where(valid, prob, 0).astype(np.uint8)
            mask = mask & valid
        self._png(f"{name}.prob.png", prob, done)
        self._png(f"{name}.mask.png", mask.astype(np.uint8) * 255, done)
        rec = {}
        sev = getattr(det, "severity", None)
        if sev is not None:  # 0 none, 1 fair, 2 poor, 3 severe (decided corrosion pixels only)
            if valid is not None:
                sev = np.where(valid, sev, 0).astype(np.uint8)
            self._png(f"{name}.severity.png", sev, done)
            n = np.bincount(sev.ravel(), minlength=4)[1:4]
            rec = {"severity": f"{name}.severity.png",
                   "severity_fractions": {k: round(float(v) / sev.size, 6) for k, v in zip(SEVERITY_STATES, n)}}
        kept = [r for r in det.regions if valid is None or valid[r.polygon_px[0][1], r.polygon_px[0][0]]]
        for r in kept:
            self.regions.append({"id": len(self.regions) + 1, "image": name, "file": str(path), **r.to_json()})
        self.images.append({
            "name": name, "file": str(path), "width": int(img.shape[1]), "height": int(img.shape[0]),
            "prob": f"{name}.prob.png", "mask": f"{name}.mask.png", **rec, "n_regions": len(kept),
            "defect_fraction": round(float(mask.mean()), 6),
        })
        typer.echo(f"{name}: {len(kept)} regions, {100 * mask.mean():.2f} % defect pixels")

    def finish(self, model_doc: dict, kinds: tuple[str, ...]) -> None:
        if self.errors and not self.images:  # nothing usable: nothing written
            if len(self.errors) == 1:
                first = self.errors[0]
                raise InputError(first["file"], first["problem"], "nothing written")
            raise InputError(self.out, f"all {len(self.errors)} images failed (listed above)", "nothing written")
        doc = {"format": DEFECTS_FORMAT, "model": model_doc, "kinds": list(kinds),
               "images": self.images, "regions": self.regions, "errors": self.errors}
        from inspect_pipe._files import write_json

        try:
            write_json(self.out / "defects.json", doc)
        except OSError as err:  # the maps without their register are of no use: none is left behind
            for p in self._written:
                p.unlink(missing_ok=True)
            raise InputError(self.out / "defects.json", f"cannot write it ({err.strerror or err})",
                             "give a writable output folder; nothing written") from None
        if self.errors:
            raise InputError(self.out, f"{len(self.errors)} of {len(self.errors) + len(self.images)} images failed "
                             "(listed above and in defects.json)", f"{len(self.images)} other images written")


def _detect_each(files: list[Path], outs: _Outputs, eng, kinds: tuple[str, ...], tile_px: int, progress=None) -> None:
    """Read, detect, write, ``eng.batch`` images at a time (a sweep's equal-size frames share one
    network call); an image that cannot be read or detected is recorded and the others go on.
    ``progress(stage, done, total)`` after each batch."""
    for start in range(0, len(files), eng.batch):
        if progress is not None:
            progress("detect", start, len(files))
        ready = []  # (path, name, img, valid)
        for path in files[start:start + eng.batch]:
            name = outs.name_for(path)
            try:
                img, valid = read_image(path)
                eng.check_image(img)
            except InputError as err:
                outs.fail(path, err)
                continue
            except ValueError as err:
                outs.fail(path, InputError(path, str(err)))
                continue
            ready.append((path, name, img, valid))
        if not ready:
            continue
        try:
            dets = eng.detect_batch([r[2] for r in ready], kinds=kinds, tile_px=tile_px)
        except ValueError as err:  # batch of one but for the network, whose images were checked above
            for path, *_ in ready:
                outs.fail(path, InputError(path, str(err)))
            continue
        for (path, name, img, valid), det in zip(ready, dets):
            try:
                outs.add(path, name, img, valid, det)
            except InputError as err:  # that image's maps could not be written: it failed, the others go on
                outs.fail(path, err)


@app.command("run")
@one_line_errors
def run(
    input: Annotated[Path, typer.Argument(help="An image, a folder of images, or a mosaic output folder.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder.")],
    kind: Annotated[Kind, typer.Option("--kind", help="Defect classes: all = corrosion + crack.")] = Kind.all,
    model: Annotated[Optional[Path], typer.Option("--model", help="Model file of the engine (default: the shipped one), or the name of a shipped one: .onnx (onnx; the shipped default, defects_unet_v5.onnx, decides and gives condition states with its own head; defects_unet_v1.onnx and any other network without a head borrow v5's states), .npz (saliency) or .json (fused: its parameters).")] = None,
    tile_px: Annotated[int, typer.Option("--tile-px", help="Tile size for large images (multiple of 64; onnx: of 16).", min=256)] = TILE_PX,
    engine: Annotated[Engine, typer.Option("--engine", help=ENGINE_HELP)] = DEFAULT,
) -> None:
    """Write OUT/NAME.prob.png (0..255 = P(defect)), OUT/NAME.mask.png (0/255) and OUT/defects.json;
    with corrosion (--kind corrosion or all) and the onnx or fused engine also OUT/NAME.severity.png
    (condition state: 0 none, 1 fair, 2 poor, 3 severe) and each corrosion region's "severity".

    Examples:

      inspect-pipe detect wall.jpg -o out/det

      inspect-pipe detect frames/ -o out/det --kind crack

      inspect-pipe detect frames/ -o out/det --engine saliency

      inspect-pipe detect frames/ -o out/det --engine fused
    """
    from inspect_pipe.saliency_defects import load_engine

    from cli.run import shipped_or_given

    eng = load_engine(engine.value, shipped_or_given(model) if model else None)  # one line and exit 2 for a missing or bad model
    eng.check_tile(tile_px)
    kinds = _kinds(kind)
    eng.check_kinds(kinds)
    files = list_inputs(input)  # bad input fails before anything is created
    if out.exists() and not out.is_dir():
        raise InputError(out, "exists and is not a folder", "give a new or an existing output folder")
    outs = _Outputs(out, len(files))
    bar = StageProgress()  # rich bars on a terminal; none under -q
    try:
        _detect_each(files, outs, eng, kinds, tile_px, progress=bar)
        bar("detect", len(files), len(files))
    finally:
        bar.close()
    outs.finish(eng.model_doc(kinds), kinds)


@app.command("train")
@one_line_errors
def train(
    data: Annotated[Path, typer.Argument(help="A defects folder holding crackforest/, vt_corrosion_cs/, sd_saliency_900/, or one labelled folder.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Model file to write: .npz (saliency tables) or .onnx (--engine onnx).")],
    cls: Annotated[Optional[str], typer.Option("--class", help="Class name for a generic images/ + masks/ folder.")] = None,
    only: Annotated[str, typer.Option("--only", help="Comma-separated classes to train (default: all found).")] = "",
    version: Annotated[Optional[str], typer.Option("--version", help="Version recorded in the model (default: the shipped one's, saliency tables 1, the onnx network 5).")] = None,
    engine: Annotated[Engine, typer.Option("--engine", help="saliency: likelihood tables (.npz), the default here (minutes); onnx: the learned network (.onnx, needs the [train] extra; about 28 min of one CPU core for the decider's 2240 steps, 55 min for v6's 4480, plus a 3-min export).")] = Engine.saliency,
    time_budget_min: Annotated[float, typer.Option("--time-budget-min", help="onnx: training stops after this many minutes of wall time (its schedule ends at the step limit or here, whichever comes first).", min=1)] = 85.0,
    max_steps: Annotated[Optional[int], typer.Option("--max-steps", help="onnx: the step limit of the schedule (default: the decider's recipe, 2240; the condition-state network v6: 4480).", min=1)] = None,
) -> None:
    """Learn a detector from labelled images (train part of the documented split only): the saliency engine's likelihood tables (.npz), or with --engine onnx the learned network (.onnx).

    Examples: inspect-pipe detect train ../shared/data/defects -o inspect_pipe/saliency_defects/models/defects_v1.npz ;
    inspect-pipe detect train ../shared/data/defects --engine onnx -o inspect_pipe/saliency_defects/models/defects_unet_v5.onnx --version 5 ;
    inspect-pipe detect train ../shared/data/defects --engine onnx -o inspect_pipe/saliency_defects/models/defects_unet_v6.onnx --version 6 --max-steps 4480
    """
    import inspect_pipe.saliency_defects as sd

    if out.is_dir():  # checked before an hour of training, not after it
        raise InputError(str(out), "is a directory", "give the model file to write, e.g. -o models/defects.onnx")
    want = ".onnx" if engine is Engine.onnx else ".npz"
    if engine is not Engine.fused and out.suffix.lower() != want:  # checked before an hour of training, not after it
        raise InputError(str(out), f"--engine {engine.value} writes a {want} file", f"give -o NAME{want}")
    parent = next((p for p in out.parents if p.exists()), None)
    if parent is not None and not parent.is_dir():
        raise InputError(str(out), f"{parent} is a file, not a folder", "give a path in a folder")
    if engine is Engine.onnx:
        return _train_onnx(data, out, version or "5", time_budget_min, max_steps)
    version = version or "1"
    if max_steps is not None:
        raise InputError("--max-steps", "only applies to --engine onnx", "drop it, or add --engine onnx")
    if engine is Engine.fused:
        raise InputError("--engine fused", "has no training of its own",
                         "fit its weights with 'python -m inspect_pipe.saliency_defects._fused DATA -o PARAMS.json'")

    cv2.setNumThreads(1)
    if not data.is_dir():
        raise InputError(data, "not a folder")
    sources = {}
    if data.name in sd.SETS:
        sources[sd.SETS[data.name]] = (data.name, sd.labelled_set(data, split="train"))
    elif (data / "images").is_dir() and (data / "masks").is_dir():
        if not cls:
            raise InputError(data, "a generic labelled folder needs --class NAME")
        sources[cls] = (data.name, sd.generic_set(data, split="train"))
    else:
        for set_name, c in sd.SETS.items():
            if (data / set_name).is_dir():
                sources[c] = (set_name, sd.labelled_set(data / set_name, split="train"))
    if only:
        want = {w.strip() for w in only.split(",") if w.strip()}
        known = set(sd.SETS.values()) | ({cls} if cls else set())
        unknown = sorted(want - known)
        if unknown:
            raise InputError(f"--only {only}", f"unknown class {unknown[0]!r}", f"one or more of {', '.join(sorted(known))}")
        sources = {c: v for c, v in sources.items() if c in want}
    if not sources:
        raise InputError(data, "no labelled set found", f"expected one of {', '.join(sd.SETS)} or images/ + masks/")
    for c, (set_name, items) in sources.items():
        if not items:
            raise InputError(data, f"no labelled images for {c} in {set_name}")
    configs = {c: sd.ClassTrainConfig(cls=c) for c in sources if c not in sd.DEFAULT_CONFIGS}
    model = sd.train_model(sources, version=version, configs=configs, log=typer.echo)
    sd.save_model(model, out)
    typer.echo(f"wrote {out}")


def _train_onnx(data: Path, out: Path, version: str, time_budget_min: float, max_steps: int | None = None) -> None:
    import importlib.util

    from inspect_pipe.saliency_defects._onnx_train import ENCODERS, OnnxTrainConfig

    from inspect_pipe.saliency_defects._core import SET_OF_CLASS

    # the data first (a wrong folder is said before a missing package), then the wheels of the
    # shipped recipe's encoder (Lite1 since v4), not only the model code's
    if not data.is_dir():
        raise InputError(data, "not a folder")
    missing = [s for s in SET_OF_CLASS.values() if not (data / s).is_dir()]
    if missing:
        raise InputError(data, f"missing {', '.join(missing)}", "the onnx engine trains on all three shared sets")
    for pkg in ("torch", "onnx", *ENCODERS[OnnxTrainConfig().arch]["packages"]):
        if importlib.util.find_spec(pkg.replace("-", "_")) is None:
            raise InputError(pkg, "not installed", "pip install -e '.[train]'")
    from inspect_pipe.saliency_defects._onnx_train import (
        OnnxTrainConfig,
        export_model,
    )
    from inspect_pipe.saliency_defects._onnx_train import train as train_net

    ckpt = out.with_suffix(".pt")
    # the cosine schedule ends at max_steps or at the budget, whichever first
    cfg = OnnxTrainConfig(time_budget_s=60 * time_budget_min, total_time_budget_s=60 * (time_budget_min + 3),
                          **({"max_steps": max_steps} if max_steps is not None else {}))
    train_net(data, ckpt, cfg, log=typer.echo)
    export_model(ckpt, out, data, version=version, log=typer.echo)
