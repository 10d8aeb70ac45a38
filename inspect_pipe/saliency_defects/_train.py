"""Learning the likelihood tables, the table weights and the operating point of one class.

Three passes over the training images (features are recomputed each pass to keep memory flat):
1. sample pixels (all classes balanced per image, an ignore band around label boundaries),
   build per-feature class-conditional histograms -> LLR tables (optionally joint tables of
   feature pairs and one tree table: a joint table over the cells of a decision tree on the
   features' bins), fit table weights by weighted logistic regression (sample weights restore the
   true pixel prior);
2. optional auto-context stage: the same on features of the stage-1 logit map;
3. choose the operating point (threshold, hysteresis low threshold) that maximises F on the
   training images, with the class's evaluation tolerance and the speckle filter applied.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import cv2
import numpy as np

from ._detect import class_logits, decide
from ._features import FEATURE_NAMES, N_HUE, N_SAT, compute_features
from ._metrics import best_f, tolerance_counts
from ._model import (
    ALL_CONTEXT_NAMES,
    CONTEXT_NAMES,
    N_BINS,
    PAIR_BINS,
    ClassModel,
    FeatureTable,
    Stage,
    context_maps,
    sigmoid,
    table_bins,
)

Loader = Callable[[], tuple[np.ndarray, np.ndarray]]

GREY_FEATURES = (
    "int_cs", "int_cs_abs", "ori_cs", "sym", "val", "rough", "rough2",
    "ridge1", "ridge2", "ridge3", "dark", "line", "line2", "coh",
)


@dataclass(frozen=True)
class ClassTrainConfig:
    """How one class is trained. Pixel counts are per training image."""

    cls: str
    features: tuple[str, ...] = FEATURE_NAMES
    needs_colour: bool = True
    tol_px: float = 0.0  # tolerance of the F score that picks the operating point
    ignore_band_px: int = 0  # label-boundary band left out of the training samples
    pos_per_image: int = 2000
    neg_per_image: int = 2000
    context: int = 0  # number of auto-context stages after the first
    context_raw: tuple[str, ...] = ()  # first-stage features that the context stages use again
    context_names: tuple[str, ...] = CONTEXT_NAMES  # context maps of the stage-1 logit they use
    pairs: tuple[tuple[str, str], ...] = ()  # feature pairs with a joint table in the first stage
    smooth_sigma_px: float = 0.0
    min_area_px: int = 20
    hysteresis_ratios: tuple[float, ...] = (1.0,)
    l2: float = 1e-3
    seed: int = 0
    level: int = 0  # pyramid level of the features (1: half resolution, the map upsampled)
    tree_depth: int = 0  # > 0: the first stage also has a tree table of this depth (at most 8)
    tree_min_leaf: int = 200  # fewest training samples on either side of a tree split

    def __post_init__(self) -> None:
        unknown = (set(self.features) - set(FEATURE_NAMES) | set(self.context_raw) - set(self.features)
                   | set(self.context_names) - set(ALL_CONTEXT_NAMES)
                   | {n for p in self.pairs for n in p} - set(self.features))
        if unknown:
            raise ValueError(f"unknown features {sorted(unknown)}")
        if not 0 <= self.tree_depth <= 8:
            raise ValueError(f"tree depth must be 0..8 (its leaves index a 256-entry table), got {self.tree_depth}")


#: Crack features: the grey features whose tables earned a weight (ridge strengths, the darkness
#: z-score, unsigned contrast and fine roughness scored ~0 next to the line detectors; the
#: full-resolution 11 px line detector added nothing to the 22 px one on validation images).
CRACK_FEATURES = ("int_cs", "ori_cs", "sym", "val", "rough2", "line2", "coh")
#: Corrosion features: saliency (intensity and orientation contrast), colour and roughness, local
#: colour statistics (variation over 7 and 15 px, colour edges, colour relative to the
#: surroundings) and the texture energies of the red chromaticity and value at full resolution.
#: Left out, with validation F unchanged without them: the crack evidence (ridges, darkness, dark
#: lines), the colour centre-surround contrasts, symmetry, the coarse roughness, the 31 px region
#: means and deviations (the relative features and the context stage carry the region), and the
#: next band's chromaticity energy (``ctex2_r``, which, like the opponents' bands, lost synthetic
#: rust with independent channel noise).
CORROSION_FEATURES = (
    "int_cs", "int_cs_abs", "ori_cs", "hs", "val", "rchrom", "rough", "lab_a", "lab_b", "rough_mean", "coh",
    "lab_a_rel", "lab_b_rel", "rchrom_rel", "val_rel",
    "lab_a_std7", "lab_b_std7", "rchrom_std7", "val_std7", "lab_a_std15", "lab_b_std15", "rchrom_std15", "val_std15",
    "lab_a_grad15", "lab_b_grad15", "rchrom_grad15",
    "ctex_r", "ctex_v", "ctex_r_mean", "ctex_v_mean", "ctex2_v",
)
#: Corrosion context maps: the 11 px line support of the logit left out (~0 weight; validation F
#: unchanged without it), the 22 px one kept.
CORROSION_CONTEXT = ("z", "z_mean", "z_box15", "z_box31", "z_box63", "z_line2")
#: Crack context maps: the 11 px line support of the logit likewise dropped for the 22 px one, and
#: the 7 and 31 px box means (small weights; validation F unchanged without them).
CRACK_CONTEXT = ("z", "z_box15", "z_box63", "z_line2")


def brightness_pairs(features) -> tuple[tuple[str, str], ...]:
    """Every feature paired with the brightness ``val``: joint tables p(f, val | class), i.e. each
    feature's likelihood conditioned on the grey level (semi-naive Bayes)."""
    return tuple((f, "val") for f in features if f != "val")


#: The configurations of the shipped model (one per class).
DEFAULT_CONFIGS = {
    "crack": ClassTrainConfig(
        cls="crack", features=CRACK_FEATURES, needs_colour=False, tol_px=2.0, ignore_band_px=2,
        pos_per_image=3000, neg_per_image=6000, context=1, context_names=CRACK_CONTEXT, min_area_px=20,
        hysteresis_ratios=(1.0, 0.8, 0.6, 0.45),
    ),
    "corrosion": ClassTrainConfig(
        cls="corrosion", features=CORROSION_FEATURES, needs_colour=True, tol_px=0.0, ignore_band_px=2,
        pos_per_image=1500, neg_per_image=1500, context=1, context_names=CORROSION_CONTEXT, smooth_sigma_px=0.5,
        min_area_px=64, level=1, tree_depth=8,
    ),
    "surface": ClassTrainConfig(
        cls="surface", features=GREY_FEATURES, needs_colour=False, tol_px=0.0, ignore_band_px=1,
        pos_per_image=4000, neg_per_image=4000, context=1, smooth_sigma_px=1.5, min_area_px=20,
        pairs=brightness_pairs(GREY_FEATURES),
    ),
}


@dataclass
class _Samples:
    pos: list = field(default_factory=list)
    neg: list = field(default_factory=list)
    n_pos_total: int = 0
    n_neg_total: int = 0


def _sample_masks(gt: np.ndarray, band: int) -> tuple[np.ndarray, np.ndarray]:
    g = gt.astype(np.uint8)
    if band <= 0:
        return gt.astype(bool), ~gt.astype(bool)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * band + 1, 2 * band + 1))
    near = cv2.dilate(g, k).astype(bool)
    pos = gt.astype(bool)
    if pos.sum() > 400:  # thin structures (cracks) keep every labelled pixel
        core = cv2.erode(g, k).astype(bool)
        if core.sum() > 0.3 * pos.sum():
            pos = core
    return pos, ~near


def _gt_at(gt: np.ndarray, level: int, shape_hw: tuple[int, int]) -> np.ndarray:
    """The label mask at pyramid ``level``: a pixel is defect when at least half its area is."""
    if level == 0:
        return gt
    g = gt.astype(np.float32)
    f = 2**level
    h, w = shape_hw
    g = cv2.copyMakeBorder(g, 0, h * f - g.shape[0], 0, w * f - g.shape[1], cv2.BORDER_REFLECT_101)
    return cv2.resize(g, (w, h), interpolation=cv2.INTER_AREA) >= 0.5


def _draw(rng: np.random.Generator, flat_idx: np.ndarray, n: int) -> np.ndarray:
    if flat_idx.size <= n:
        return flat_idx
    return rng.choice(flat_idx, n, replace=False)


def _collect(maps: dict[str, np.ndarray], names, pos_m, neg_m, cfg, rng, acc: _Samples) -> None:
    pi = np.flatnonzero(pos_m.ravel())
    ni = np.flatnonzero(neg_m.ravel())
    acc.n_pos_total += pi.size
    acc.n_neg_total += ni.size
    pi = _draw(rng, pi, cfg.pos_per_image)
    ni = _draw(rng, ni, cfg.neg_per_image)
    stack = np.stack([maps[n].ravel() for n in names], axis=1)
    acc.pos.append(stack[pi])
    acc.neg.append(stack[ni])


def _tables(names, pos: np.ndarray, neg: np.ndarray) -> list[FeatureTable]:
    tables = []
    for j, name in enumerate(names):
        xp, xn = pos[:, j], neg[:, j]
        if name == "hs":
            nb, lo, hi, cat = N_HUE * N_SAT, 0.0, float(N_HUE * N_SAT), True
            bp = np.clip(xp, 0, nb - 1).astype(int)
            bn = np.clip(xn, 0, nb - 1).astype(int)
        else:
            both = np.concatenate([xp, xn])
            lo, hi = (float(v) for v in np.percentile(both, [0.5, 99.5]))
            if hi <= lo:
                hi = lo + 1e-6
            nb, cat = N_BINS, False
            probe = FeatureTable(name, lo, hi, np.zeros(nb, np.float32))
            bp = np.minimum(probe.bins(xp.reshape(-1, 1)).ravel().astype(int), nb - 1)
            bn = np.minimum(probe.bins(xn.reshape(-1, 1)).ravel().astype(int), nb - 1)
        hp = np.bincount(bp, minlength=nb).astype(np.float64) + 1.0
        hn = np.bincount(bn, minlength=nb).astype(np.float64) + 1.0
        if not cat:  # light smoothing along the value axis
            k = np.array([0.25, 0.5, 0.25])
            hp = np.convolve(np.pad(hp, 1, mode="edge"), k, "valid")
            hn = np.convolve(np.pad(hn, 1, mode="edge"), k, "valid")
        llr = np.log(hp / hp.sum()) - np.log(hn / hn.sum())
        tables.append(FeatureTable(name, lo, hi, llr.astype(np.float32), cat))
    return tables


def _pair_tables(names, pairs, singles, pos: np.ndarray, neg: np.ndarray) -> list[FeatureTable]:
    """Joint class-conditional tables of feature pairs, on the ranges of their single tables."""
    rng = {t.name: (t.lo, t.hi) for t in singles}
    tables = []
    for a, b in pairs:
        probe = FeatureTable(f"{a}*{b}", *rng[a], np.zeros(PAIR_BINS**2, np.float32), True, (a, b), *rng[b])
        ia, ib = names.index(a), names.index(b)
        nb = PAIR_BINS**2
        hs = []
        for x in (pos, neg):
            bi = probe.pair_bins(x[:, ia:ia + 1], x[:, ib:ib + 1]).ravel().astype(int)
            h = np.bincount(bi, minlength=nb).astype(np.float64).reshape(PAIR_BINS, PAIR_BINS)
            h = cv2.GaussianBlur(h, (3, 3), 0.7, borderType=cv2.BORDER_REPLICATE) + 1.0  # light 2-D smoothing
            hs.append(h.ravel())
        llr = np.log(hs[0] / hs[0].sum()) - np.log(hs[1] / hs[1].sum())
        tables.append(FeatureTable(probe.name, probe.lo, probe.hi, llr.astype(np.float32), True, (a, b), probe.lo2, probe.hi2))
    return tables


def _llr_matrix(tables, x: np.ndarray, names) -> np.ndarray:
    feats = {n: x[:, j:j + 1].astype(np.float32) for j, n in enumerate(names)}
    cols = [t.lut()[b.ravel().astype(int)] for t, b in zip(tables, table_bins(tables, feats))]
    return np.stack(cols, axis=1).astype(np.float64)


def _entropy_sum(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """sum over the two classes of w log(w / (p + q)) (minus the weighted entropy), elementwise."""
    t = p + q
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(p > 0, p * np.log(p / t), 0.0) + np.where(q > 0, q * np.log(q / t), 0.0)
    return np.nan_to_num(out)


def _grow_tree(B: np.ndarray, y: np.ndarray, w: np.ndarray, depth: int, min_leaf: int) -> tuple[np.ndarray, np.ndarray]:
    """A depth-``depth`` decision tree on the bin matrix ``B`` (n, F) uint8: at every node the
    split (feature, bin threshold) with the largest weighted information gain about ``y``, level by
    level, all nodes of a level at once (histograms of the bins per node). Returns (split, thr) in
    heap order; a node that no split improves (or too few samples) gets split -1."""
    n, F = B.shape
    nb = 256
    split = np.full(2**depth - 1, -1, np.int16)
    thr = np.zeros(2**depth - 1, np.uint8)
    node = np.zeros(n, np.int64)  # node of each sample, heap order
    for d in range(depth):
        first, cnt = 2**d - 1, 2**d
        local = node - first
        wp = np.bincount(local, weights=w * y, minlength=cnt)
        wn = np.bincount(local, weights=w * (1 - y), minlength=cnt)
        nc = np.bincount(local, minlength=cnt)
        parent = _entropy_sum(wp, wn)
        best = np.zeros(cnt)
        for f in range(F):
            idx = local * nb + B[:, f]
            lp = np.cumsum(np.bincount(idx, weights=w * y, minlength=cnt * nb).reshape(cnt, nb), 1)
            ln = np.cumsum(np.bincount(idx, weights=w * (1 - y), minlength=cnt * nb).reshape(cnt, nb), 1)
            lc = np.cumsum(np.bincount(idx, minlength=cnt * nb).reshape(cnt, nb), 1)
            gain = _entropy_sum(lp, ln) + _entropy_sum(wp[:, None] - lp, wn[:, None] - ln) - parent[:, None]
            gain[(lc < min_leaf) | (nc[:, None] - lc < min_leaf)] = 0.0
            t = gain.argmax(1)
            g = gain[np.arange(cnt), t]
            better = g > best
            best[better] = g[better]
            split[first:first + cnt][better] = f
            thr[first:first + cnt][better] = t[better]
        s, th = split[first:first + cnt][local], thr[first:first + cnt][local]
        right = (s >= 0) & (B[np.arange(n), np.maximum(s, 0)] > th)
        node = 2 * node + 1 + right
    return split, thr


def _tree_table(names, tables, x: np.ndarray, y: np.ndarray, w: np.ndarray, grow: np.ndarray,
                depth: int, min_leaf: int) -> FeatureTable | None:
    """The tree table of a stage: grown on the samples ``grow``, its leaf likelihoods p(leaf |
    class) counted on the others (so the table's evidence is not the tree's own fit)."""
    singles = [t for t in tables if not t.pair and not t.tree_inputs]
    feats = {n: x[:, j:j + 1].astype(np.float32) for j, n in enumerate(names)}
    B = np.stack([t.bins_in(feats).ravel() for t in singles], axis=1)
    split, thr = _grow_tree(B[grow], y[grow], w[grow], depth, min_leaf)
    used = sorted({int(k) for k in split if k >= 0})
    if not used:  # no split gained anything: no table
        return None
    remap = np.full(len(singles), -1, np.int16)
    remap[used] = np.arange(len(used))
    probe = FeatureTable("tree", 0.0, float(2**depth), np.zeros(2**depth, np.float32), True,
                         tree_inputs=tuple(singles[k].name for k in used),
                         tree_split=np.where(split >= 0, remap[np.maximum(split, 0)], -1).astype(np.int16),
                         tree_thr=thr)
    leaf = probe.tree_cells({singles[k].name: B[:, k] for k in used}).astype(int)
    est = ~grow
    hp = np.bincount(leaf[est & (y == 1)], minlength=2**depth) + 1.0
    hn = np.bincount(leaf[est & (y == 0)], minlength=2**depth) + 1.0
    llr = np.log(hp / hp.sum()) - np.log(hn / hn.sum())
    return FeatureTable("tree", 0.0, float(2**depth), llr.astype(np.float32), True,
                        tree_inputs=probe.tree_inputs, tree_split=probe.tree_split, tree_thr=thr)


def _logistic(X: np.ndarray, y: np.ndarray, w: np.ndarray, l2: float) -> tuple[np.ndarray, float]:
    """Weighted L2-regularised logistic regression by Newton's method; returns (coef, bias)."""
    n, d = X.shape
    A = np.hstack([X, np.ones((n, 1))])
    beta = np.zeros(d + 1)
    beta[:d] = 1.0 / max(d, 1)
    reg = np.full(d + 1, l2 * w.sum())
    reg[-1] = 0.0
    for _ in range(50):
        z = A @ beta
        p = 1.0 / (1.0 + np.exp(-np.clip(z, -30, 30)))
        g = A.T @ (w * (p - y)) + reg * beta
        H = (A * (w * p * (1 - p))[:, None]).T @ A + np.diag(reg) + 1e-9 * np.eye(d + 1)
        step = np.linalg.solve(H, g)
        beta -= step
        if np.abs(step).max() < 1e-7:
            break
    return beta[:d].astype(np.float32), float(beta[d])


def _fit_stage(names, acc: _Samples, l2: float, pairs=(), tree_depth: int = 0, tree_min_leaf: int = 200,
               seed: int = 0) -> Stage:
    pos = np.concatenate(acc.pos)
    neg = np.concatenate(acc.neg)
    tables = _tables(names, pos, neg)
    tables += _pair_tables(list(names), pairs, tables, pos, neg)
    x = np.concatenate([pos, neg])
    y = np.concatenate([np.ones(len(pos)), np.zeros(len(neg))])
    # sample weights restore the true class frequencies of the (non-ignored) training pixels
    wp = acc.n_pos_total / max(len(pos), 1)
    wn = acc.n_neg_total / max(len(neg), 1)
    w = np.concatenate([np.full(len(pos), wp), np.full(len(neg), wn)])
    w /= w.mean()
    if tree_depth:  # grown on a random half of the samples, its likelihoods counted on the other
        grow = np.random.default_rng(seed + 1).random(len(y)) < 0.5
        tree = _tree_table(names, tables, x, y, w, grow, tree_depth, tree_min_leaf)
        tables += [tree] if tree is not None else []
    X = _llr_matrix(tables, x, names)
    coef, bias = _logistic(X, y, w, l2)
    prior = float(np.log(max(acc.n_pos_total, 1) / max(acc.n_neg_total, 1)))
    return Stage(tuple(tables), coef, bias, prior)


def _operating_point(cfg: ClassTrainConfig, stages, items: Sequence[Loader]) -> tuple[float, float, dict]:
    probs, gts = [], []
    total = None
    cm0 = ClassModel(cfg.cls, tuple(stages), 0.5, 0.5, cfg.smooth_sigma_px, cfg.min_area_px, cfg.needs_colour,
                     level=cfg.level)
    for load in items:
        img, gt = load()
        p = np.clip(np.rint(sigmoid(class_logits(img, [cm0])[cfg.cls]) * 255), 0, 255).astype(np.uint8)
        probs.append(p)
        gts.append(gt)
        c = tolerance_counts(p, gt, cfg.tol_px)
        total = c if total is None else total + c
    f0, t0 = best_f(total)
    best = (-1.0, t0, 1.0)
    for ratio in cfg.hysteresis_ratios:
        for t in range(max(t0 - 40, 2), min(t0 + 41, 255), 3):
            cm = ClassModel(cfg.cls, (), t / 255, t * ratio / 255, 0, cfg.min_area_px, cfg.needs_colour)
            tot = None
            for p, gt in zip(probs, gts):
                m = decide(p, cm)[0]
                c = tolerance_counts(m.astype(np.uint8) * 255, gt, cfg.tol_px)
                tot = c if tot is None else tot + c
            pr, rc, f = (float(a[255]) for a in tot.prf())
            if f > best[0]:
                best = (f, t, ratio, pr, rc)
    f, t, ratio, pr, rc = best
    score = {"f_ods_train": round(f0, 4), "f_train": round(f, 4), "precision_train": round(pr, 4),
             "recall_train": round(rc, 4), "tol_px": cfg.tol_px}
    return t / 255, t * ratio / 255, score


def train_class(items: Sequence[Loader], cfg: ClassTrainConfig, *, log=print) -> ClassModel:
    """Learn one class from labelled images (``load() -> (image, gt bool)``)."""
    if not items:
        raise ValueError("no training images")
    rng = np.random.default_rng(cfg.seed)
    acc = _Samples()
    names = list(cfg.features)
    for load in items:
        img, gt = load()
        fs = compute_features(img, names, level=cfg.level)
        pos_m, neg_m = _sample_masks(_gt_at(gt, cfg.level, fs.shape), cfg.ignore_band_px)
        _collect({n: fs[n] for n in names}, names, pos_m, neg_m, cfg, rng, acc)
    stage1 = _fit_stage(names, acc, cfg.l2, cfg.pairs, cfg.tree_depth, cfg.tree_min_leaf, cfg.seed)
    log(f"  {cfg.cls}: stage 1 on {sum(len(a) for a in acc.pos)} + {sum(len(a) for a in acc.neg)} px; "
        f"weights " + ", ".join(f"{n}={w:.2f}" for n, w in zip(stage1.names, stage1.weights)))
    stages = [stage1]
    cnames = list(cfg.context_names) + list(cfg.context_raw)
    for k in range(cfg.context):
        acc2 = _Samples()
        for load in items:
            img, gt = load()
            fs = compute_features(img, names, level=cfg.level)
            feats = {n: fs[n] for n in names}
            z = stages[0].logit(feats)
            for st in stages[1:]:
                z = st.logit(context_maps(stages[0], feats, z, st.inputs))
            pos_m, neg_m = _sample_masks(_gt_at(gt, cfg.level, fs.shape), cfg.ignore_band_px)
            _collect(context_maps(stages[0], feats, z, cnames), cnames, pos_m, neg_m, cfg, rng, acc2)
        st = _fit_stage(cnames, acc2, cfg.l2)
        log(f"  {cfg.cls}: context {k + 1} weights " + ", ".join(f"{n}={w:.2f}" for n, w in zip(cnames, st.weights)))
        stages.append(st)
    thr, low, score = _operating_point(cfg, stages, items)
    log(f"  {cfg.cls}: operating point P >= {thr:.3f} (hysteresis {low:.3f}); train {score}")
    return ClassModel(cfg.cls, tuple(stages), thr, low, cfg.smooth_sigma_px, cfg.min_area_px, cfg.needs_colour, score,
                      level=cfg.level)


def train_model(sources: dict, *, version: str, configs: dict | None = None, log=print) -> "DefectModel":
    """Train every class of ``sources`` ({class: (set_name, [LabelledImage, ...])}) and record the
    data set, split rule and training images in the model's metadata."""
    import datetime as _dt

    from inspect_pipe import __version__

    from ._datasets import SPLIT_RULE
    from ._model import DefectModel

    configs = {**DEFAULT_CONFIGS, **(configs or {})}
    classes, data = {}, {}
    for cls, (set_name, items) in sources.items():
        log(f"training {cls} on {set_name}: {len(items)} images")
        classes[cls] = train_class([it.load for it in items], configs[cls], log=log)
        data[cls] = {
            "set": set_name,
            "split": "train",
            "split_rule": SPLIT_RULE,
            "n_images": len(items),
            "images": [it.stem for it in items],
        }
    meta = {
        "version": version,
        "created": _dt.date.today().isoformat(),
        "software": f"inspect_pipe {__version__}",
        "training_data": data,
    }
    return DefectModel(classes, meta)
