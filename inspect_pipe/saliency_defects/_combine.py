"""The simpler combination operators that the Bayes combination is compared with.

Each continuous feature of a class's first stage becomes a conspicuity map in [0, 1]: scaled by
the fixed range [lo, hi] recorded in its table and flipped when its likelihood ratio falls with
the value (so 1 always means "more defect-like"); the categorical hue-saturation table is not a
conspicuity map and is left out. ``max`` takes the largest map per pixel (winner-take-all), the
normalised sum their mean (Itti's linear combination of normalised maps).
"""

from __future__ import annotations

import numpy as np

from ._features import FeatureStack
from ._model import ClassModel


def conspicuity_maps(fs: FeatureStack, cm: ClassModel) -> list[np.ndarray]:
    """Normalised, defect-oriented maps (H, W) float32 in [0, 1] of ``cm``'s stage-1 features."""
    maps = []
    for t in cm.stages[0].tables:
        if t.categorical:
            continue
        x = (fs[t.name] - np.float32(t.lo)) * np.float32(1.0 / max(t.hi - t.lo, 1e-9))
        x = np.clip(x, 0, 1)
        slope = np.polyfit(np.arange(t.llr.size), t.llr, 1)[0]
        maps.append(1 - x if slope < 0 else x)
    return maps


def combine_max(maps: list[np.ndarray]) -> np.ndarray:
    return np.maximum.reduce(maps)


def combine_normalised_sum(maps: list[np.ndarray]) -> np.ndarray:
    return (np.sum(maps, axis=0) / np.float32(len(maps))).astype(np.float32)
