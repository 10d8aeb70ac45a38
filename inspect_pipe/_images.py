"""One check every image reader shares: a JPEG or PNG cut short (a copy interrupted, a card pulled)
decodes without an error in OpenCV, which fills the missing rows with grey and prints a stray
libjpeg line; so it is refused by its missing end marker before it is decoded."""

from __future__ import annotations

from pathlib import Path


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
