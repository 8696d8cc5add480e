"""Keep freed memory in the process between iterations (glibc only).

An adjustment allocates and frees arrays of tens to hundreds of megabytes in
every iteration. glibc's defaults return freed memory to the system and map
fresh pages for the next array, so the kernel zeroes the same memory again
and again; Dask's worker processes make it worse (``MALLOC_TRIM_THRESHOLD_`` of
64 KiB, set before they start). On a 254-WAP cell the system time was 9 s of
34 s under Dask's setting and 2 s with the settings below. Elsewhere (not
glibc) this does nothing.
"""
from __future__ import annotations

import ctypes
import ctypes.util

__all__ = ["keep_freed_memory"]

_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD = -1, -2, -3
_done = False


def keep_freed_memory() -> bool:
    """Raise glibc's trim and mmap thresholds for this process; True if it took effect."""
    global _done
    if _done:
        return True
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
