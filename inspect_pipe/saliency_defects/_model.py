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
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ._features import N_HUE, N_SAT, FeatureStack, _LINES

FORMAT = "inspect_pipe.defect_model/1"
N_BINS = 48
CONTEXT_NAMES = ("z", "z_mean", "z_box15", "z_box31", "z_box63", "z_line", "z_line2")
#: context features reach this far (px) beyond the first stage's support
CONTEXT_SUPPORT_PX = 32  # half of the largest box (63 px); lines reach 22 px


@dataclass(frozen=True)
class FeatureTable:
    """LLR table of one feature: continuous values are binned uniformly on [lo, hi] (clipped)."""

    name: str
    lo: float
    hi: float
    llr: np.ndarray  # (n_bins,) float32
    categorical: bool = False

    def bins(self, x: np.ndarray) -> np.ndarray:
        """Bin index per pixel, uint8; values past the last bin give 255 (see :meth:`lut`)."""
        x = np.ascontiguousarray(x, np.float32)
        if self.categorical:
            return cv2.convertScaleAbs(cv2.max(x, 0.0))
        scale = self.llr.shape[0] / max(self.hi - self.lo, 1e-9)
        # floor((x - lo) * scale) for x >= lo, saturated at 255: one pass, no temporaries
        return cv2.convertScaleAbs(cv2.max(x, float(self.lo)), alpha=scale, beta=-self.lo * scale - 0.5 + 1e-4)

    def lut(self, weight: float = 1.0) -> np.ndarray:
        lut = np.full(256, self.llr[-1], np.float32)
        lut[: self.llr.shape[0]] = self.llr
        return lut * np.float32(weight)

    def lookup(self, x: np.ndarray, weight: float = 1.0) -> np.ndarray:
        return cv2.LUT(self.bins(x), self.lut(weight))


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

    def logit(self, feats, *, naive: bool = False) -> np.ndarray:
        """``feats``: mapping name -> (H, W) float32. ``naive``: unweighted tables + prior."""
        acc = None
        for t, w in zip(self.tables, self.weights):
            term = t.lookup(feats[t.name], 1.0 if naive else float(w))
            acc = term if acc is None else cv2.add(acc, term)
        return acc + np.float32(self.log_prior_odds if naive else self.bias)


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


def context_features(z: np.ndarray) -> dict[str, np.ndarray]:
    """Context maps of a logit map ``z`` (H, W) float32: itself, its local means over 7 to 63 px
    boxes (region support), and its best mean along 11 px and 22 px lines (connected, elongated
    support: the role of percolation in crack detection)."""
    h, w = z.shape
    zc = np.clip(z, -12, 12).astype(np.float32)
    out = {"z": zc, "z_mean": cv2.blur(zc, (7, 7))}
    for n in (15, 31, 63):
        out[f"z_box{n}"] = cv2.blur(zc, (n, n), borderType=cv2.BORDER_REFLECT_101)
    out["z_line"] = _best_line(zc)
    # half resolution on an even-sized copy, so a tile and the whole image sample the same grid
    ze = cv2.copyMakeBorder(zc, 0, h % 2, 0, w % 2, cv2.BORDER_REFLECT_101)
    half = cv2.resize(ze, (ze.shape[1] // 2, ze.shape[0] // 2), interpolation=cv2.INTER_AREA)
    up = cv2.resize(_best_line(half), (ze.shape[1], ze.shape[0]), interpolation=cv2.INTER_LINEAR)
    out["z_line2"] = up[:h, :w]
    return out


def class_logit(fs: FeatureStack, cm: ClassModel, *, naive: bool = False) -> np.ndarray:
    """Final logit map (H, W) float32 of class ``cm`` (stages chained, then smoothed)."""
    feats = {n: fs.data[i] for i, n in enumerate(fs.names)}
    z = cm.stages[0].logit(feats, naive=naive)
    for st in cm.stages[1:]:
        z = st.logit(context_features(z), naive=naive)
    if cm.smooth_sigma_px > 0:
        z = cv2.GaussianBlur(z, (0, 0), cm.smooth_sigma_px)
    return z


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
                feats.append({"name": t.name, "lo": t.lo, "hi": t.hi, "categorical": t.categorical})
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
        }
    header = dict(model.meta)
    header["format"] = FORMAT
    header["classes"] = classes
    header["feature_geometry"] = {"n_hue": N_HUE, "n_sat": N_SAT}
    arrays["meta"] = np.frombuffer(json.dumps(header, indent=1).encode(), np.uint8)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)


def load_model(path: Path) -> DefectModel:
    """Read a model written by :func:`save_model`. Raises ValueError on a wrong or damaged file."""
    try:
        with np.load(Path(path), allow_pickle=False) as z:
            header = json.loads(bytes(z["meta"]).decode())
            arrays = {k: z[k] for k in z.files if k != "meta"}
    except (OSError, KeyError, ValueError, json.JSONDecodeError) as err:
        raise ValueError(f"not a defect model file ({err.__class__.__name__}: {err})") from None
    if header.get("format") != FORMAT:
        raise ValueError(f"unsupported model format {header.get('format')!r}, expected {FORMAT}")
    geo = header.get("feature_geometry", {})
    if geo.get("n_hue") != N_HUE or geo.get("n_sat") != N_SAT:
        raise ValueError("model was trained with a different hue-saturation table geometry")
    classes = {}
    for cname, c in header["classes"].items():
        stages = []
        for k, s in enumerate(c["stages"]):
            tables = tuple(
                FeatureTable(f["name"], float(f["lo"]), float(f["hi"]), arrays[f"{cname}/{k}/{f['name']}"], bool(f["categorical"]))
                for f in s["features"]
            )
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
        )
    meta = {k: v for k, v in header.items() if k not in ("classes", "feature_geometry")}
    return DefectModel(classes, meta)
