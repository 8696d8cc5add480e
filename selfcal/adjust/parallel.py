"""A pass over the chunks of the points on the machine's cores.

The linearisation, the reduction, the residuals, the leverages, the point cofactors and the evaluation of the
AP columns go over the points (observations) in chunks (``Problem.chunks``); the first two sum each chunk's
products into a few arrays (the image blocks, the camera-parameter blocks), the others write their own rows.
The work of a chunk is NumPy, BLAS and Numba kernels compiled with ``nogil``, which release the interpreter
lock, so two threads that take alternate chunks run side by side. Each of two groups of chunks sums into
arrays of its own, added at the end in a fixed order, whether the groups ran on two threads or one after the
other: the result is the same bit for bit on one thread as on two, in whatever order the threads ran (the
Dask batch, one thread per worker, equals the serial run). Inside the pass every BLAS call runs on one thread.
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
    """``work(chunk, sums)`` of every chunk. The chunks go to MAX_WORKERS groups (group g takes chunks g, g + n,
    ...), each with its own ``sums = new_sums()``, and the groups to the threads: the sums, and so the result,
    are the same bit for bit on one thread as on two. Returns the results in chunk order and each group's sums
    (group order). A pass started inside another one runs on its caller's thread (the pool's thread may be the
    caller)."""
    n = min(MAX_WORKERS, len(chunks))
    if n <= 1:
        sums = new_sums()
        return [work(chunk, sums) for chunk in chunks], [sums]
    parts = [new_sums() for _ in range(n)]

    def run(group: int) -> list:
        inside = getattr(_state, "inside", False)
        _state.inside = True
        try:
            return [work(chunks[i], parts[group]) for i in range(group, len(chunks), n)]
        finally:
            _state.inside = inside

    results: list = [None] * len(chunks)
    with linalg.blas_on_one_thread():          # the pass's threads are the parallelism; on one, the same calls
        if getattr(_state, "inside", False) or workers() < n:
            done = [run(group) for group in range(n)]
        else:
            others = [_pool().submit(run, group) for group in range(1, n)]
            try:
                mine = run(0)
            finally:
                concurrent.futures.wait(others)     # no worker outlives the pass, whatever happened here
            done = [mine] + [future.result() for future in others]
    for group, part in enumerate(done):
        results[group::n] = part
    return results, parts
