"""File adapters: a folder of images as a :class:`FrameSource`."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from inspect_pipe._images import imread, truncation
from inspect_pipe.errors import InputError

from ._register import FrameError

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm", ".ppm"}


def read_image(path: Path) -> np.ndarray:
    """8-bit BGR (or grey) image; raises :class:`FrameError` with the reason."""
    why = truncation(path)
    if why:
        raise FrameError(why)
    img = imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise FrameError("unreadable or corrupt image")
    if img.dtype == np.uint16:
        img = (img / 257).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise FrameError(f"unsupported pixel type {img.dtype}")
    if img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return img


class FolderSource:
    """Images of a folder, sorted by name, loaded one at a time."""

    def __init__(self, folder: Path) -> None:
        folder = Path(folder)
        if not folder.exists():
            raise InputError(folder, "not found", "give a sweep directory or a folder of images")
        if not folder.is_dir():
            raise InputError(folder, "not a directory", "give a sweep directory or a folder of images")
        self.folder = folder
        self.paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())
        if not self.paths:
            raise InputError(folder, "no images found", f"expected files ending in {', '.join(sorted(IMAGE_SUFFIXES))}")

    def __len__(self) -> int:
        return len(self.paths)

    def name(self, i: int) -> str:
        return self.paths[i].name

    def path(self, i: int) -> Path:
        return self.paths[i]

    def load(self, i: int) -> np.ndarray:
        return read_image(self.paths[i])
