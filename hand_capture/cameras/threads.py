"""Process tuning for real-time loops: the BLAS thread pool, and reuse of freed memory.

numpy's bundled OpenBLAS starts one thread per core. On a small shared machine a real-time
loop of many small matrix products (the hand model's skinning, eq. II.8) then waits for
descheduled BLAS threads: measured on the 2-core project machine under load, one
``HandModel.vertices`` call took 12 ms with the default pool and 0.4 ms with one thread.
Camera and tracker nodes call :func:`limit_blas_threads` once at start-up; the touch encoder
runs its small products inside :func:`blas_threads`.

:func:`reuse_freed_memory` keeps image-sized blocks in the heap once freed (glibc otherwise
returns them to the kernel, and every frame page-faults its fresh buffers in again).
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Iterator
from contextlib import contextmanager
from functools import cache

__all__ = ["blas_threads", "get_blas_threads", "limit_blas_threads", "reuse_freed_memory"]

_M_TRIM_THRESHOLD = -1  # glibc mallopt parameters (malloc.h)
_M_MMAP_THRESHOLD = -3

_GET_SYMBOLS = (
    "scipy_openblas_get_num_threads64_",
    "scipy_openblas_get_num_threads_64_",
    "scipy_openblas_get_num_threads",
    "openblas_get_num_threads64_",
    "openblas_get_num_threads",
)
_SYMBOLS = (
    "scipy_openblas_set_num_threads64_",
    "scipy_openblas_set_num_threads_64_",
    "scipy_openblas_set_num_threads",
    "openblas_set_num_threads64_",
    "openblas_set_num_threads",
)


@cache
def _openblas_libs() -> tuple[ctypes.CDLL, ...]:
    """The OpenBLAS libraries loaded in this process (looked up once; hot paths call this)."""
    import numpy  # noqa: F401  (make sure numpy's BLAS is loaded)

    try:
        with open("/proc/self/maps") as fh:
            paths = sorted({line.split()[-1] for line in fh
                            if "openblas" in line.lower() and line.split()[-1].startswith("/")})
    except OSError:
        return ()
    libs = []
    for path in paths:
        try:
            libs.append(ctypes.CDLL(path))
        except OSError:
            continue
    return tuple(libs)


def get_blas_threads() -> int | None:
    """Threads of the first loaded OpenBLAS (None when it cannot be queried)."""
    for lib in _openblas_libs():
        for sym in _GET_SYMBOLS:
            fn = getattr(lib, sym, None)
            if fn is not None:
                fn.restype = ctypes.c_int
                return int(fn())
    return None


@contextmanager
def blas_threads(n: int = 1) -> Iterator[None]:
    """Run a block with ``n`` BLAS threads, then restore the previous count."""
    before = get_blas_threads()
    limit_blas_threads(n, set_env=False)
    try:
        yield
    finally:
        if before is not None:
            limit_blas_threads(before, set_env=False)


def limit_blas_threads(n: int = 1, set_env: bool = True) -> list[str]:
    """Set every loaded OpenBLAS library to ``n`` threads; returns the libraries changed.

    Works on Linux (reads ``/proc/self/maps``); elsewhere it only sets the environment
    variables that child processes inherit and returns an empty list.
    """
    n = max(int(n), 1)
    if set_env:
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
            os.environ.setdefault(var, str(n))
    changed = []
    for lib in _openblas_libs():
        for sym in _SYMBOLS:
            fn = getattr(lib, sym, None)
            if fn is not None:
                fn.argtypes = [ctypes.c_int]
                fn.restype = None
                fn(n)
                changed.append(lib._name)
                break
    return changed


def reuse_freed_memory(mmap_threshold: int = 32 << 20, trim_threshold: int = 64 << 20) -> bool:
    """Let glibc's malloc reuse freed blocks up to ``mmap_threshold`` bytes; True if set.

    By default glibc serves blocks over 128 KiB (a 320x240 depth image is 150 KB, its render
    buffers 75-600 KB) with their own ``mmap`` and unmaps them when freed, and trims the top
    of the heap beyond 128 KiB; a node that allocates and frees such arrays every frame then
    page-faults all of them in again each time. Measured on the 2-core machine: 0.4 of the
    1.4 ms of the renderer's output step. With higher mmap and trim thresholds the freed
    memory stays in the process (at most about ``trim_threshold`` unused) for the next
    frame. Process-wide; a no-op returning False where ``mallopt`` does not exist (not glibc).
    """
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold))) and \
        bool(mallopt(_M_TRIM_THRESHOLD, int(trim_threshold)))
