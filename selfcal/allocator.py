"""Keep freed memory in the process between iterations (glibc only).

An adjustment allocates and frees arrays of tens to hundreds of megabytes in
every iteration. glibc's defaults return freed memory to the system and map
fresh pages for the next array, so the kernel zeroes the same memory again
and again; Dask's worker processes make it worse (``MALLOC_TRIM_THRESHOLD_`` of
64 KiB, set before they start). On a 254-WAP cell the system time was 9 s of
34 s under Dask's setting and 2 s with the settings below. Elsewhere (not
glibc) this does nothing.

NumPy also asks the kernel for transparent huge pages on every large array
(madvise). On a virtual machine the first touch of such memory can cost far
more than that of small pages the process has had before: 331 MB (a WAP
camera's AP columns on the 80,000-observation seed-000 block) took 0.99 s with
huge pages and 0.21 s without on this project's VM, and the writes after it
were equally fast (0.016 s). So the same call stops that request, unless the
user set ``NUMPY_MADVISE_HUGEPAGE`` (NumPy's own switch) in the environment.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import importlib
import os

__all__ = ["keep_freed_memory"]

_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD = -1, -2, -3
_done = False


def keep_freed_memory() -> bool:
    """Raise glibc's trim and mmap thresholds for this process; True if it took effect."""
    global _done
    if _done:
        return True
    _small_pages()
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    ok = all(mallopt(option, value) == 1 for option, value in (
        (_M_MMAP_THRESHOLD, 32 * 2**20),          # the largest glibc accepts; bigger arrays stay mapped
        (_M_TRIM_THRESHOLD, 2**31 - 1),
        (_M_TOP_PAD, 256 * 2**20)))
    _done = ok
    return ok


def _small_pages() -> None:
    """Stop NumPy's madvise for transparent huge pages (module docstring), unless the environment decides."""
    if "NUMPY_MADVISE_HUGEPAGE" in os.environ:
        return
    # a private function of NumPy (not in its type stubs): looked up by name, NumPy >= 2's module first
    for module in ("numpy._core.multiarray", "numpy.core.multiarray"):
        try:
            set_madvise_hugepage = getattr(importlib.import_module(module), "_set_madvise_hugepage")
        except (ImportError, AttributeError):
            continue
        set_madvise_hugepage(False)
        return
