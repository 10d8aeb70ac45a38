"""Learned likelihood tables and their Bayes combination into P(defect | features).

For each defect class and each feature f, training estimates the class-conditional histograms
p(f | defect) and p(f | background) on fixed bins and stores their log ratio
LLR_f(b) = log p(b | defect) - log p(b | background). Bayes' rule with conditionally independent
features gives

    logit P(defect | f_1..f_n) = log P(defect)/P(background) + sum_f LLR_f(b_f)      (naive Bayes)

Saliency features are strongly correlated, which makes the plain sum over-confident; the shipped
model therefore weights each table (w_f, learned by logistic regression on the LLR values, a
"weighted naive Bayes") and replaces the prior term by a learned bias. Both forms are kept in the
model, so the benchmark can compare them.

An optional second stage (auto-context) applies the same machinery to features of the first
stage's logit map: its mean and its support along lines (connected, elongated evidence, the
role percolation plays in the crack detectors of Bonnin-Pascual and Ortiz).
"""

from __future__ import annotations

import json
import math
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ._features import _LINES, COLOUR_FEATURES, N_HUE, N_SAT, FeatureStack

FORMAT = "inspect_pipe.defect_model/2"
#: Model formats this reader takes (/1: the same without tree tables).
READ_FORMATS = ("inspect_pipe.defect_model/1", FORMAT)
N_BINS = 48
PAIR_BINS = 16  # per axis of a joint (two-feature) table: 256 bins, one uint8 index
CONTEXT_NAMES = ("z", "z_mean", "z_box15", "z_box31", "z_box63", "z_line", "z_line2")
#: every context map a stage may use (CONTEXT_NAMES is the default set)
ALL_CONTEXT_NAMES = CONTEXT_NAMES + ("z_box127", "zc", "zc_box15", "zc_box31", "zc_box63")


def context_reach_px(names) -> int:
    """How far (px at the class's level) the context maps ``names`` read beyond a pixel."""
    reach = {"z_mean": 3, "z_line": 5, "z_line2": 12}
    r = 0
    for n in names:
        if "_box" in n:
            r = max(r, int(n.rsplit("_box", 1)[1]) // 2)
        else:
            r = max(r, reach.get(n, 0))
    return r


def _cv_ready(x: np.ndarray) -> np.ndarray:
    """float32 with contiguous rows (OpenCV takes row-strided views, such as the feature maps'
    crops of their padded arrays, without a copy)."""
    if x.dtype == np.float32 and x.strides[-1] == 4:
        return x
    return np.ascontiguousarray(x, np.float32)


@dataclass(frozen=True)
class FeatureTable:
    """LLR table of one feature: continuous values are binned uniformly on [lo, hi] (clipped)."""

    name: str
    lo: float
    hi: float
    llr: np.ndarray  # (n_bins,) float32
    categorical: bool = False
    #: a joint table of two features (semi-naive Bayes): p(f_a, f_b | class) on PAIR_BINS x
    #: PAIR_BINS bins, f_a on [lo, hi], f_b on [lo2, hi2]; ``name`` is "a*b"
    pair: tuple[str, str] | None = None
    lo2: float = 0.0
    hi2: float = 1.0
    #: a joint table over the cells of a binary partition of several features (semi-naive Bayes on
    #: a learned grid): a decision tree of depth d on the bins of the stage's single tables
    #: ``tree_inputs``; internal node i (heap order, children 2i+1, 2i+2) sends a pixel right when
    #: the bin of feature ``tree_inputs[tree_split[i]]`` is > ``tree_thr[i]`` (split -1: all
    #: left); the 2^d leaves are the table's bins
    tree_inputs: tuple[str, ...] | None = None
    tree_split: np.ndarray | None = None  # (2^d - 1,) int16
    tree_thr: np.ndarray | None = None  # (2^d - 1,) uint8

    def bins(self, x: np.ndarray) -> np.ndarray:
        """Bin index per pixel, uint8; values past the last bin give 255 (see :meth:`lut`)."""
        x = _cv_ready(x)
        if self.categorical:
            return cv2.convertScaleAbs(cv2.max(x, 0.0))
        scale = self.llr.shape[0] / max(self.hi - self.lo, 1e-9)
        # floor((x - lo) * scale) for x >= lo, saturated at 255: one pass, no temporaries
        return cv2.convertScaleAbs(cv2.max(x, float(self.lo)), alpha=scale, beta=-self.lo * scale - 0.5 + 1e-4)

    def pair_bins(self, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
        """Joint bin index (uint8) of a pair table: bin_a * PAIR_BINS + bin_b."""
        out = None
        for x, lo, hi, mul in ((xa, self.lo, self.hi, PAIR_BINS), (xb, self.lo2, self.hi2, 1)):
            x = _cv_ready(x)
            scale = PAIR_BINS / max(hi - lo, 1e-9)
            b = cv2.min(cv2.convertScaleAbs(cv2.max(x, float(lo)), alpha=scale, beta=-lo * scale - 0.5 + 1e-4), PAIR_BINS - 1)
            out = b * np.uint8(mul) if out is None else cv2.add(out, b)
        return out

    def tree_cells(self, bins) -> np.ndarray:
        """Leaf index (uint8) per pixel of a tree table; ``bins``: name -> uint8 bin map of each
        of ``tree_inputs`` (the bins of the stage's single tables)."""
        maps = [bins[n] for n in self.tree_inputs]
        shape = maps[0].shape
        n = maps[0].size
        flat = np.stack([m.ravel() for m in maps]).ravel()  # input k's bins at k * n .. k * n + n - 1
        split = self.tree_split.astype(np.int64)
        offset = (np.maximum(split, 0) * n).astype(np.int64 if flat.size >= 2**31 else np.int32)
        thr = np.where(split >= 0, self.tree_thr, 255).astype(np.uint8)  # no split: bin > 255 never
        pos = np.arange(n, dtype=offset.dtype)
        node = (flat[offset[0]:offset[0] + n] > thr[0]).astype(offset.dtype) + 1  # level 1: root decided
        idx = np.empty(n, offset.dtype)
        for _ in range(int(np.log2(split.size + 1)) - 1):
            np.add(offset.take(node), pos, out=idx)
            right = flat.take(idx) > thr.take(node)
            node *= 2
            node += 1
            node += right
        return (node - split.size).astype(np.uint8).reshape(shape)

    def bins_in(self, feats) -> np.ndarray:
        """Bin index per pixel of this table's feature(s) in ``feats`` (name -> map)."""
        if self.tree_inputs:
            raise ValueError("a tree table reads the bins of its stage's single tables (see table_bins)")
        if self.pair:
            return self.pair_bins(feats[self.pair[0]], feats[self.pair[1]])
        return self.bins(feats[self.name])

    def lut(self, weight: float = 1.0) -> np.ndarray:
        lut = np.full(256, self.llr[-1], np.float32)
        lut[: self.llr.shape[0]] = self.llr
        return lut * np.float32(weight)

    def lookup(self, feats, weight: float = 1.0) -> np.ndarray:
        """Weighted LLR per pixel; ``feats``: mapping name -> (H, W) float32."""
        return cv2.LUT(self.bins_in(feats), self.lut(weight))


def table_bins(tables, feats):
    """Bin index map (uint8) of each of ``tables`` on ``feats`` (name -> map), in order, one at a
    time; a tree table reads the bins of the single tables before it."""
    reads = {n for t in tables if t.tree_inputs for n in t.tree_inputs}
    bins: dict[str, np.ndarray] = {}
    for t in tables:
        if t.tree_inputs:
            yield t.tree_cells(bins)
            continue
        b = t.bins_in(feats)
        if t.name in reads and not t.pair:
            bins[t.name] = b
        yield b


@dataclass(frozen=True)
class Stage:
    """One layer of tables: logit = bias + sum_f weights[f] * LLR_f."""

    tables: tuple[FeatureTable, ...]
    weights: np.ndarray  # (F,) float32
    bias: float
    log_prior_odds: float  # log P(defect)/P(background) in the training pixels

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(t.name for t in self.tables)

    @property
    def inputs(self) -> tuple[str, ...]:
        """The maps the tables read (a pair table reads its two features, a tree table the bins
        of the stage's single tables)."""
        out: list[str] = []
        for t in self.tables:
            out += [n for n in (t.tree_inputs or t.pair or (t.name,)) if n not in out]
        return tuple(out)

    def logit(self, feats, *, naive: bool = False) -> np.ndarray:
        """``feats``: mapping name -> (H, W) float32. ``naive``: unweighted tables + prior."""
        acc = None
        for t, w, b in zip(self.tables, self.weights, table_bins(self.tables, feats)):
            term = cv2.LUT(b, t.lut(1.0 if naive else float(w)))
            acc = term if acc is None else cv2.add(acc, term)
        return acc + np.float32(self.log_prior_odds if naive else self.bias)

    def colour_logit(self, feats, *, naive: bool = False) -> np.ndarray:
        """The colour tables' part of the weighted sum (no bias): the colour evidence alone."""
        acc = None
        for t, w in zip(self.tables, self.weights):
            if t.name in COLOUR_FEATURES:
                term = t.lookup(feats, 1.0 if naive else float(w))
                acc = term if acc is None else cv2.add(acc, term)
        return acc


@dataclass(frozen=True)
class ClassModel:
    """Everything that turns features into one class's probability map and decision."""

    name: str
    stages: tuple[Stage, ...]
    threshold: float  # decide defect where P >= threshold (after smoothing)
    low_threshold: float  # hysteresis: keep pixels >= low connected to a pixel >= threshold
    smooth_sigma_px: float  # Gaussian smoothing of the final logit map
    min_area_px: int  # connected components smaller than this are speckle
    needs_colour: bool
    train_score: dict = field(default_factory=dict)
    level: int = 0  # pyramid level of the class's feature maps (1: half resolution, upsampled)

    @property
    def feature_names(self) -> tuple[str, ...]:
        """The features the first stage reads."""
        return self.stages[0].inputs if self.stages else ()


@dataclass(frozen=True)
class DefectModel:
    """A versioned set of class models plus where and how they were trained."""

    classes: dict[str, ClassModel]
    meta: dict

    @property
    def version(self) -> str:
        return str(self.meta.get("version", "?"))


def _best_line(z: np.ndarray) -> np.ndarray:
    best = None
    for k in _LINES:
        r = cv2.filter2D(z, -1, k, borderType=cv2.BORDER_REFLECT_101)
        best = r if best is None else np.maximum(best, r)
    return best


def context_features(z: np.ndarray, names=CONTEXT_NAMES, zc: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Context maps ``names`` of a logit map ``z`` (H, W) float32: itself, its local means over
    7 to 127 px boxes (region support), and its best mean along 11 px and 22 px lines (connected,
    elongated support: the role of percolation in crack detection); ``zc*``: the same boxes over
    ``zc``, the first stage's colour evidence alone (region colour, the cascade's colour model)."""
    h, w = z.shape
    zc_ = None if zc is None else np.clip(zc, -12, 12).astype(np.float32)
    zz = np.clip(z, -12, 12).astype(np.float32)
    out = {"z": zz}
    if "zc" in names:
        out["zc"] = zc_
    if "z_mean" in names:
        out["z_mean"] = cv2.blur(zz, (7, 7))
    for n in (15, 31, 63, 127):
        for pre, m in (("z", zz), ("zc", zc_)):
            if f"{pre}_box{n}" in names:
                out[f"{pre}_box{n}"] = cv2.blur(m, (n, n), borderType=cv2.BORDER_REFLECT_101)
    if "z_line" in names:
        out["z_line"] = _best_line(zz)
    if "z_line2" in names:
        # half resolution on an even-sized copy, so a tile and the whole image sample the same grid
        ze = cv2.copyMakeBorder(zz, 0, h % 2, 0, w % 2, cv2.BORDER_REFLECT_101)
        half = cv2.resize(ze, (ze.shape[1] // 2, ze.shape[0] // 2), interpolation=cv2.INTER_AREA)
        up = cv2.resize(_best_line(half), (ze.shape[1], ze.shape[0]), interpolation=cv2.INTER_LINEAR)
        out["z_line2"] = up[:h, :w]
    return out


def context_maps(stage1: Stage, feats, z: np.ndarray, names, *, naive: bool = False) -> dict[str, np.ndarray]:
    """What a context stage with tables ``names`` reads: first-stage features and context maps."""
    zc = stage1.colour_logit(feats, naive=naive) if any(n.startswith("zc") for n in names) else None
    return {**feats, **context_features(z, names, zc)}


def class_logit(fs: FeatureStack, cm: ClassModel, *, naive: bool = False) -> np.ndarray:
    """Final logit map of class ``cm`` (stages chained, then smoothed) at the resolution of ``fs``
    (which must be computed at ``cm.level``); :func:`to_full_res` brings it to the image's."""
    if fs.level != cm.level:
        raise ValueError(f"class {cm.name} needs features at level {cm.level}, got level {fs.level}")
    feats = fs.as_dict()
    z = cm.stages[0].logit(feats, naive=naive)
    for st in cm.stages[1:]:
        # a context stage's tables: context maps of z, and optionally first-stage features again
        z = st.logit(context_maps(cm.stages[0], feats, z, st.inputs, naive=naive), naive=naive)
    if cm.smooth_sigma_px > 0:
        z = cv2.GaussianBlur(z, (0, 0), cm.smooth_sigma_px)
    return z


def to_full_res(m: np.ndarray, shape_hw: tuple[int, int], level: int) -> np.ndarray:
    """A map computed at pyramid ``level`` (ceil(H / 2^level) x ceil(W / 2^level)) brought to the
    image's (H, W) by bilinear interpolation (the pyramid's pixel-centre geometry)."""
    if level == 0:
        return m
    f = 2**level
    up = cv2.resize(m, (m.shape[1] * f, m.shape[0] * f), interpolation=cv2.INTER_LINEAR)
    return up[: shape_hw[0], : shape_hw[1]]


def sigmoid(z: np.ndarray) -> np.ndarray:
    z = np.clip(z, -30, 30)
    return (1.0 / (1.0 + np.exp(-z))).astype(np.float32)


# ----------------------------------------------------------------------------- file format


def save_model(model: DefectModel, path: Path) -> None:
    """Write ``model`` as one .npz: arrays plus a JSON header under the key ``meta``."""
    arrays: dict[str, np.ndarray] = {}
    classes = {}
    for cname, cm in model.classes.items():
        stages = []
        for k, st in enumerate(cm.stages):
            feats = []
            for t in st.tables:
                arrays[f"{cname}/{k}/{t.name}"] = t.llr.astype(np.float32)
                f = {"name": t.name, "lo": t.lo, "hi": t.hi, "categorical": t.categorical}
                if t.pair:
                    f.update(pair=list(t.pair), lo2=t.lo2, hi2=t.hi2)
                if t.tree_inputs:
                    f.update(tree_inputs=list(t.tree_inputs))
                    arrays[f"{cname}/{k}/{t.name}:split"] = t.tree_split.astype(np.int16)
                    arrays[f"{cname}/{k}/{t.name}:thr"] = t.tree_thr.astype(np.uint8)
                feats.append(f)
            stages.append(
                {
                    "features": feats,
                    "weights": [float(w) for w in st.weights],
                    "bias": st.bias,
                    "log_prior_odds": st.log_prior_odds,
                }
            )
        classes[cname] = {
            "stages": stages,
            "threshold": cm.threshold,
            "low_threshold": cm.low_threshold,
            "smooth_sigma_px": cm.smooth_sigma_px,
            "min_area_px": cm.min_area_px,
            "needs_colour": cm.needs_colour,
            "train_score": cm.train_score,
            "level": cm.level,
        }
    header = dict(model.meta)
    header["format"] = FORMAT
    header["classes"] = classes
    header["feature_geometry"] = {"n_hue": N_HUE, "n_sat": N_SAT}
    arrays["meta"] = np.frombuffer(json.dumps(header, indent=1).encode(), np.uint8)
    import io

    from inspect_pipe._files import atomic_write

    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    atomic_write(Path(path), buf.getvalue())  # a model being replaced is never left half-written


def _check_tree(t: FeatureTable, tables, where: str) -> None:
    """A tree table read from a file must be whole: its split and threshold arrays of one heap
    size (2^d - 1, d <= 8), splits naming its inputs, and every input a single table read before
    it (else the damage would surface as an exception in the middle of a detection)."""
    if not t.tree_inputs:
        return
    split, thr = t.tree_split, t.tree_thr
    ok = split is not None and thr is not None and split.ndim == 1 and split.shape == thr.shape
    ok = ok and split.size + 1 in (2, 4, 8, 16, 32, 64, 128, 256) and int(split.max(initial=-1)) < len(t.tree_inputs)
    before = {u.name for u in tables[: tables.index(t)] if not u.pair and not u.tree_inputs}
    if not ok or not set(t.tree_inputs) <= before:
        raise ValueError(f"damaged model file: the tree table of {where} is incomplete")


#: Largest smoothing a class may ask for (px): the shipped classes use 0-1.5; beyond this the
#: Gaussian's kernel costs seconds per frame and blurs a crack away.
MAX_SMOOTH_SIGMA_PX = 20.0


def _check_class(c: ClassModel) -> None:
    """A class read from a file must be usable as it stands: finite thresholds in order within
    [0, 1], a feature level the features have, a sane smoothing, and every table the length its
    kind has with one weight per table (else a damaged file decides with shifted tables, or fails
    later on an image that is not at fault)."""
    where = f"damaged model file: class {c.name!r}"
    if not (0.0 <= c.low_threshold <= c.threshold <= 1.0):  # NaN fails every comparison
        raise ValueError(f"{where}: thresholds must satisfy 0 <= low <= threshold <= 1")
    if not 0.0 <= c.smooth_sigma_px <= MAX_SMOOTH_SIGMA_PX:
        raise ValueError(f"{where}: smooth_sigma_px must be in [0, {MAX_SMOOTH_SIGMA_PX:g}]")
    if c.min_area_px < 0 or c.level not in (0, 1):
        raise ValueError(f"{where}: min_area_px must be >= 0 and the feature level 0 or 1")
    for k, s in enumerate(c.stages):
        if s.weights.shape != (len(s.tables),) or not np.isfinite(s.weights).all() or \
                not (math.isfinite(s.bias) and math.isfinite(s.log_prior_odds)):
            raise ValueError(f"{where}: stage {k} needs one finite weight per table and a finite bias")
        for t in s.tables:
            n = (t.tree_split.size + 1 if t.tree_inputs and t.tree_split is not None else PAIR_BINS * PAIR_BINS if t.pair
                 else None if t.categorical else N_BINS)
            ok = t.llr.ndim == 1 and t.llr.size > 0 and (n is None or t.llr.size == n) and np.isfinite(t.llr).all()
            if not ok or not (math.isfinite(t.lo) and math.isfinite(t.hi) and t.lo < t.hi):
                raise ValueError(f"{where}: table {t.name!r} of stage {k} is not a whole table of its kind")


def load_model(path: Path) -> DefectModel:
    """Read a model written by :func:`save_model`. Raises ValueError on a wrong or damaged file."""
    try:
        with np.load(Path(path), allow_pickle=False) as z:
            header = json.loads(bytes(z["meta"]).decode())
            arrays = {k: z[k] for k in z.files if k != "meta"}
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, UnicodeDecodeError) as err:
        # a truncated or bit-flipped .npz fails its zip structure, its CRC or its deflate stream
        why = "holds Python objects, which are not read" if "pickled" in str(err) else f"{err.__class__.__name__}: {str(err)[:80]}"
        raise ValueError(f"not a defect model file ({why}; give a .npz written by 'inspect-pipe detect train')") from None
    if not isinstance(header, dict):
        raise ValueError("not a defect model file (its header is not a JSON object)")
    try:
        return _from_header(header, arrays)
    except (KeyError, TypeError, AttributeError, IndexError) as err:  # a ValueError says its own reason
        raise ValueError(f"damaged model file ({err.__class__.__name__} in its header or arrays)") from None


def _from_header(header: dict, arrays: dict) -> DefectModel:
    if header.get("format") not in READ_FORMATS:
        raise ValueError(f"unsupported model format {header.get('format')!r}, expected {FORMAT}")
    geo = header.get("feature_geometry", {})
    if geo.get("n_hue") != N_HUE or geo.get("n_sat") != N_SAT:
        raise ValueError("model was trained with a different hue-saturation table geometry")
    classes = {}
    for cname, c in header["classes"].items():
        stages = []
        for k, s in enumerate(c["stages"]):
            tables = tuple(
                FeatureTable(f["name"], float(f["lo"]), float(f["hi"]), arrays[f"{cname}/{k}/{f['name']}"], bool(f["categorical"]),
                             tuple(f["pair"]) if f.get("pair") else None, float(f.get("lo2", 0.0)), float(f.get("hi2", 1.0)),
                             tuple(f["tree_inputs"]) if f.get("tree_inputs") else None,
                             arrays.get(f"{cname}/{k}/{f['name']}:split"), arrays.get(f"{cname}/{k}/{f['name']}:thr"))
                for f in s["features"]
            )
            for t in tables:
                _check_tree(t, tables, f"{cname} stage {k}")
            stages.append(Stage(tables, np.asarray(s["weights"], np.float32), float(s["bias"]), float(s["log_prior_odds"])))
        classes[cname] = ClassModel(
            name=cname,
            stages=tuple(stages),
            threshold=float(c["threshold"]),
            low_threshold=float(c["low_threshold"]),
            smooth_sigma_px=float(c["smooth_sigma_px"]),
            min_area_px=int(c["min_area_px"]),
            needs_colour=bool(c["needs_colour"]),
            train_score=dict(c.get("train_score", {})),
            level=int(c.get("level", 0)),
        )
        _check_class(classes[cname])
    meta = {k: v for k, v in header.items() if k not in ("classes", "feature_geometry")}
    return DefectModel(classes, meta)
