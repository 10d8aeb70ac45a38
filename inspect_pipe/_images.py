"""One check every image reader shares: a JPEG or PNG cut short (a copy interrupted, a card pulled)
decodes without an error in OpenCV, which fills the missing rows with grey and prints a stray
libjpeg line; so it is refused by its missing end marker before it is decoded. And one reader,
:func:`imread`, for which a file OpenCV refuses to decode is unreadable, not an exception."""

from __future__ import annotations

import re
import sys
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


#: What a decoder prints when it decodes (or gives up on) damaged data; anything else on stderr
#: during a read (a warning, another thread's output, a progress bar) is not about the image.
_DAMAGE = re.compile(r"Corrupt JPEG data|Premature end of JPEG|libpng error|TIFF_Error|TIFFReadDirectory|TIFFFetchDirectory|imread_.*can't read")
#: libjpeg's note about a few padding bytes before a marker (a writer's quirk; no pixel changes);
#: hundreds of them are scan data lost (a zeroed block).
_HARMLESS = re.compile(r"\b([1-9]|1[0-6]) extraneous bytes before marker")


def imread_checked(path: Path | str, flags: int = cv2.IMREAD_COLOR) -> tuple[np.ndarray | None, str]:
    """(``cv2.imread``'s image, the damage its decoder reported: "" when none; what OpenCV
    raises, cv2.error, is raised). libjpeg decodes a JPEG whose data is damaged but whose end
    marker is there (grey rows, shifted blocks) and only prints "Corrupt JPEG data" to stderr;
    libtiff and libpng print their errors the same way. This reads them from the process's stderr
    (file descriptor 2), redirected to a temporary file for the duration of the read, and keeps
    only the decoders' damage reports (:data:`_DAMAGE`). Not for threads: the redirection is
    process-wide (the CLI reads its inputs one at a time). Where stderr cannot be redirected (it is
    closed, no temporary file can be made) the image is read without listening."""
    import os
    import tempfile

    try:
        said = tempfile.TemporaryFile()
        saved = os.dup(2)
    except OSError:
        return cv2.imread(str(path), flags), ""
    with said:
        if sys.stderr is not None:
            sys.stderr.flush()
        os.dup2(said.fileno(), 2)
        try:
            img = cv2.imread(str(path), flags)
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        said.seek(0)
        text = said.read(65536).decode("utf-8", "replace")
    # OpenCV's own log prefix ("[ERROR:0@0.6] global grfmt_tiff.cpp:117 TIFF_Error ") is left out
    lines = [re.sub(r"^\[\s*\w+:[\d@.]+\] global \S+ (TIFF_Error |imread_ )?", "", ln.strip())
             for ln in text.splitlines() if _DAMAGE.search(ln) and not _HARMLESS.search(ln)]
    return img, "; ".join(dict.fromkeys(lines))[:200]
