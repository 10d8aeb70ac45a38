"""OpenBLAS held to one thread while the mosaicer runs.

numpy's and scipy's OpenBLAS start a thread per core and spin-wait them on every product above a
few thousand elements. The mosaicer's products are small (bundle adjustment vectors of ~35,000
entries, 600x128 descriptor blocks) and it runs its own threads: on the shared 2-core machine the
spinning doubled the global alignment's CPU time on synth_rust_sweep (2.6 -> 1.0 s with one
thread) and a 540x540x128 product took 15 ms instead of 1. ``one_blas_thread()`` sets every
OpenBLAS loaded in the process to one thread and restores the previous count on exit (through
OpenBLAS's own ``*_set_num_threads``, as threadpoolctl does; a no-op where none is found).
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import os
import threading

_SETTERS = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads", "openblas_set_num_threads64_", "openblas_set_num_threads")
_GETTERS = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads", "openblas_get_num_threads64_", "openblas_get_num_threads")
_lock = threading.Lock()
_depth = 0
_saved: list[tuple[object, int]] = []


def _openblas_libs() -> list[tuple[object, object]]:
    """(set, get) of each OpenBLAS mapped into this process (Linux: /proc/self/maps)."""
    try:
        with open("/proc/self/maps") as fh:
            paths = sorted({line.split()[-1] for line in fh if "openblas" in line.lower() and "/" in line})
    except OSError:
        return []
    out = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path, mode=getattr(os, "RTLD_NOLOAD", 0) | os.RTLD_LOCAL)  # only one already loaded
        except OSError:
            continue
        setter = next((getattr(lib, s) for s in _SETTERS if hasattr(lib, s)), None)
        getter = next((getattr(lib, g) for g in _GETTERS if hasattr(lib, g)), None)
        if setter is not None and getter is not None:
            getter.restype = ctypes.c_int
            out.append((setter, getter))
    return out


@contextlib.contextmanager
def one_blas_thread():
    """Every loaded OpenBLAS on one thread inside the block (re-entrant, thread-safe; restored at the outermost exit)."""
    global _depth
    with _lock:
        if _depth == 0:
            _saved.clear()
            for setter, getter in _openblas_libs():
                try:
                    n = int(getter())
                    setter(ctypes.c_int(1))
                    _saved.append((setter, n))
                except Exception:  # an ABI we do not know: leave it alone
                    continue
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                for setter, n in _saved:
                    setter(ctypes.c_int(n))
                _saved.clear()


def with_one_blas_thread(fn):
    """Decorator: ``fn`` runs inside :func:`one_blas_thread`."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with one_blas_thread():
            return fn(*args, **kwargs)

    return wrapper
