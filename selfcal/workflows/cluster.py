"""A Dask cluster for a verb: a local one started here, or a running scheduler reached at its address.

``--scheduler`` names it: ``local`` (one worker process per core), ``local:N`` (N worker processes), or a
scheduler's address (``tcp://host:8786``). A local cluster's workers run one thread each, with one BLAS thread and
one thread per pass over the points (``SELFCAL_THREADS``): the workers are the parallelism. A scheduler that cannot
be reached is an error before any work (:class:`~selfcal.errors.UsageError`, exit 2). The batch's matrices
(:mod:`selfcal.batch`) and one adjustment's points (:mod:`selfcal.adjust.distributed`) use the same.
"""
from __future__ import annotations

import contextlib
import logging
import os
from typing import Any, Callable, Iterator

from ..errors import UsageError

__all__ = ["parse_scheduler", "scheduler_workers", "dask_client", "close_quietly", "CONNECT_TIMEOUT_S", "SINGLE_THREAD"]

#: how long reaching a scheduler at an address may take before it is an error
CONNECT_TIMEOUT_S = 10.0

_DASK_LOGGERS = ("distributed", "tornado", "asyncio")

#: a local cluster's workers: one thread each, every library's threads one
SINGLE_THREAD = {k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "SELFCAL_THREADS")}


def parse_scheduler(text: str) -> tuple[str, int | None]:
    """("local", workers or None) or ("address", None) of a ``--scheduler`` value; a malformed one is a
    UsageError naming it."""
    text = text.strip()
    if text == "local":
        return "local", None
    if text.startswith("local:"):
        count = text[len("local:"):]
        if not count.isdigit() or int(count) < 1:
            raise UsageError(f"--scheduler local:N needs a whole number of workers N >= 1, found '{text}'")
        return "local", int(count)
    host, _, port = text.partition("://")[2].rpartition(":") if "://" in text else text.rpartition(":")
    if host and port.isdigit() and 0 < int(port) < 65536:
        return "address", None
    raise UsageError(f"--scheduler must be 'local', 'local:N' or a scheduler's address with its port "
                     f"(tcp://host:8786), found '{text}'")


def scheduler_workers(spec: str) -> tuple[int, bool]:
    """(workers, local) of the cluster ``spec`` names: a local cluster's count (the cores for 'local'), or the
    workers a scheduler at an address has now (reached, then left as it was)."""
    kind, workers = parse_scheduler(spec)
    if kind == "local":
        return workers or os.cpu_count() or 1, True
    with dask_client(spec) as client:
        return len(client.scheduler_info()["workers"]), False


@contextlib.contextmanager
def dask_client(spec: str, say: Callable[[str], None] | None = None) -> Iterator[Any]:
    """A :class:`dask.distributed.Client` of the cluster ``spec`` names (:func:`parse_scheduler`), closed (and a
    local cluster stopped) on the way out."""
    kind, workers = parse_scheduler(spec)
    from dask.distributed import Client, LocalCluster
    tell = say or (lambda text: None)
    cluster = None
    if kind == "local":
        n = workers or os.cpu_count() or 1
        tell(f"starting a local Dask cluster of {n} worker process{'es' if n > 1 else ''} ...")
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                               env=SINGLE_THREAD)      # ":0": a free port (two runs raced)
        client = Client(cluster)
    else:
        tell(f"connecting to the Dask scheduler at {spec} ...")
        try:
            client = Client(spec, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError, ValueError) as exc:       # (ValueError: an address Dask cannot parse)
            raise UsageError(f"cannot reach the Dask scheduler at {spec} within {CONNECT_TIMEOUT_S:g} s "
                             f"({type(exc).__name__}: {exc})") from None
    try:
        yield client
    finally:
        close_quietly(client, cluster)


def _quiet_dask() -> None:
    """Dask's loggers to CRITICAL in this process (a worker's, run there by :func:`close_quietly`)."""
    for name in _DASK_LOGGERS:
        logging.getLogger(name).setLevel(logging.CRITICAL)


def close_quietly(client, cluster) -> None:
    """Close the client, then the local cluster, with Dask's loggers silenced in the workers and here. The work
    is done (its errors came back with its futures): what a worker, its nanny or the scheduler logs while they stop
    (a heartbeat that found the scheduler gone, a connection closed under a pending read) is a traceback about the
    shutdown alone, and it ended a successful demo (issue 45). A scheduler given by its address is left as it was:
    its workers are someone else's."""
    if cluster is not None:
        try:
            client.run(_quiet_dask)
        except Exception:              # noqa: BLE001 - a worker already gone has nothing to say
            pass
    loggers = [logging.getLogger(name) for name in _DASK_LOGGERS]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.CRITICAL)
    try:
        client.close()
        if cluster is not None:
            cluster.close()
    finally:
        for logger, level in zip(loggers, levels):
            logger.setLevel(level)
