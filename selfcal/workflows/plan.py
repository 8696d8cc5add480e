"""``selfcal plan``: what one adjustment of a block will need, before it runs (issue 43 item 2).

:func:`plan_block` takes the block's sizes as the engine would see them (the problem is arranged, as the
adjustment's first step does, but nothing is linearised), measures the reduced camera system's fill on the image
graph (images joined where they share a point: its pairs, its reverse Cuthill-McKee band and CHOLMOD's factor of it,
n_images unknowns instead of n_theta) and hands them to :func:`selfcal.stats.plan.plan_adjustment`.
:func:`available_mb` is the machine's memory available now; :func:`check_fits` the error when the plan exceeds it.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp

from ..block import Block
from ..errors import UsageError
from ..stats.plan import MB, BlockSizes, Plan, machine_speed, plan_adjustment

if TYPE_CHECKING:
    from ..adjust.problem import Problem

__all__ = ["plan_block", "image_graph_sizes", "available_mb", "check_fits", "TooLarge"]


class TooLarge(UsageError):
    """The block needs more memory than the machine has available (exit 2, before any work); ``figures``: the plan
    it refused, part by part (the figures of the verb's --json document)."""

    def __init__(self, message: str, figures: dict | None = None):
        super().__init__(message)
        self.figures = figures


def image_graph_sizes(obs_image: np.ndarray, obs_point: np.ndarray, n_images: int, n_points: int) -> dict:
    """The image graph's pairs, its reverse Cuthill-McKee half bandwidth, and the non-zeros and sum of squared
    column counts of its Cholesky factor in CHOLMOD's ordering (SuperLU's column counts without scikit-sparse)."""
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    incidence = sp.csr_matrix((np.ones(len(obs_image)), (obs_image, obs_point)), shape=(n_images, n_points))
    incidence.data[:] = 1.0                                     # an image observing a point twice counts once
    graph = (incidence @ incidence.T).tocsr()
    graph.setdiag(0.0)
    graph.eliminate_zeros()
    pairs = graph.nnz // 2
    if n_images == 0:
        return {"image_pairs": 0, "band_images": 0, "factor_blocks": 0, "factor_block_flops": 0.0}
    order = reverse_cuthill_mckee(graph, symmetric_mode=True)
    permuted = graph[order][:, order].tocoo()
    band = int(np.max(np.abs(permuted.row - permuted.col), initial=0))
    # an SPD matrix on the graph's pattern (diagonally dominant), whose factor has the fill of the reduced system's
    # image blocks
    pattern = graph.copy()
    pattern.data[:] = -1.0
    spd = (pattern + sp.diags(np.asarray(graph.getnnz(axis=1), float) + 1.0)).tocsc()
    try:
        from sksparse.cholmod import cholesky
        lower = cholesky(spd).L().tocsc()
    except ImportError:                                         # pragma: no cover - without scikit-sparse
        from scipy.sparse.linalg import splu
        lower = splu(spd, permc_spec="MMD_AT_PLUS_A").L.tocsc()
    counts = np.diff(lower.indptr).astype(float)
    return {"image_pairs": int(pairs), "band_images": band, "factor_blocks": int(lower.nnz),
            "factor_block_flops": float(np.sum(counts ** 2))}


def _model_sizes(block: Block, ap: str, grid: tuple[int, int]) -> tuple[int, int, int, int, Problem]:
    """(image width, camera parameters, AP coefficients, trajectory terms, problem) of the block with AP model
    ``ap``: the problem arranged as the adjustment arranges it (no linearisation)."""
    from ..adjust import AdjustOptions, APOptions
    from ..adjust.problem import build_problem

    problem = build_problem(block, AdjustOptions(ap=APOptions(ap, grid=grid)))
    n_ap = sum(int(cam.free[cam.n_core:].sum()) for cam in problem.cameras)
    return problem.image_width, problem.n_d, n_ap, problem.n_extra, problem


def plan_block(block: Block, ap: str | None = None, grid: tuple[int, int] = (9, 6), probe: bool = True) -> Plan:
    """Predict one adjustment of ``block`` with AP model ``ap`` (None: what ``selfcal adjust`` chooses by default;
    ``auto...``: the candidate with the most parameters, the largest system the model choice adjusts).
    ``probe``: scale the times by this machine's speed now (:func:`~selfcal.stats.plan.machine_speed`)."""
    from .adjust import ap_candidates, default_ap_model, is_auto

    spec = default_ap_model(block) if ap is None else ap
    candidates = ap_candidates(spec, grid) if is_auto(spec) else [(spec, grid)]
    widest = None
    planned = spec
    for model, model_grid in candidates:
        sizes = _model_sizes(block, model, model_grid)
        if widest is None or sizes[1] + sizes[3] > widest[1] + widest[3]:
            widest, planned = sizes, model
    assert widest is not None
    image_width, n_d, n_ap, n_extra, problem = widest
    graph = image_graph_sizes(problem.obs_image, problem.obs_point, problem.n_images, problem.n_points)
    block_sizes = BlockSizes(n_images=problem.n_images, n_cameras=len(problem.cameras), n_points=problem.n_points,
                       n_observations=problem.n_image_observations, image_width=image_width,
                       n_camera_parameters=n_d, n_ap=n_ap, n_extra=n_extra, **graph)
    plan = plan_adjustment(block_sizes, machine_speed() if probe else 1.0)
    plan.ap_model = planned if planned == spec else f"{planned} (the widest of {spec})"
    return plan


def available_mb() -> float:
    """Memory available to a new process now (MB): psutil's ``available`` where psutil is installed, else
    /proc/meminfo's MemAvailable; NaN where neither can be read."""
    import importlib
    try:
        psutil = importlib.import_module("psutil")            # the bench extra's; not a dependency
        return float(psutil.virtual_memory().available) / MB
    except ImportError:
        pass
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0 / MB
    except OSError:
        pass
    return float("nan")


def check_fits(plan: Plan, available: float, workflow: bool = True, workers: int | None = None) -> None:
    """Raise :class:`TooLarge` when the plan's peak exceeds ``available`` MB (no check when it is unknown): the one
    adjustment's peak, or with ``workflow`` that of ``selfcal adjust``'s default tested workflow; with ``workers``
    (a local cluster's), their peaks beside the client's (:meth:`~selfcal.stats.plan.Plan.worker_peak_mb`)."""
    need = plan.workflow_peak_mb if workflow else plan.peak_mb
    if workers:
        need = plan.client_peak_mb(workers, workflow) + workers * plan.worker_peak_mb(workers, workflow)
    if np.isfinite(available) and need > available:
        largest = max(plan.memory_mb, key=lambda k: plan.memory_mb[k])
        what = "selfcal adjust with its default tests" if workflow else "one adjustment"
        if workers:
            what += (f", and {workers} local workers of {plan.worker_peak_mb(workers, workflow) / 1024:.1f} GB each "
                     f"beside it")
        raise TooLarge(f"the block needs about {need / 1024:.1f} GB ({what}), the machine has {available / 1024:.1f} "
                       f"GB available; the largest part of one adjustment is the {largest.replace('_', ' ')} "
                       f"({plan.memory_mb[largest] / 1024:.1f} GB, {plan.factorisation} factorisation, "
                       f"{plan.covariance}): free memory, use a larger machine, or split the block",
                       {**plan.as_dict(), "available_mb": available})
