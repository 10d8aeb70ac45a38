"""Saliency-based corrosion and crack detection with learned probabilities.

After Bonnin-Pascual and Ortiz, "A Probabilistic Approach for Defect Detection Based on Saliency
Mechanisms" (ETFA 2014): conspicuity features over a Gaussian pyramid (intensity, colour,
orientation, symmetry), plus corrosion colour/roughness and crack ridge/line evidence, turned into
P(defect | features) by Bayes' rule with learned class-conditional likelihood tables.

Pure array-in / array-out, except :mod:`._datasets` (labelled-set readers for training) and the
model file reader/writer.

    >>> model = load_model(default_model_path())
    >>> det = detect(bgr_image, model, kinds=("corrosion", "crack"))
    >>> det.prob, det.mask, det.regions

The learned engine (``--engine onnx``, an EfficientNet-Lite0 U-Net on onnxruntime) has the same outputs,
plus condition states of corrosion (``det.severity``):

    >>> det = detect_onnx(bgr_image, load_onnx_model(default_onnx_path()))

and the fused engine (``--engine fused``, per-class weighted mean of both, fitted on validation images):

    >>> det = detect_fused(bgr_image, load_fused_model())

Callers that take an engine by name (``inspect-pipe detect``, the pipeline) load it with
:func:`load_engine` (``ENGINES``; ``DEFAULT_ENGINE`` is ``onnx``).
"""

from __future__ import annotations

from pathlib import Path

from ._combine import combine_max, combine_normalised_sum, conspicuity_maps
from ._datasets import SETS, SPLIT_RULE, LabelledImage, generic_set, labelled_set, split_of
from ._engines import DEFAULT_ENGINE, ENGINES, DetectorEngine, load_engine
from ._detect import TILE_PX, Detection, Region, class_probabilities, class_probabilities_u8, decide, detect
from ._features import FEATURE_NAMES, FeatureStack, compute_features
from ._fused import FusedModel, default_fused_path, detect_fused, load_fused_model
from ._onnx_detect import OnnxModel, default_onnx_path, detect_onnx, detect_onnx_batch, load_onnx_model, onnx_probabilities_u8
from ._model import ClassModel, DefectModel, load_model, save_model
from ._train import DEFAULT_CONFIGS, ClassTrainConfig, train_class, train_model

MODEL_VERSION = "1"
KINDS = ("corrosion", "crack")  # what --kind all means; "surface" (steel-strip saliency) is opt-in


def default_model_path() -> Path:
    """The model shipped inside the package."""
    return Path(__file__).parent / "models" / f"defects_v{MODEL_VERSION}.npz"


__all__ = [
    "DEFAULT_ENGINE", "ENGINES", "DetectorEngine", "load_engine",
    "FEATURE_NAMES", "KINDS", "MODEL_VERSION", "SPLIT_RULE", "TILE_PX",
    "ClassModel", "ClassTrainConfig", "DEFAULT_CONFIGS", "DefectModel", "Detection", "FeatureStack",
    "LabelledImage", "Region",
    "class_probabilities", "class_probabilities_u8", "combine_max", "combine_normalised_sum",
    "compute_features", "conspicuity_maps", "decide", "default_model_path", "detect",
    "generic_set", "labelled_set", "OnnxModel", "default_onnx_path", "detect_onnx", "detect_onnx_batch",
    "load_onnx_model", "onnx_probabilities_u8", "FusedModel", "default_fused_path", "detect_fused", "load_fused_model", "load_model", "SETS", "save_model", "split_of", "train_class", "train_model",
]
