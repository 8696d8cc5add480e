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
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..adjust import AdjustOptions, APOptions, RobustOptions, TrajectoryOptions
from ..ap import ALL_MODELS, AP_FAMILIES, parse_ap_spec, takes_grid
from ..errors import AdjustmentError
from ..report import result_files
from ..stats import ScreeningOptions, SnoopingOptions, VarianceOptions
from ..workflows.adjust import AdjustRequest, adjust_block
from ..workflows.cluster import SINGLE_THREAD, close_quietly
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
    # no leave-one-out check of the control and no half-block check in a matrix: the comparison ranks the models by
    # their check points, and one re-adjustment per GCP (two per cell for the halves) would multiply its cost
    request = AdjustRequest(options=options, snooping=settings.snooping, screening=settings.screening,
                            variance=settings.variance, robust=settings.robust, control_loo=False, half_block=False)
    try:
        adjusted = adjust_block(block, request)
    except AdjustmentError as exc:
        return Cell(scenario, model, None, str(exc), time.perf_counter() - t0)
    seconds = time.perf_counter() - t0
    extra = {"scenario": scenario, "seconds": seconds, "grid": list(settings.grid),
             "prediction": _prediction(adjusted.tested.result)} | adjusted.summary_extra
    files = result_files(adjusted.block, adjusted.tested, extra, settings.screening, adjusted.checks, adjusted.track,
                         adjusted.plane)
    return Cell(scenario, model, files, None, seconds)


def _prediction(result) -> dict | None:
    """summary.json ``prediction`` of a cell: the cross-validated prediction error of held-out tie points of its
    tested adjustment (:mod:`selfcal.stats.prediction`; the comparison's CV column), None where it cannot be had."""
    from ..stats.prediction import converged_fold_systems, prediction_error
    if not result.converged:
        return None
    try:
        return prediction_error(converged_fold_systems(result), result.block.image_sigma_px).as_dict()
    except (ValueError, np.linalg.LinAlgError):
        return None


def run_matrix(blocks: dict, models: list[str], settings: CellSettings = CellSettings(),
               scheduler: str | None = "local", n_workers: int | None = None,
               done: Callable[[Cell], None] | None = None, say: Callable[[str], None] | None = None,
               every_s: float = 1.5) -> list[Cell]:
    """Adjust every block with every model; cells in (block, model) order.

    Parameters
    ----------
    blocks : dict scenario name -> Block (pruned, as read)
    scheduler : None for a serial run in this process, "local" for a local Dask
        cluster, or the address of an existing Dask scheduler.
    n_workers : worker processes of the local cluster (default: the number of cores).
    done : called with each cell as it finishes.
    say : called with a line when the cluster starts and whenever ``every_s`` pass on Dask without a cell
        finishing (the cells of a 28-image block take 10-20 s: the caller's progress).
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
    from dask.distributed import Client, LocalCluster, wait

    with _Ticker(say if say is not None else (lambda text: None), every_s) as ticker:
        cluster = None
        if scheduler == "local":
            workers = n_workers or os.cpu_count() or 1
            ticker.say(f"starting a local Dask cluster of {workers} worker process{'es' if workers > 1 else ''} ...")
            ticker.status = lambda t: f"starting the Dask cluster ({t:.0f} s) ..."
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   dashboard_address=":0", env=SINGLE_THREAD)   # ":0": a free port (two runs raced)
        else:
            ticker.say(f"connecting to the Dask scheduler at {scheduler} ...")
            ticker.status = lambda t: f"connecting to the Dask scheduler ({t:.0f} s) ..."
        client = Client(cluster if cluster is not None else scheduler)
        try:
            ticker.status = lambda t: f"sending the blocks to the workers ({t:.0f} s) ..."
            shared = {name: client.scatter(block, broadcast=True) for name, block in blocks.items()}
            # the wavelet cells take 3-4 times as long as the others: submitted first, they leave no worker idle
            first = sorted(range(len(cases)), key=lambda i: not takes_grid(cases[i][1]))
            submitted = {}
            for i in first:
                name, model = cases[i]
                submitted[i] = client.submit(run_cell, name, shared[name], model, settings, pure=False,
                                             key=f"selfcal-{name}-{model}-{time.time_ns()}")
            futures = [submitted[i] for i in range(len(cases))]      # in the cells' order
            t0, pending = time.perf_counter(), set(futures)
            ticker.status = lambda _: (f"{len(cases) - len(pending)}/{len(cases)} adjustments done in "
                                       f"{time.perf_counter() - t0:.0f} s ...")
            while pending:
                try:
                    finished, pending = wait(pending, timeout=0.5, return_when="FIRST_COMPLETED")
                except TimeoutError:
                    continue
                for future in finished:
                    cell = future.result()
                    if done is not None:
                        ticker.call(done, cell)
            ticker.status = None
            return client.gather(futures)
        finally:
            ticker.status = None
            close_quietly(client, cluster)


class _Ticker:
    """The batch's voice on Dask: ``say`` a line, and whenever ``every_s`` pass without one, the ``status`` line
    (a function of the seconds since the status was set; None: quiet). Dask's calls block without a word: the
    workers' start takes 2-4 s on a loaded machine (each imports the engine), a cell of a 28-image block 10-20 s."""

    def __init__(self, tell: Callable[[str], None], every_s: float) -> None:
        self._tell, self._every_s = tell, every_s
        self._status: Callable[[float], str] | None = None
        self._since = self._last = time.perf_counter()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    @property
    def status(self) -> Callable[[float], str] | None:
        return self._status

    @status.setter
    def status(self, status: Callable[[float], str] | None) -> None:
        with self._lock:
            self._status, self._since = status, time.perf_counter()

    def say(self, text: str) -> None:
        with self._lock:
            self._tell(text)
            self._last = time.perf_counter()

    def call(self, function: Callable[[Cell], None], cell: Cell) -> None:
        """The caller's ``function(cell)``, which may print, without the status line in between."""
        with self._lock:
            function(cell)
            self._last = time.perf_counter()

    def _run(self) -> None:
        while not self._stop.wait(0.1):
            with self._lock:
                now = time.perf_counter()
                if self._status is not None and now - self._last >= self._every_s:
                    self._tell(self._status(now - self._since))
                    self._last = now

    def __enter__(self) -> _Ticker:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
