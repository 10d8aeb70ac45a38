"""Fused engine (``--engine fused``): a per-class weighted mean of the two engines' probabilities.

    p_fused = w_c * p_saliency + (1 - w_c) * p_onnx        (per pixel, uint8 0..255)

decided at a per-class threshold, with the onnx engine's speckle sizes. The weights ``w_c`` (a
grid of 0, 0.1, ..., 1) and thresholds are fitted on the onnx network's VALIDATION images only
(the 'train' part of the split with ``sha1("val:<set>/<stem>") % 5 == 0``, ``_onnx_train.VAL_RULE``);
the 'eval' part is never read. Refit with one command (about a minute on 2 cores):

    python -m inspect_pipe.saliency_defects._fused ../shared/data/defects -o inspect_pipe/saliency_defects/models/fused_v2.json

The parameters live in a small versioned JSON file (``models/fused_v2.json``) that records the
split they were fitted on, the validation figure of every weight, and the SHA-256 of the two
model files they were fitted for.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._core import OPERATING_RANGE_U8, SET_OF_CLASS, TILE_PX, decide_u8
from ._detect import Detection, class_probabilities_u8
from ._model import DefectModel, load_model
from ._onnx_detect import (
    MIN_AREA_PX,
    TOL_PX,
    OnnxModel,
    _check,
    _detection,
    load_onnx_model,
    onnx_maps,
    onnx_probabilities_u8,
    with_condition_states,
)

FUSED_FORMAT = "inspect_pipe.defect_fused/1"
CLASSES = ("corrosion", "crack", "surface")
WEIGHT_GRID = tuple(round(0.1 * i, 1) for i in range(11))
#: What a class's weight is chosen by on the validation images: F at the operating point (2 px
#: tolerance for cracks, strict pixels for corrosion) or, for the steel-surface salient-object
#: protocol, max F-beta (beta^2 = 0.3). The threshold is the best-F level of the fused map.
CRITERION = {"crack": "F", "corrosion": "F", "surface": "Fbeta"}


@dataclass(frozen=True)
class FusedModel:
    params_path: Path
    params: dict
    saliency: DefectModel
    onnx: OnnxModel
    weights: dict[str, float]
    thresholds_u8: dict[str, int]
    min_area_px: dict[str, int]

    @property
    def version(self) -> str:
        return str(self.params.get("version", "?"))


def sha256_of(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def fuse_u8(p_sal: np.ndarray, p_onnx: np.ndarray, w: float) -> np.ndarray:
    """w * p_sal + (1 - w) * p_onnx, both uint8 maps of one shape, rounded to uint8."""
    if p_sal.shape != p_onnx.shape:
        raise ValueError(f"probability maps differ in shape: {p_sal.shape} vs {p_onnx.shape}")
    f = np.float32(w) * p_sal.astype(np.float32) + np.float32(1 - w) * p_onnx.astype(np.float32)
    return np.clip(np.rint(f), 0, 255).astype(np.uint8)


def default_fused_path() -> Path:
    return Path(__file__).parent / "models" / "fused_v2.json"


def load_fused_params(path: Path) -> dict:
    """Read and check a parameter file. Raises ValueError with a one-line reason."""
    path = Path(path)
    if not path.is_file():
        raise ValueError("fused parameter file not found" if not path.exists() else "a directory, not a fused parameter file")
    try:
        p = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise ValueError("fused parameter file is not JSON") from None
    if not isinstance(p, dict) or p.get("format") != FUSED_FORMAT:
        raise ValueError(f"fused parameter format {p.get('format') if isinstance(p, dict) else None!r}, expected {FUSED_FORMAT!r}")
    cls = p.get("classes")
    if not isinstance(cls, dict) or not cls:
        raise ValueError("fused parameter file has no classes")
    for k, c in cls.items():
        w, t = c.get("weight_saliency") if isinstance(c, dict) else None, c.get("threshold_u8") if isinstance(c, dict) else None
        if isinstance(w, bool) or not isinstance(w, (int, float)) or not 0 <= w <= 1 or \
                isinstance(t, bool) or not isinstance(t, int) or not 1 <= t <= 255:
            raise ValueError(f"fused parameters for {k!r}: weight must be in [0, 1] and threshold in 1..255")
        area = c.get("min_area_px", 0)
        if isinstance(area, bool) or not isinstance(area, int) or not 0 <= area <= 1_000_000:
            raise ValueError(f"fused parameters for {k!r}: min_area_px must be a whole number of pixels, 0..1000000")
    engines = p.get("engines") or {}
    if not isinstance(engines, dict) or not all(isinstance(e, dict) and isinstance(e.get("sha256", ""), str)
                                                and isinstance(e.get("file", ""), (str, type(None))) for e in engines.values()):
        raise ValueError("fused parameters: 'engines' must map each engine to {file, sha256}")
    return p


def load_fused_model(params_path: Path | None = None, *, saliency_path: Path | None = None,
                     onnx_path: Path | None = None, threads: int = 1) -> FusedModel:
    """Both engines' models and the fusion parameters (defaults: the shipped files)."""
    from . import default_model_path
    from ._onnx_detect import default_onnx_path

    params_path = Path(params_path or default_fused_path())
    p = load_fused_params(params_path)
    sal_path, onx_path = Path(saliency_path or default_model_path()), Path(onnx_path or default_onnx_path())
    for engine, used in (("saliency", sal_path), ("onnx", onx_path)):
        fitted = (p.get("engines") or {}).get(engine) or {}
        if fitted.get("sha256") and used.is_file() and sha256_of(used) != fitted["sha256"]:
            raise ValueError(f"fused parameters were fitted for other {engine} weights than {used.name}'s (its SHA-256 is not "
                             f"the one recorded for {fitted.get('file')!r}; refit: python -m inspect_pipe.saliency_defects._fused DATA -o PARAMS.json)")
    sal = load_model(sal_path)
    onx = load_onnx_model(onx_path, threads=threads)
    if onnx_path is None:  # the shipped network: the corrosion it decides gets v6's states, as with detect
        onx = with_condition_states(onx, threads=threads)
    cls = {k: c for k, c in p["classes"].items() if k in sal.classes and k in onx.classes}
    return FusedModel(params_path, p, sal, onx,
                      {k: float(c["weight_saliency"]) for k, c in cls.items()},
                      {k: int(c["threshold_u8"]) for k, c in cls.items()},
                      {k: int(c.get("min_area_px", MIN_AREA_PX.get(k, 64))) for k, c in cls.items()})


def _check_kinds(model: FusedModel, kinds) -> None:
    for k in kinds:
        if k not in model.weights:
            raise ValueError(f"fused parameters have no class {k!r} (have {', '.join(model.weights)})")


def fused_maps(image: np.ndarray, model: FusedModel, kinds, *, tile_px: int = TILE_PX):
    """(per-class fused maps (uint8), the network's condition-state map or None). Both engines
    tile large images on the core's grid, with tiles of ``tile_px`` and their own overlaps."""
    _check_kinds(model, kinds)
    _check(image)
    ps = class_probabilities_u8(image, model.saliency, kinds, tile_px=tile_px)
    po, states = onnx_maps(image, model.onnx, kinds=kinds, tile_px=tile_px)
    return {k: fuse_u8(ps[k], po[k], model.weights[k]) for k in kinds}, states


def fused_probabilities_u8(image: np.ndarray, model: FusedModel, kinds, *, tile_px: int = TILE_PX) -> dict[str, np.ndarray]:
    """Per-class fused maps (uint8), see :func:`fused_maps`."""
    return fused_maps(image, model, kinds, tile_px=tile_px)[0]


def detect_fused(image: np.ndarray, model: FusedModel, *, kinds=("corrosion", "crack"), tile_px: int = TILE_PX) -> Detection:
    """Like :func:`detect`, on the fused maps; decided corrosion pixels get the network's
    condition state. Raises ValueError for an unusable image (the saliency engine's rules:
    colour needed for corrosion; the network's: sides >= 32 px)."""
    probs, states = fused_maps(image, model, kinds, tile_px=tile_px)
    return _detection(probs, model, kinds, states)


# ----------------------------------------------------------------------------- fitting


def _val_maps(data: Path, cls: str, sal: DefectModel, onx: OnnxModel):
    from ._datasets import labelled_set
    from ._onnx_train import is_val

    set_name = SET_OF_CLASS[cls]
    items = [it for it in labelled_set(Path(data) / set_name, split="train") if is_val(set_name, it.stem)]
    out = []
    for it in items:
        img, gt = it.load()
        out.append((class_probabilities_u8(img, sal, (cls,))[cls], onnx_probabilities_u8(img, onx, kinds=(cls,))[cls], gt))
    return [it.stem for it in items], out


def score_weight(maps, cls: str, w: float, threshold_u8: int | None = None) -> dict:
    """Summed-count figures of the fused maps of (p_sal, p_onnx, gt) triples at one weight:
    best F and its threshold, F at ``threshold_u8`` (default: that best one) after speckle
    removal, and for 'surface' the max F-beta."""
    from ._metrics import best_f, max_fbeta, saliency_curves, tolerance_counts

    tol = TOL_PX[cls]
    sums = op = None
    P, R = [], []
    fused = []
    for ps, po, gt in maps:
        f = fuse_u8(ps, po, w)
        fused.append(f)
        c = tolerance_counts(f, gt, tol)
        sums = c if sums is None else sums + c
        if cls == "surface":
            pr, rc, _ = saliency_curves(f, gt)
            P.append(pr)
            R.append(rc)
    best, t = best_f(sums, *OPERATING_RANGE_U8)
    t = t if threshold_u8 is None else threshold_u8
    for f, (_, _, gt) in zip(fused, maps):
        m = decide_u8(f, t, MIN_AREA_PX[cls])[0]
        c = tolerance_counts(m.astype(np.uint8) * 255, gt, tol)
        op = c if op is None else op + c
    out = {"best_F": round(best, 4), "threshold_u8": int(t), "F": round(float(op.prf()[2][255]), 4)}
    if P:
        out["Fbeta"] = round(max_fbeta(P, R), 4)
    return out


def fit_fused(data: Path, *, saliency_path: Path | None = None, onnx_path: Path | None = None,
              version: str = "1", log=print) -> dict:
    """Choose each class's weight and threshold on the validation images (see module doc)."""
    from . import default_model_path
    from ._datasets import SPLIT_RULE
    from ._onnx_detect import default_onnx_path
    from ._onnx_train import VAL_RULE

    sp, op = Path(saliency_path or default_model_path()), Path(onnx_path or default_onnx_path())
    sal, onx = load_model(sp), load_onnx_model(op, threads=1)
    classes = {}
    for cls in CLASSES:
        stems, maps = _val_maps(data, cls, sal, onx)
        if not maps:
            raise ValueError(f"{data}: no validation images for {cls} ({SET_OF_CLASS[cls]})")
        curve = {f"{w:.1f}": score_weight(maps, cls, w) for w in WEIGHT_GRID}
        key = CRITERION[cls]
        wbest = max(WEIGHT_GRID, key=lambda w: (curve[f"{w:.1f}"][key], -w))  # ties: more network
        best = curve[f"{wbest:.1f}"]
        log(f"{cls}: weight_saliency {wbest:.1f}, threshold {best['threshold_u8']}, validation {key} {best[key]:.3f} "
            f"(saliency alone {curve['1.0'][key]:.3f}, onnx alone {curve['0.0'][key]:.3f})")
        classes[cls] = {"weight_saliency": wbest, "threshold_u8": best["threshold_u8"],
                        "min_area_px": MIN_AREA_PX[cls], "criterion": key,
                        "validation": {"set": SET_OF_CLASS[cls], "n_images": len(maps), "images": stems,
                                       "by_weight": curve}}
    return {
        "format": FUSED_FORMAT,
        "version": version,
        "rule": "p = w * p_saliency + (1 - w) * p_onnx per class (uint8); decision p >= threshold_u8; "
                "components below min_area_px removed",
        "fitted_on": {"split": "validation", "split_rule": SPLIT_RULE, "val_rule": VAL_RULE,
                      "note": "the 'eval' part is never read; the saliency tables were trained on the whole "
                              "'train' part, so its validation maps are in-sample (favours saliency)"},
        "weight_grid": list(WEIGHT_GRID),
        "engines": {"saliency": {"file": sp.name, "sha256": sha256_of(sp)},
                    "onnx": {"file": op.name, "sha256": sha256_of(op)}},
        "classes": classes,
    }


#: CPU time of one 752 x 480 frame (corrosion + crack, whole detection, one thread) of each engine,
#: as loaded by ``detect`` (onnx: v5 deciding, v6's condition states at ``STATES_SCALE`` 0.375;
#: fused: the same with the saliency tables), the median of 12 interleaved rounds in one process, two
#: runs (2026-11-29 15:40, AMD EPYC, 2 cores; v1 deciding with v6's states 35 ms, v6 alone 40 ms,
#: v5 alone with its own head 41 ms; docs/detect_onnx.md). The Intel Xeon host of 2026-11-27 ran the
#: same frame about 1.5x slower (saliency 85 ms).
FRAME_CPU_MS = {"onnx": 45.0, "saliency": 56.0, "fused": 95.0}
#: The per-frame time target of the default engine (issue 21: 60 ms on one core).
FRAME_MS_TARGET = 60.0
#: The default engine is the fastest whose mean validation figure is within this of the best.
DEFAULT_MARGIN = 0.01


def validation_scores(params: dict) -> dict[str, dict[str, float]]:
    """Each engine's validation figure per class (``CRITERION``), read from a fitted parameter
    file: the network alone is weight 0, saliency alone weight 1, fused the fitted weight."""
    out: dict[str, dict[str, float]] = {"onnx": {}, "saliency": {}, "fused": {}}
    for cls, c in params["classes"].items():
        key, bw = c["criterion"], c["validation"]["by_weight"]
        out["onnx"][cls] = float(bw["0.0"][key])
        out["saliency"][cls] = float(bw["1.0"][key])
        out["fused"][cls] = float(bw[f"{float(c['weight_saliency']):.1f}"][key])
    return out


def default_engine_on_validation(params: dict, margin: float = DEFAULT_MARGIN, *, frame_ms: dict | None = None,
                                 target_ms: float | None = FRAME_MS_TARGET) -> str:
    """The engine ``inspect-pipe detect`` should use by default, chosen on the validation images
    only: among the engines within the per-frame time target (all of them when ``target_ms`` is
    None or none meets it), the fastest whose mean validation figure over the classes is within
    ``margin`` of the best of them."""
    frame_ms = frame_ms or FRAME_CPU_MS
    scores = validation_scores(params)
    mean = {e: float(np.mean(list(v.values()))) for e, v in scores.items()}
    ok = [e for e in mean if target_ms is None or frame_ms[e] <= target_ms] or list(mean)
    best = max(mean[e] for e in ok)
    return next(e for e in sorted(ok, key=lambda e: frame_ms[e]) if mean[e] >= best - margin)


def main(argv=None) -> None:
    import argparse

    import cv2

    ap = argparse.ArgumentParser(description="Fit the fused engine's weights on the validation images.")
    ap.add_argument("data", type=Path, help="folder holding crackforest/, vt_corrosion_cs/, sd_saliency_900/")
    ap.add_argument("-o", "--out", type=Path, default=default_fused_path())
    ap.add_argument("--version", default="1")
    a = ap.parse_args(argv)
    cv2.setNumThreads(1)
    params = fit_fused(a.data, version=a.version)
    a.out.write_text(json.dumps(params, indent=1) + "\n")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
