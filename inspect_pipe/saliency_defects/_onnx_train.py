"""Training of the learned segmentation engine (PyTorch, CPU) and its ONNX export.

Only ``inspect-pipe detect train --engine onnx`` and ``tools/train_onnx.py`` import this module;
inference (``_onnx_detect``) needs onnxruntime only. Install with ``pip install -e .[train]``.

Network: a half-resolution U-Net (``build_net``: stride-2 stem, levels at 1/2, 1/4, 1/8, 1/16 of
widths 16-32-64-128, depthwise-separable blocks at 1/2 and 1/4, about 0.34 M parameters; the
sigmoid map comes out at 1/2 resolution and is up-sampled bilinearly, inside the training graph
and by the inference after export), RGB in, one map per class out (corrosion, crack, surface). Each data set labels one class only, so the loss of a sample is taken
on its own class's channel (the other channels are not supervised by that sample).

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

from ._datasets import SPLIT_RULE, labelled_set
from ._metrics import best_f, tolerance_counts
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
SET_OF_CLASS = {"corrosion": "vt_corrosion_cs", "crack": "crackforest", "surface": "sd_saliency_900"}


def is_val(set_name: str, stem: str) -> bool:
    return int(hashlib.sha1(f"val:{set_name}/{stem}".encode()).hexdigest(), 16) % 5 == 0


@dataclass(frozen=True)
class OnnxTrainConfig:
    seed: int = 0
    crop_px: int = 128
    per_class_batch: int = 4  # crops of each class per step
    max_steps: int = 24000  # about 60 min on one core of the 2-core development machine
    lr: float = 3e-3
    weight_decay: float = 1e-4
    val_every: int = 500
    patience: int = 6  # validations without improvement before stopping
    time_budget_s: float = 85 * 60  # the cosine schedule ends at max_steps or here, whichever first
    threads: int = 1  # one thread: the run is step-for-step reproducible and leaves a core free
    crack_centre_p: float = 0.6  # share of crack crops centred on a crack pixel
    widths: tuple[int, ...] = (16, 32, 64, 128)
    dw_levels: int = 2  # levels (from the 1/2-res one) with depthwise-separable blocks
    # phase 2: fine-tuning from phase 1's best checkpoint with more context for corrosion (larger
    # crops), a soft-F1 term on the corrosion channel and a lower lr; 0 steps: no phase 2
    ft_steps: int = 3000
    ft_crop_px: int = 256  # corrosion crops in phase 2 (crack, surface keep crop_px)
    ft_corrosion_batch: int = 4  # corrosion crops per step in phase 2 (crack, surface: per_class_batch)
    ft_lr: float = 5e-4
    ft_soft_f1: float = 1.0  # weight of (1 - soft F1 over the batch) on the corrosion channel
    ft_val_every: int = 250
    ft_time_budget_s: float = 30 * 60
    total_time_budget_s: float = 88 * 60  # both phases (phase 2 gets what phase 1 left, up to ft_time_budget_s)


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


# ----------------------------------------------------------------------------- data


@dataclass
class _Item:
    cls: str
    stem: str
    rgb: np.ndarray  # (H, W, 3) uint8
    gt: np.ndarray  # (H, W) bool
    pos: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int32))  # (n, 2) y, x of GT pixels


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
            if is_val(set_name, it.stem):
                va.append(x)
            else:
                x.pos = np.argwhere(x.gt).astype(np.int32)
                tr.append(x)
        train[c], val[c] = tr, va
        record[c] = {"set": set_name, "split_rule": SPLIT_RULE, "val_rule": VAL_RULE,
                     "n_train": len(tr), "n_val": len(va), "val_stems": [v.stem for v in va]}
    return train, val, record


def _crop(item: _Item, size: int, rng: np.random.Generator, centre_p: float) -> tuple[np.ndarray, np.ndarray]:
    h, w = item.gt.shape
    if h < size or w < size:  # pad small images by reflection
        py, px = max(0, size - h), max(0, size - w)
        rgb = cv2.copyMakeBorder(item.rgb, 0, py, 0, px, cv2.BORDER_REFLECT_101)
        gt = cv2.copyMakeBorder(item.gt.astype(np.uint8), 0, py, 0, px, cv2.BORDER_REFLECT_101).astype(bool)
        h, w = gt.shape
    else:
        rgb, gt = item.rgb, item.gt
    if len(item.pos) and rng.random() < centre_p:
        y, x = item.pos[rng.integers(len(item.pos))]
        y0 = int(np.clip(y - rng.integers(size), 0, h - size))
        x0 = int(np.clip(x - rng.integers(size), 0, w - size))
    else:
        y0, x0 = int(rng.integers(h - size + 1)), int(rng.integers(w - size + 1))
    return rgb[y0:y0 + size, x0:x0 + size], gt[y0:y0 + size, x0:x0 + size]


def _augment(rgb: np.ndarray, gt: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Flips, 90-degree turns, brightness / contrast / gamma; hue is kept (rust is a colour)."""
    k = int(rng.integers(4))
    rgb, gt = np.rot90(rgb, k), np.rot90(gt, k)
    if rng.random() < 0.5:
        rgb, gt = rgb[:, ::-1], gt[:, ::-1]
    x = rgb.astype(np.float32) / 255.0
    x = x ** float(np.exp(rng.normal(0, 0.2)))
    m = x.mean()
    x = (x - m) * float(rng.uniform(0.75, 1.3)) + m * float(rng.uniform(0.8, 1.2))
    x = x * rng.uniform(0.93, 1.07, size=3).astype(np.float32)  # white balance
    x = x + rng.normal(0, rng.uniform(0, 0.02), size=x.shape).astype(np.float32)
    return np.clip(x, 0, 1), np.ascontiguousarray(gt)


def _normalise(x01: np.ndarray) -> np.ndarray:
    """(H, W, 3) float RGB in [0, 1] -> (3, H, W) network input."""
    return ((x01 - np.asarray(INPUT_MEAN, np.float32)) / np.asarray(INPUT_STD, np.float32)).transpose(2, 0, 1)


def _batch(train: dict[str, list[_Item]], cfg: OnnxTrainConfig, rng: np.random.Generator,
           classes=CLASSES, crop_px: int | None = None, n: int | None = None):
    xs, ys, cs = [], [], []
    for ci, c in enumerate(CLASSES):
        if not train.get(c) or c not in classes:
            continue
        for _ in range(n or cfg.per_class_batch):
            it = train[c][int(rng.integers(len(train[c])))]
            rgb, gt = _crop(it, crop_px or cfg.crop_px, rng, cfg.crack_centre_p if c == "crack" else 0.3)
            x, g = _augment(rgb, gt, rng)
            if c == "crack":  # 1-px labels of a 2-px-tolerance protocol: learn a 3-px wide line
                g = cv2.dilate(g.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
            xs.append(_normalise(x))
            ys.append(g.astype(np.float32))
            cs.append(ci)
    return np.stack(xs), np.stack(ys), np.asarray(cs)


# ----------------------------------------------------------------------------- validation


def _predict(net, rgb: np.ndarray) -> np.ndarray:
    """(C, H, W) float probabilities for one whole image (reflect-padded to MULTIPLE_OF)."""
    import torch

    h, w = rgb.shape[:2]
    H, W = -(-h // MULTIPLE_OF) * MULTIPLE_OF, -(-w // MULTIPLE_OF) * MULTIPLE_OF
    x = cv2.copyMakeBorder(rgb, 0, H - h, 0, W - w, cv2.BORDER_REFLECT_101).astype(np.float32) / 255.0
    with torch.no_grad():
        p = net(torch.from_numpy(_normalise(x)[None]))[0].numpy()
    return p[:, :h, :w]


def validate(net, val: dict[str, list[_Item]]) -> dict[str, dict]:
    """Per class: best F over thresholds on the validation part (crack with the 2 px tolerance)
    and the threshold (0..255) achieving it."""
    net.eval()
    out = {}
    for ci, c in enumerate(CLASSES):
        if not val.get(c):
            continue
        counts = None
        for it in val[c]:
            p = _predict(net, it.rgb)[ci]
            k = tolerance_counts(p, it.gt, TOL_PX[c])
            counts = k if counts is None else counts + k
        f, t = best_f(counts)
        out[c] = {"F": round(f, 4), "threshold_u8": t}
    net.train()
    return out


# ----------------------------------------------------------------------------- training


def _optimise(opt, loss, loss_avg: float | None) -> float:
    """One optimiser step on ``loss``; returns the running mean of the loss for the log."""
    opt.zero_grad()
    loss.backward()
    opt.step()
    lv = loss.item()
    return lv if loss_avg is None else 0.98 * loss_avg + 0.02 * lv


def train(root: Path, ckpt: Path, cfg: OnnxTrainConfig = OnnxTrainConfig(), log: Callable[[str], None] = print) -> dict:
    """Train on ``root`` (a defects folder) and keep the best checkpoint at ``ckpt`` (.pt).
    Stops at max_steps, after ``patience`` validations without improvement, or at the time
    budget. Returns the best validation record."""
    import torch

    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    cv2.setNumThreads(1)
    rng = np.random.default_rng(cfg.seed)
    t0 = time.monotonic()
    train_items, val_items, record = load_parts(root)
    log("data: " + ", ".join(f"{c} {r['n_train']} train / {r['n_val']} val" for c, r in record.items())
        + f" ({time.monotonic() - t0:.0f} s)")
    net = build_net(cfg.widths, dw_levels=cfg.dw_levels)
    n_par = sum(p.numel() for p in net.parameters())
    log(f"net: {n_par} parameters")
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
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
            g["lr"] = lr_at(step)
        x, y, c = _batch(train_items, cfg, rng)
        loss_avg = _optimise(opt, _loss(net, x, y, c), loss_avg)
        step += 1
        if step % 50 == 0:
            log(f"step {step} loss {loss_avg:.4f} lr {lr_at(step):.2e} ({time.monotonic() - t0:.0f} s)")
        over_time = time.monotonic() - t0 > cfg.time_budget_s
        if step % cfg.val_every == 0 or step == cfg.max_steps or over_time:
            v = validate(net, val_items)
            score = float(np.mean([r["F"] for r in v.values()]))
            log(f"val step {step}: " + ", ".join(f"{k} F {r['F']:.3f} @ {r['threshold_u8']}" for k, r in v.items())
                + f" mean {score:.4f} ({time.monotonic() - t0:.0f} s)")
            if score > best_score:
                best_score, bad = score, 0
                best = {"step": step, "val": v, "mean_F": round(score, 4)}
                torch.save({"state": net.state_dict(), "best": best, "record": record, "config": asdict(cfg),
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
        f"({time.monotonic() - t0:.0f} s)")
    ck = torch.load(ckpt, weights_only=False)
    ck["stopped"] = {"step": step, "reason": reason, "wall_s": round(time.monotonic() - t0)}
    torch.save(ck, ckpt)
    if cfg.ft_steps > 0:  # phase 2 gets what is left of the whole budget, at most ft_time_budget_s
        left = cfg.total_time_budget_s - (time.monotonic() - t0)
        best = finetune(ckpt, cfg, items=(train_items, val_items), log=log, budget_s=max(60.0, left))
    return best


_POS_WEIGHT = {"corrosion": 1.0, "crack": 3.0, "surface": 1.0}


def _loss(net, x, y, c, soft_f1: float = 0.0):
    """BCE (crack positives weighted) + 0.5 soft Dice per sample, each sample on its own class's
    channel; with ``soft_f1`` > 0 the corrosion samples get BCE + soft_f1 * (1 - soft F1 over the
    whole batch: the summed-counts F1 of the evaluation protocol) instead."""
    import torch

    xt, yt = torch.from_numpy(x), torch.from_numpy(y)
    p = net(xt)
    p = p[torch.arange(len(c)), torch.from_numpy(c)]  # each sample's own class channel
    p = p.clamp(1e-6, 1 - 1e-6)
    w = torch.tensor([_POS_WEIGHT[CLASSES[i]] for i in c])[:, None, None]
    bce_px = -(w * yt * torch.log(p) + (1 - yt) * torch.log(1 - p))
    inter = (p * yt).sum((1, 2))
    dice = 1 - (2 * inter + 1) / (p.sum((1, 2)) + yt.sum((1, 2)) + 1)
    if soft_f1 <= 0:
        return bce_px.mean() + 0.5 * dice.mean()
    corr = torch.from_numpy(c == CLASSES.index("corrosion"))
    loss = bce_px.mean()
    if (~corr).any():
        loss = loss + 0.5 * dice[~corr].mean() * float((~corr).sum()) / len(c)
    if corr.any():
        pc, yc = p[corr], yt[corr]
        tp = (pc * yc).sum()
        f1 = 2 * tp / (pc.sum() + yc.sum() + 1)
        loss = loss + soft_f1 * (1 - f1) * float(corr.sum()) / len(c)
    return loss


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
    net = build_net(tuple(ck["config"]["widths"]), dw_levels=ck["config"]["dw_levels"])
    net.load_state_dict(ck["state"])
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.ft_lr, weight_decay=cfg.weight_decay)
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
        x1, y1, c1 = _batch(train_items, cfg, rng, classes=("corrosion",), crop_px=cfg.ft_crop_px,
                            n=cfg.ft_corrosion_batch)
        x2, y2, c2 = _batch(train_items, cfg, rng, classes=others)
        l1 = _loss(net, x1, y1, c1, cfg.ft_soft_f1)
        l2 = _loss(net, x2, y2, c2)
        loss_avg = _optimise(opt, (l1 * len(c1) + l2 * len(c2)) / (len(c1) + len(c2)), loss_avg)
        step += 1
        if step % 50 == 0:
            log(f"ft step {step} loss {loss_avg:.4f} ({time.monotonic() - t0:.0f} s)")
        over_time = time.monotonic() - t0 > budget
        if step % cfg.ft_val_every == 0 or step == n or over_time:
            v = validate(net, val_items)
            net.eval()
            score = float(np.mean([r["F"] for r in v.values()]))
            log(f"ft val step {step}: " + ", ".join(f"{k} F {r['F']:.3f} @ {r['threshold_u8']}" for k, r in v.items())
                + f" mean {score:.4f} ({time.monotonic() - t0:.0f} s)")
            if round(score, 4) > round(best_score, 4):  # phase 1's figure is stored rounded: a tie is no gain
                best_score = score
                best = {"step": p1["step"], "ft_step": step, "val": v, "mean_F": round(score, 4)}
                ck2 = dict(ck, state=net.state_dict(), best=best, phase1_best=p1, config=asdict(cfg))
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
    net = build_net(tuple(cfg["widths"]), dw_levels=cfg["dw_levels"])
    net.load_state_dict(ck["state"])
    net.eval()
    net.full_output = False  # the graph ends at the 1/2-res sigmoid map; the inference up-samples it
    dummy = torch.zeros(1, 3, 64, 64)
    out.parent.mkdir(parents=True, exist_ok=True)
    torch.onnx.export(
        net, (dummy,), str(out), input_names=["image"], output_names=["prob"], opset_version=17,
        dynamic_axes={"image": {0: "n", 2: "h", 3: "w"}, "prob": {0: "n", 2: "h", 3: "w"}}, dynamo=False,
    )
    m = onnx.load(str(out))
    best = ck["best"]
    meta = {
        "format": ONNX_FORMAT,
        "version": version,
        "classes": list(CLASSES),
        "input": {"name": "image", "layout": "NCHW", "channels": "RGB", "scale": 1 / 255,
                  "mean": list(INPUT_MEAN), "std": list(INPUT_STD), "multiple_of": MULTIPLE_OF,
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
                     "command": "inspect-pipe detect train ../shared/data/defects --engine onnx -o MODEL.onnx"},
        "licence": LICENCE,
    }
    del m.metadata_props[:]
    p = m.metadata_props.add()
    p.key, p.value = "inspect_pipe", json.dumps(meta)
    m.doc_string = "inspect_pipe learned defect segmentation (half-resolution U-Net); see metadata 'inspect_pipe'"
    onnx.save(m, str(out))
    log(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB)")
