"""``inspect-pipe detect``: defect probability maps, masks and regions; ``detect train``.

``inspect-pipe detect INPUT -o OUT`` is shorthand for ``inspect-pipe detect run INPUT -o OUT``:
the group routes anything that is not a sub-command name to ``run`` (click groups cannot have
a positional argument of their own in front of sub-commands).
"""

from __future__ import annotations

import json
from enum import Enum
from pathlib import Path
from typing import Annotated, Optional

import cv2
import numpy as np
import typer
from typer.core import TyperGroup

from cli._common import one_line_errors
from inspect_pipe.errors import InputError

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
        "INPUT alone is short for 'detect run INPUT'.\n\nExamples:\n\n"
        "  inspect-pipe detect wall.jpg -o out/det\n\n"
        "  inspect-pipe detect sweep_frames/ -o out/det --kind crack\n\n"
        "  inspect-pipe detect out/mosaic -o out/det          (a mosaic output folder)\n\n"
        "  inspect-pipe detect train ../shared/data/defects -o my_model.npz"
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


class Engine(str, Enum):
    saliency = "saliency"
    onnx = "onnx"
    fused = "fused"


class Kind(str, Enum):
    all = "all"
    corrosion = "corrosion"
    crack = "crack"
    surface = "surface"


def _kinds(kind: Kind) -> tuple[str, ...]:
    from inspect_pipe.saliency_defects import KINDS

    return KINDS if kind is Kind.all else (kind.value,)


def list_inputs(inp: Path) -> list[Path]:
    """Images to process: INPUT itself, the mosaic of a mosaic output folder, or a folder's images."""
    if not inp.exists():
        raise InputError(inp, "not found")
    if inp.is_file():
        return [inp]
    if (inp / "mosaic.json").exists() and (inp / "mosaic.png").exists():
        return [inp / "mosaic.png"]
    files = sorted(p for p in inp.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTS)
    if not files:  # a sweep may keep its frames one level down
        files = sorted(
            p for d in sorted(inp.iterdir()) if d.is_dir()
            for p in d.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTS
        )
    if not files:
        raise InputError(inp, "no images in folder", f"expected {', '.join(IMAGE_EXTS)} files")
    return files


def read_image(path: Path) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """(8-bit BGR or grey image, validity mask from an alpha channel or None). Raises InputError."""
    try:
        if path.stat().st_size == 0:
            raise InputError(path, "empty file")
    except OSError as err:
        raise InputError(path, f"cannot read ({err.strerror})") from None
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise InputError(path, "unreadable or empty image")
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


def _write_png(path: Path, img: np.ndarray) -> None:
    if not cv2.imwrite(str(path), img):
        raise InputError(path, "cannot write output")


def _name_for(path: Path, used: set[str]) -> str:
    name = path.stem
    k = 2
    while name in used:  # a.jpg and a.png in one folder
        name = f"{path.stem}_{k}"
        k += 1
    used.add(name)
    return name


class _Outputs:
    """The outputs every engine writes: ``NAME.prob.png``, ``NAME.mask.png`` per image and one
    ``defects.json``; failed images are recorded and reported after the others are written."""

    def __init__(self, out: Path) -> None:
        self.out = out
        out.mkdir(parents=True, exist_ok=True)
        self.images: list[dict] = []
        self.regions: list[dict] = []
        self.errors: list[dict] = []
        self._used: set[str] = set()

    def name_for(self, path: Path) -> str:
        return _name_for(path, self._used)

    def fail(self, path: Path, err: InputError) -> None:
        self.errors.append({"file": str(path), "problem": err.problem + (f" ({err.hint})" if err.hint else "")})
        typer.echo(f"error: {err}", err=True)

    def add(self, path: Path, name: str, img: np.ndarray, valid: Optional[np.ndarray], det) -> None:
        prob, mask = det.prob, det.mask
        if valid is not None:  # transparent pixels of a mosaic are not wall
            prob = np.where(valid, prob, 0).astype(np.uint8)
            mask = mask & valid
        _write_png(self.out / f"{name}.prob.png", prob)
        _write_png(self.out / f"{name}.mask.png", mask.astype(np.uint8) * 255)
        kept = [r for r in det.regions if valid is None or valid[r.polygon_px[0][1], r.polygon_px[0][0]]]
        for r in kept:
            self.regions.append({"id": len(self.regions) + 1, "image": name, "file": str(path), **r.to_json()})
        self.images.append({
            "name": name, "file": str(path), "width": int(img.shape[1]), "height": int(img.shape[0]),
            "prob": f"{name}.prob.png", "mask": f"{name}.mask.png", "n_regions": len(kept),
            "defect_fraction": round(float(mask.mean()), 6),
        })
        typer.echo(f"{name}: {len(kept)} regions, {100 * mask.mean():.2f} % defect pixels")

    def finish(self, model_doc: dict, kinds: tuple[str, ...]) -> None:
        doc = {"format": DEFECTS_FORMAT, "model": model_doc, "kinds": list(kinds),
               "images": self.images, "regions": self.regions, "errors": self.errors}
        (self.out / "defects.json").write_text(json.dumps(doc, indent=1))
        if self.errors:
            first = self.errors[0]
            more = f"; {len(self.errors) - 1} more failed" if len(self.errors) > 1 else ""
            raise InputError(first["file"], first["problem"] + more, f"{len(self.images)} other images written to {self.out}")


def _detect_each(files: list[Path], outs: _Outputs, detect_one) -> None:
    """One image at a time: read, detect (``detect_one(img)``), write; errors recorded."""
    for path in files:
        name = outs.name_for(path)
        try:
            img, valid = read_image(path)
            try:
                det = detect_one(img)
            except ValueError as err:
                raise InputError(path, str(err)) from None
        except InputError as err:
            outs.fail(path, err)
            continue
        outs.add(path, name, img, valid, det)


@app.command("run")
@one_line_errors
def run(
    input: Annotated[Path, typer.Argument(help="An image, a folder of images, or a mosaic output folder.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder.")],
    kind: Annotated[Kind, typer.Option("--kind", help="Defect classes: all = corrosion + crack.")] = Kind.all,
    model: Annotated[Optional[Path], typer.Option("--model", help="Model file (default: the shipped one).")] = None,
    tile_px: Annotated[int, typer.Option("--tile-px", help="Tile size for large images (multiple of 64).", min=256)] = 768,
    engine: Annotated[Engine, typer.Option("--engine", help="saliency: Bayes on saliency features (default); onnx: the learned network; fused: a per-class weighted mean of both (--model: its parameter .json).")] = Engine.saliency,
) -> None:
    """Write OUT/NAME.prob.png (0..255 = P(defect)), OUT/NAME.mask.png (0/255) and OUT/defects.json.

    Examples: inspect-pipe detect wall.jpg -o out/det ; inspect-pipe detect frames/ -o out/det --kind crack ;
    inspect-pipe detect frames/ -o out/det --engine onnx ; inspect-pipe detect frames/ -o out/det --engine fused
    """
    import inspect_pipe.saliency_defects as sd

    if engine is Engine.onnx:
        return _run_onnx(input, out, kind, model, tile_px)
    if engine is Engine.fused:
        return _run_fused(input, out, kind, model, tile_px)
    if tile_px % 64:
        raise InputError("--tile-px", f"{tile_px} is not a multiple of 64")
    model_path = model or sd.default_model_path()
    if not model_path.exists():
        raise InputError(model_path, "model file not found", "train one with 'inspect-pipe detect train'")
    try:
        mdl = sd.load_model(model_path)
    except ValueError as err:
        raise InputError(model_path, str(err)) from None
    kinds = _kinds(kind)
    for k in kinds:
        if k not in mdl.classes:
            raise InputError(model_path, f"model has no class {k!r}", f"has {', '.join(mdl.classes)}")
    files = list_inputs(input)  # bad input fails before anything is created
    outs = _Outputs(out)
    _detect_each(files, outs, lambda img: sd.detect(img, mdl, kinds=kinds, tile_px=tile_px))
    outs.finish({"file": str(model_path), "version": mdl.version,
                 "operating_points": {k: mdl.classes[k].threshold for k in kinds},
                 "min_area_px": {k: mdl.classes[k].min_area_px for k in kinds}}, kinds)


def _run_onnx(input: Path, out: Path, kind: Kind, model: Optional[Path], tile_px: int) -> None:
    """``detect --engine onnx``: same outputs, the learned network on onnxruntime; a sweep's
    equal-size frames run in batches."""
    from inspect_pipe.saliency_defects import _onnx_detect as od

    if tile_px % od.MULTIPLE_OF:
        raise InputError("--tile-px", f"{tile_px} is not a multiple of {od.MULTIPLE_OF}")
    model_path = model or od.default_onnx_path()
    try:
        mdl = od.load_onnx_model(model_path)
    except ValueError as err:
        raise InputError(model_path, str(err), "use --engine saliency, or train one with 'inspect-pipe detect train --engine onnx'") from None
    kinds = _kinds(kind)
    for k in kinds:
        if k not in mdl.classes:
            raise InputError(model_path, f"model has no class {k!r}", f"has {', '.join(mdl.classes)}")
    files = list_inputs(input)
    outs = _Outputs(out)
    chunk = 4
    for start in range(0, len(files), chunk):
        ready = []  # (path, name, img, valid)
        for path in files[start:start + chunk]:
            name = outs.name_for(path)
            try:
                img, valid = read_image(path)
                od._check(img)
            except InputError as err:
                outs.fail(path, err)
                continue
            except ValueError as err:
                outs.fail(path, InputError(path, str(err)))
                continue
            ready.append((path, name, img, valid))
        if ready:
            dets = od.detect_onnx_batch([r[2] for r in ready], mdl, kinds=kinds, tile_px=tile_px)
            for (path, name, img, valid), det in zip(ready, dets):
                outs.add(path, name, img, valid, det)
    outs.finish({"file": str(model_path), "engine": "onnx", "version": mdl.version,
                 "operating_points": {k: round(mdl.thresholds_u8[k] / 255, 4) for k in kinds},
                 "min_area_px": {k: mdl.min_area_px[k] for k in kinds}}, kinds)


def _run_fused(input: Path, out: Path, kind: Kind, model: Optional[Path], tile_px: int) -> None:
    """``detect --engine fused``: both engines' maps, mixed per class with the weights and
    thresholds fitted on the validation images (``models/fused_v1.json``)."""
    from inspect_pipe.saliency_defects import _fused as fu

    if tile_px % 64:
        raise InputError("--tile-px", f"{tile_px} is not a multiple of 64")
    params_path = model or fu.default_fused_path()
    try:
        mdl = fu.load_fused_model(params_path)
    except ValueError as err:
        raise InputError(params_path, str(err), "use --engine saliency or --engine onnx") from None
    kinds = _kinds(kind)
    for k in kinds:
        if k not in mdl.weights:
            raise InputError(params_path, f"fused parameters have no class {k!r}", f"have {', '.join(mdl.weights)}")
    files = list_inputs(input)  # bad input fails before anything is created
    outs = _Outputs(out)
    _detect_each(files, outs, lambda img: fu.detect_fused(img, mdl, kinds=kinds, tile_px=tile_px))
    outs.finish({"file": str(params_path), "engine": "fused", "version": mdl.version,
                 "engines": {"saliency": mdl.saliency.version, "onnx": mdl.onnx.version},
                 "weights_saliency": {k: mdl.weights[k] for k in kinds},
                 "operating_points": {k: round(mdl.thresholds_u8[k] / 255, 4) for k in kinds},
                 "min_area_px": {k: mdl.min_area_px[k] for k in kinds}}, kinds)


@app.command("train")
@one_line_errors
def train(
    data: Annotated[Path, typer.Argument(help="A defects folder holding crackforest/, vt_corrosion_cs/, sd_saliency_900/, or one labelled folder.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Model file to write (.npz).")],
    cls: Annotated[Optional[str], typer.Option("--class", help="Class name for a generic images/ + masks/ folder.")] = None,
    only: Annotated[str, typer.Option("--only", help="Comma-separated classes to train (default: all found).")] = "",
    version: Annotated[str, typer.Option("--version", help="Version recorded in the model.")] = "1",
    engine: Annotated[Engine, typer.Option("--engine", help="saliency: likelihood tables (.npz); onnx: the learned network (.onnx, needs the [train] extra).")] = Engine.saliency,
    time_budget_min: Annotated[float, typer.Option("--time-budget-min", help="onnx: stop training after this many minutes.", min=1)] = 85.0,
) -> None:
    """Learn the likelihood tables from labelled images (train part of the documented split only).

    Examples: inspect-pipe detect train ../shared/data/defects -o inspect_pipe/saliency_defects/models/defects_v1.npz ;
    inspect-pipe detect train ../shared/data/defects --engine onnx -o inspect_pipe/saliency_defects/models/defects_unet_v1.onnx
    """
    import inspect_pipe.saliency_defects as sd

    if engine is Engine.onnx:
        return _train_onnx(data, out, version, time_budget_min)
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


def _train_onnx(data: Path, out: Path, version: str, time_budget_min: float) -> None:
    try:
        import torch  # noqa: F401
    except ImportError:
        raise InputError("torch", "not installed", "pip install -e '.[train]'") from None
    from inspect_pipe.saliency_defects._onnx_train import (
        SET_OF_CLASS,
        OnnxTrainConfig,
        export_onnx,
    )
    from inspect_pipe.saliency_defects._onnx_train import train as train_net

    if not data.is_dir():
        raise InputError(data, "not a folder")
    missing = [s for s in SET_OF_CLASS.values() if not (data / s).is_dir()]
    if missing:
        raise InputError(data, f"missing {', '.join(missing)}", "the onnx engine trains on all three shared sets")
    ckpt = out.with_suffix(".pt")
    train_net(data, ckpt, OnnxTrainConfig(time_budget_s=60 * time_budget_min), log=typer.echo)
    export_onnx(ckpt, out, version=version, log=typer.echo)
