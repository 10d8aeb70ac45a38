"""Crash-safe file writing shared by every step: write a temporary file beside the target, then
rename it into place, so a reader sees the old file or the whole new one, never a part."""

from __future__ import annotations

import errno
import json
import os
import tempfile
import threading
from pathlib import Path
from typing import Any

import cv2
import numpy as np


_UMASK: int | None = None
_UMASK_LOCK = threading.Lock()


def current_umask() -> int:
    """The process's umask, read without leaving it changed for a moment where the kernel tells it
    (``/proc/self/status``, Linux >= 4.7); elsewhere set and restored once under a lock, then kept."""
    global _UMASK
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    with _UMASK_LOCK:
        if _UMASK is None:
            _UMASK = os.umask(0o022)
            os.umask(_UMASK)
        return _UMASK


def atomic_write(path: Path, data: bytes, *, fsync: bool = True) -> None:
    """Write ``data`` to ``path`` atomically; ``fsync`` also survives power loss (slower).

    The file gets the mode ``open()`` would give a new file (0o666 less the umask: 0644 by
    default), not mkstemp's private 0600, so a colleague or a web server can read the report."""
    path = Path(path)
    if os.path.lexists(path) and not (path.is_file() or path.is_symlink()):
        # a directory, a device (/dev/full), a pipe: renaming over it would remove it, not write into it
        raise OSError(errno.EEXIST, "exists and is not a regular file (give a file path)", str(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
        os.fchmod(fd, 0o666 & ~current_umask())
        if fsync:
            os.fsync(fd)
        os.close(fd)
        fd = -1
        os.replace(tmp, path)
    except BaseException as err:
        if fd >= 0:
            os.close(fd)
        Path(tmp).unlink(missing_ok=True)
        if isinstance(err, OSError) and err.filename is None and err.errno is not None:
            # a full disk (ENOSPC) or a failing device surfaces from os.write without a name: name the file
            raise OSError(err.errno, err.strerror or os.strerror(err.errno), str(path)) from None
        raise


def write_json(path: Path, doc: Any) -> None:
    atomic_write(path, (json.dumps(doc, indent=1) + "\n").encode())


def write_png(path: Path, image: np.ndarray, *, compression: int = 3) -> None:
    ok, buf = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, compression])
    if not ok:
        raise OSError(f"{path}: PNG encoding failed")
    atomic_write(path, buf.tobytes())
