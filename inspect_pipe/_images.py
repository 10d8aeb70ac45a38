"""One check every image reader shares: a JPEG or PNG cut short (a copy interrupted, a card pulled)
decodes without an error in OpenCV, which fills the missing rows with grey and prints a stray
libjpeg line; so it is refused by its missing end marker before it is decoded. And one reader,
:func:`imread`, for which a file OpenCV refuses to decode is unreadable, not an exception."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def truncation(path: Path) -> str:
    """Why a JPEG or PNG file is cut short or not what its name says ("" when it looks whole)."""
    path = Path(path)
    suffix = path.suffix.lower()
    try:
        size = path.stat().st_size
        with path.open("rb") as fh:
            head = fh.read(8)
            fh.seek(max(size - 16, 0))
            tail = fh.read()
    except OSError as err:
        return f"cannot read ({err.strerror})"
    if size == 0:
        return "empty file"
    if suffix in {".jpg", ".jpeg"}:
        if head[:2] != b"\xff\xd8":
            return "not a JPEG file"
        if b"\xff\xd9" not in tail:
            return "truncated JPEG (no end-of-image marker)"
    if suffix == ".png":
        if head != b"\x89PNG\r\n\x1a\n":
            return "not a PNG file"
        if b"IEND" not in tail:
            return "truncated PNG (no IEND chunk)"
    return ""


def imread(path: Path | str, flags: int = cv2.IMREAD_COLOR) -> np.ndarray | None:
    """``cv2.imread``, with what OpenCV raises for a file it will not decode (a header claiming
    more than 2^30 pixels, a damaged TIFF directory) read as it reads any unreadable file: None."""
    try:
        return cv2.imread(str(path), flags)
    except cv2.error:
        return None
