"""Readers for the labelled defect sets and the reproducible train / evaluation split.

This is the one I/O module of the package; the algorithms never read files. Each reader returns
:class:`LabelledImage` items whose ``load()`` gives (image uint8 BGR or grey, ground truth bool).

Split: an image is in the evaluation part when ``sha1("<set>/<stem>")`` read as an integer is
divisible by 3 (about one third), otherwise in the training part. The rule depends only on the
file name, so it is the same on every machine and for any subset of files.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from inspect_pipe._images import imread

SPLIT_RULE = 'eval if int(sha1("<set>/<stem>").hexdigest(), 16) % 3 == 0 else train'

#: Data set name -> (folder under data/defects, class it trains).
SETS = {
    "crackforest": "crack",
    "vt_corrosion_cs": "corrosion",
    "sd_saliency_900": "surface",
}


def split_of(set_name: str, stem: str) -> str:
    """'train' or 'eval' for one image (see module doc)."""
    h = int(hashlib.sha1(f"{set_name}/{stem}".encode()).hexdigest(), 16)
    return "eval" if h % 3 == 0 else "train"


@dataclass(frozen=True)
class LabelledImage:
    set_name: str
    stem: str
    image_path: Path
    load: Callable[[], tuple[np.ndarray, np.ndarray]]
    #: (H, W) uint8 condition states (0 good, 1 fair, 2 poor, 3 severe), for sets that label them
    load_states: Callable[[], np.ndarray] | None = None


def _read(path: Path, flags: int) -> np.ndarray:
    img = imread(str(path), flags)
    if img is None:
        raise ValueError(f"{path}: unreadable image")
    return img


def _crackforest(root: Path) -> list[LabelledImage]:
    import scipy.io as sio

    items = []
    for p in sorted((root / "image").glob("*.jpg")):
        gt_path = root / "groundTruth" / f"{p.stem}.mat"
        if not gt_path.exists():
            continue

        def load(p=p, gt_path=gt_path):
            g = sio.loadmat(str(gt_path))["groundTruth"][0, 0]
            return _read(p, cv2.IMREAD_COLOR), g["Segmentation"] == 2

        items.append(LabelledImage("crackforest", p.stem, p, load))
    return items


#: VT corrosion mask colours (BGR as read by OpenCV) -> condition state (its SOURCE.md):
#: fair (surface rust), poor (pack rust, pitting), severe (section loss); black is good.
VT_STATE_BGR = {1: (0, 0, 128), 2: (0, 128, 0), 3: (0, 128, 128)}
CONDITION_STATES = ("none", "fair", "poor", "severe")


def condition_states(mask_bgr: np.ndarray) -> np.ndarray:
    """(H, W) uint8 condition state of a VT colour mask: 0 good, 1 fair, 2 poor, 3 severe."""
    out = np.zeros(mask_bgr.shape[:2], np.uint8)
    for state, bgr in VT_STATE_BGR.items():
        out[(mask_bgr == np.asarray(bgr, np.uint8)).all(-1)] = state
    return out


def _vt(root: Path) -> list[LabelledImage]:
    items = []
    for p in sorted((root / "images").glob("*.jpeg")):
        m = root / "masks" / f"{p.stem}.png"
        if not m.exists():
            continue

        def load(p=p, m=m):
            return _read(p, cv2.IMREAD_COLOR), _read(m, cv2.IMREAD_GRAYSCALE) > 0

        def load_states(m=m):
            return condition_states(_read(m, cv2.IMREAD_COLOR))

        items.append(LabelledImage("vt_corrosion_cs", p.stem, p, load, load_states))
    return items


def _sd(root: Path) -> list[LabelledImage]:
    items = []
    for p in sorted((root / "images").glob("*.bmp")):
        m = root / "ground_truth" / f"{p.stem}.png"
        if not m.exists():
            continue

        def load(p=p, m=m):
            return _read(p, cv2.IMREAD_GRAYSCALE), _read(m, cv2.IMREAD_GRAYSCALE) > 127

        items.append(LabelledImage("sd_saliency_900", p.stem, p, load))
    return items


_READERS = {"crackforest": _crackforest, "vt_corrosion_cs": _vt, "sd_saliency_900": _sd}


def labelled_set(folder: Path, set_name: str | None = None, split: str | None = None) -> list[LabelledImage]:
    """Items of one data set folder (its name picks the reader unless ``set_name`` is given),
    optionally only the 'train' or 'eval' part. Sorted by file name."""
    folder = Path(folder)
    name = set_name or folder.name
    if name not in _READERS:
        raise ValueError(f"unknown labelled set {name!r} (know {', '.join(_READERS)})")
    items = _READERS[name](folder)
    if split is not None:
        items = [it for it in items if split_of(name, it.stem) == split]
    return items


def _generic(root: Path, set_name: str) -> list[LabelledImage]:
    """Any folder with ``images/NAME.(jpg|jpeg|png|bmp|tif)`` and ``masks/NAME.png`` (non-zero = defect)."""
    items = []
    for p in sorted((root / "images").iterdir()):
        if p.suffix.lower() not in (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff"):
            continue
        m = root / "masks" / f"{p.stem}.png"
        if not m.exists():
            continue

        def load(p=p, m=m):
            return _read(p, cv2.IMREAD_COLOR), _read(m, cv2.IMREAD_GRAYSCALE) > 0

        items.append(LabelledImage(set_name, p.stem, p, load))
    return items


def generic_set(folder: Path, split: str | None = None) -> list[LabelledImage]:
    """A user's labelled folder (``images/`` + ``masks/``), named after the folder."""
    folder = Path(folder)
    items = _generic(folder, folder.name)
    if split is not None:
        items = [it for it in items if split_of(folder.name, it.stem) == split]
    return items
