"""Train the learned defect segmentation network and export it to ONNX.

    nice -n 10 python tools/train_onnx.py ../shared/data/defects \
        -o inspect_pipe/saliency_defects/models/defects_unet_v1.onnx --ckpt bench/_work/onnx/unet.pt

Same as ``inspect-pipe detect train DATA --engine onnx -o MODEL.onnx``. ``--export-only`` exports
an existing checkpoint (e.g. of a run stopped early).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path


def main(argv=None) -> None:
    from inspect_pipe.saliency_defects._onnx_train import (
        OnnxTrainConfig,
        export_onnx,
        train,
    )

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", type=Path)
    ap.add_argument("-o", "--out", type=Path, required=True)
    ap.add_argument("--ckpt", type=Path, default=None, help="checkpoint (default: OUT with .pt)")
    ap.add_argument("--export-only", action="store_true")
    for f in dataclasses.fields(OnnxTrainConfig):
        if f.type in ("int", "float"):
            ap.add_argument("--" + f.name.replace("_", "-"), type=eval(f.type), default=f.default)
    a = ap.parse_args(argv)
    ckpt = a.ckpt or a.out.with_suffix(".pt")
    if not a.export_only:
        cfg = OnnxTrainConfig(**{f.name: getattr(a, f.name) for f in dataclasses.fields(OnnxTrainConfig)
                                 if hasattr(a, f.name)})
        ckpt.parent.mkdir(parents=True, exist_ok=True)
        train(a.data, ckpt, cfg, log=lambda s: print(s, flush=True))
    export_onnx(ckpt, a.out, log=lambda s: print(s, flush=True))


if __name__ == "__main__":
    main()
