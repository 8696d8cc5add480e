"""Experiment matrices: many adjustments (scenario x AP model), serially or on Dask.

Each cell of the matrix (one block, one AP model) is independent: the matrix
is a Dask task graph with one task per cell. By default a local cluster of
worker processes on this machine runs it (one BLAS thread each, so that the
workers do not compete for cores); ``scheduler=ADDRESS`` runs the same tasks
on an existing Dask cluster. Results come back to the caller as data (the
results-folder files), so workers need no shared file system. The numbers are
the same as those of the serial run.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from typing import Callable

from ..adjust import AdjustOptions, APOptions, RobustOptions, TrajectoryOptions
from ..ap import ALL_MODELS, AP_FAMILIES, parse_ap_spec, takes_grid
from ..errors import AdjustmentError
from ..report import result_files
from ..stats import ScreeningOptions, SnoopingOptions, VarianceOptions
from ..workflows.adjust import AdjustRequest, adjust_block
from ..allocator import keep_freed_memory

__all__ = ["Cell", "CellSettings", "run_cell", "run_matrix", "available_models", "PAPER_MODELS", "ALL_MODELS"]

#: the models of the seed-000 comparison, in the paper's order; "gruen" (Grün's 44
#: orthogonal polynomials) stands for BINGO's polynomial AP set (BINGO is commercial)
PAPER_MODELS = ("none", "gruen", "wavelet:db4", "wavelet:bl4", "wavelet:sym4", "wavelet:meyer")
#: every family, with its default settings


def available_models(models) -> list[str]:
    """The models whose family is registered (others are skipped)."""
    return [m for m in models if parse_ap_spec(m)[0] in AP_FAMILIES]


@dataclass(frozen=True)
class CellSettings:
    """How every cell is adjusted."""

    grid: tuple[int, int] = (9, 6)
    gnss_drift: int = 1
    imu_drift: int = 1
    lever_arm: bool = False
    boresight: bool = False
    snooping: SnoopingOptions | None = field(default_factory=SnoopingOptions)
    screening: ScreeningOptions | None = field(default_factory=ScreeningOptions)
    variance: VarianceOptions | None = None
    robust: RobustOptions | None = field(default_factory=RobustOptions)


@dataclass
class Cell:
    scenario: str
    model: str
    files: dict | None          # result files as data (see selfcal.report.result_files)
    error: str | None
    seconds: float


def run_cell(scenario: str, block, model: str, settings: CellSettings = CellSettings()) -> Cell:
    """Adjust one block with one AP model as ``selfcal adjust`` does (:func:`selfcal.workflows.adjust.adjust_block`:
    its checks, the robust cleaning, snooping and screening); failures are recorded, not raised."""
    keep_freed_memory()
    t0 = time.perf_counter()
    options = AdjustOptions(ap=APOptions(model, grid=settings.grid), trajectory=TrajectoryOptions(gnss_drift=settings.gnss_drift, imu_drift=settings.imu_drift, lever_arm=settings.lever_arm, boresight=settings.boresight))
    request = AdjustRequest(options=options, snooping=settings.snooping, screening=settings.screening,
                            variance=settings.variance, robust=settings.robust)
    try:
        adjusted = adjust_block(block, request)
    except AdjustmentError as exc:
        return Cell(scenario, model, None, str(exc), time.perf_counter() - t0)
    seconds = time.perf_counter() - t0
    extra = {"scenario": scenario, "seconds": seconds, "grid": list(settings.grid)} | adjusted.summary_extra
    files = result_files(adjusted.block, adjusted.tested, extra, settings.screening, adjusted.checks, adjusted.track)
    return Cell(scenario, model, files, None, seconds)


def run_matrix(blocks: dict, models: list[str], settings: CellSettings = CellSettings(),
               scheduler: str | None = "local", n_workers: int | None = None,
               done: Callable[[Cell], None] | None = None) -> list[Cell]:
    """Adjust every block with every model; cells in (block, model) order.

    Parameters
    ----------
    blocks : dict scenario name -> Block (pruned, as read)
    scheduler : None for a serial run in this process, "local" for a local Dask
        cluster, or the address of an existing Dask scheduler.
    n_workers : worker processes of the local cluster (default: the number of cores).
    done : called with each cell as it finishes.
    """
    cases = [(name, model) for name in blocks for model in models]
    if scheduler is None:
        cells = []
        for name, model in cases:
            cell = run_cell(name, blocks[name], model, settings)
            if done is not None:
                done(cell)
            cells.append(cell)
        return cells
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler == "local":
        single_thread = {k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                                          "SELFCAL_THREADS")}
        cluster = LocalCluster(n_workers=n_workers or os.cpu_count() or 1, threads_per_worker=1,
                               processes=True, dashboard_address=":0", env=single_thread)   # ":0": a free port (two runs at once raced for 8787)
    client = Client(cluster if cluster is not None else scheduler)
    try:
        shared = {name: client.scatter(block, broadcast=True) for name, block in blocks.items()}
        # the wavelet cells take 3-4 times as long as the others: submitted first, they leave no worker idle at the end
        first = sorted(range(len(cases)), key=lambda i: not takes_grid(cases[i][1]))
        submitted = {}
        for i in first:
            name, model = cases[i]
            submitted[i] = client.submit(run_cell, name, shared[name], model, settings, pure=False,
                                         key=f"selfcal-{name}-{model}-{time.time_ns()}")
        futures = [submitted[i] for i in range(len(cases))]      # in the cells' order
        if done is not None:
            for future in as_completed(futures):
                done(future.result())
        return client.gather(futures)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
