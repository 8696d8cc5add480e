"""A pass over the chunks of the points on the machine's cores.

The linearisation, the reduction, the residuals, the leverages, the point cofactors and the evaluation of the
AP columns go over the points (observations) in chunks (``Problem.chunks``); the first two sum each chunk's
products into a few arrays (the image blocks, the camera-parameter blocks), the others write their own rows. The work of a
chunk is NumPy, BLAS and Numba kernels compiled with ``nogil``, which release the interpreter lock, so two
threads that take alternate chunks run side by side. Each thread sums into arrays of its own, added at the
end in a fixed order: the result does not depend on which thread ran first, and differs from one thread's
sums only by rounding. Inside the pass every BLAS call runs on one thread (the threads are the parallelism).
"""
from __future__ import annotations

import concurrent.futures
import functools
import os
import threading
from typing import Callable, Sequence

from ..errors import UsageError
from . import linalg

__all__ = ["over_chunks", "workers"]

#: the most threads a pass uses
MAX_WORKERS = 2


def workers() -> int:
    """Threads a pass over the chunks uses: ``SELFCAL_THREADS`` if set (the batch's worker processes set 1: they
    are the parallelism there), else the cores this process may run on; at most MAX_WORKERS."""
    setting = os.environ.get("SELFCAL_THREADS", "").strip()
    if setting:
        try:
            return max(1, min(MAX_WORKERS, int(setting)))
        except ValueError:
            raise UsageError(f"SELFCAL_THREADS must be a whole number of threads, found '{setting}'") from None
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:                      # not Linux
        cores = os.cpu_count() or 1
    return max(1, min(MAX_WORKERS, cores))


_state = threading.local()              # .inside: this thread is running chunks of a pass


@functools.cache
def _pool() -> concurrent.futures.ThreadPoolExecutor:
    return concurrent.futures.ThreadPoolExecutor(max_workers=MAX_WORKERS - 1, thread_name_prefix="selfcal-chunks")


# a process forked after a pass (multiprocessing's default on Linux) has the pool but not its thread: the
# child makes its own, or its first pass would wait for a thread that does not exist
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_pool.cache_clear)


def over_chunks(chunks: Sequence, work: Callable, new_sums: Callable) -> tuple[list, list]:
    """``work(chunk, sums)`` of every chunk, thread t taking chunks t, t + n, ... (n threads) with its own
    ``sums = new_sums()``. Returns the results in chunk order and the sums of each thread (thread order).
    A pass started inside another one runs on its caller's thread (the pool's thread may be the caller)."""
    n = 1 if getattr(_state, "inside", False) else min(workers(), len(chunks))
    if n <= 1:
        sums = new_sums()
        return [work(chunk, sums) for chunk in chunks], [sums]
    parts = [new_sums() for _ in range(n)]

    def run(t: int) -> list:
        _state.inside = True
        try:
            return [work(chunks[i], parts[t]) for i in range(t, len(chunks), n)]
        finally:
            _state.inside = False

    results: list = [None] * len(chunks)
    with linalg.blas_on_one_thread():          # the pass's threads are the parallelism
        others = [_pool().submit(run, t) for t in range(1, n)]
        try:
            mine = run(0)
        finally:
            concurrent.futures.wait(others)         # no worker outlives the pass, whatever happened here
        done = [future.result() for future in others]
    for t, part in enumerate([mine] + done):
        results[t::n] = part
    return results, parts
