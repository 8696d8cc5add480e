"""A plan before the run (issue 43 item 2): the peak memory and the seconds per iteration of one adjustment with the
sigma of every unknown, predicted from the block's sizes alone.

The prediction follows the engine's own choices (:mod:`selfcal.adjust.linalg`): a reduced camera system of up to
``DENSE_ASSEMBLY_LIMIT`` unknowns is assembled and factorised dense; a larger one is banded where its reverse
Cuthill-McKee band is narrow (with a border for the camera parameters) and cheap (n w^2 <= ``BAND_FLOPS``), else
CHOLMOD. Q_theta is the dense inverse up to ``DENSE_LIMIT`` unknowns or without a band, else the selected inverse
on the band (:class:`~selfcal.adjust.selected.BandedCofactor`). The peak is the sum of

- the process with selfcal's modules and their compiled kernels loaded (``BASE_MB``),
- the observations' part: every array that grows with the image observations (the problem, the Jacobian chunks,
  the Schur terms of their points, residuals, the points' cofactors), ``BYTES_PER_OBSERVATION`` each, plus the AP
  columns (observations x 2 x AP coefficients doubles) where the camera has APs,
- the reduced camera system: its numbers in the form of the path taken (dense n^2; sparse: the pattern of every
  image pair that shares a point and the camera columns; the band; CHOLMOD's factor, whose fill is the image
  graph's factor times the image block), ``BYTES_PER_SYSTEM_NUMBER`` each (the copies the path keeps),
- the covariance: the dense inverse (n^2), or the selected inverse's numbers (n w), ``BYTES_PER_COVARIANCE_NUMBER``
  each.

Seconds per iteration: ``SECONDS_PER_OBSERVATION`` (linearisation, reduction, back-substitution and the cost at
the step: passes over the observations on two threads) plus the factorisation's flops at ``FLOPS_PER_SECOND``,
both scaled by a probe of this machine taken now against the same probe when they were measured
(:func:`machine_speed`). The constants were measured once with ``benchmarks/bench_plan.py`` on the synthetic strip
blocks (seed-000 simulator, AP model none); see docs/DESIGN-NOTES.md, "Plan before the run". The prediction is
for the blocks it was measured on and their like: a block of another shape (a wide AP model, random image graphs,
line images) uses the same formulas with constants not measured on it.

This module does no I/O: :mod:`selfcal.workflows.plan` reads the block and measures its image graph.
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np

from ..adjust.linalg import BAND_FLOPS, BAND_SHARE, CHOLMOD_AVAILABLE, DENSE_ASSEMBLY_LIMIT, DENSE_LIMIT

__all__ = ["BlockSizes", "Plan", "plan_adjustment", "machine_speed", "MB"]

MB = 1024.0 * 1024.0

# The constants: one run of benchmarks/bench_plan.py (2026-12-07, this 2-core VM shared with other work, load
# average about 5) on the strip blocks of 28, 102, 200, 504, 1000 and 2000 images at 0.5 tie points per mm^2 (AP
# model none), the peak resident memory and the median seconds per iteration of each adjustment measured in a process
# of its own; the memory constants are a non-negative least-squares fit of the relative error of the peaks (every
# block within 2 % of its measured peak; the two blocks of another density, which the fit did not see, 1 % and 3 %),
# the time constants likewise with each adjustment's own probe (:func:`machine_speed`) and the factorisation rate
# held at CHOLMOD's measured one. docs/DESIGN-NOTES.md, "Plan before the run", has the table.

#: resident MB of a process that has imported selfcal and adjusted a small block (the fit's intercept)
BASE_MB = 192.0
#: bytes that grow with each image observation: the problem, the Jacobian chunks, the Schur terms of their points,
#: residuals, the points' cofactors (fitted)
BYTES_PER_OBSERVATION = 641.0
#: bytes per number of the reduced camera system as the path keeps it: S and its scaled copy, the factor, the
#: workspace of the factorisation; a number of a sparse pattern counts 1.5 for its index (fitted)
BYTES_PER_SYSTEM_NUMBER = 45.3
#: bytes per number of Q_theta: the dense inverse's n^2, or the selected inverse's n (w + 1 + border) (fitted)
BYTES_PER_COVARIANCE_NUMBER = 12.3
#: bytes per number of the points' couplings with the AP coefficients, 3 n_points n_ap (each point's block of W with
#: the AP columns, kept per chunk, and its products in the reduction and the points' cofactors): fitted on the wavelet
#: blocks of ``bench_plan.py --ap wavelet:db4`` (254 coefficients on 9x6; 28-504 images, 11,507-210,390
#: observations), where the constants above, fitted without APs, left 0.61-0.74 of the measured peaks; every block
#: within 0.87-1.05 with it. The AP columns themselves are counted at 8 bytes per number (``ap_columns``).
BYTES_PER_AP_COUPLING = 35.3
#: flops per second of the points' products with the AP columns (6 n_points n_d^2 per iteration, n_d the camera
#: parameters: each point's 3 x n_d couplings times themselves), at probe speed 1: fitted on the same wavelet blocks
#: (their seconds per iteration within 0.44-1.20, the smallest block's fixed costs left out)
AP_COUPLING_FLOPS_PER_SECOND = 2.89e10

#: ``selfcal adjust BLOCK`` with its default options (the tested workflow: robust start, snooping rounds, the model
#: choice, leave-one-out control, the half-block check, the report) holds more than one adjustment: its peak over
#: the one adjustment's, MB at no observation and bytes per image observation, a non-negative fit of the relative
#: errors to the command's measured peaks (``benchmarks/bench_plan.py --workflow``: /proc's VmHWM, 2026-12-08) on the
#: strip blocks of 28, 102, 200, 504 and 1000 images (309, 415, 577, 981, 1522 MB; the fit within 2.3 % of each; 504
#: images at 1.0 tie points per mm^2, not fitted: 1478 MB predicted, 1342 MB measured; docs/DESIGN-NOTES.md)
WORKFLOW_BASE_MB = 94.2
WORKFLOW_BYTES_PER_OBSERVATION = 1514.0
#: the tested workflow of a block with APs holds about one more array of the AP columns beside one adjustment's (a
#: re-adjustment's own beside the one it started from): fitted in units of that array on the wavelet blocks of
#: ``bench_plan.py --workflow --ap wavelet:db4`` (28-504 images; 0.75-0.86 of the measured peaks without the term,
#: 0.96-1.04 with it)
WORKFLOW_AP_COLUMN_ARRAYS = 1.05

#: a worker of a cluster that holds a share of the points (``selfcal adjust --scheduler``,
#: :mod:`selfcal.adjust.distributed`): MB at no observation and bytes per image observation of its share (its share's
#: problem and linearisation, its reduced sums, its points' results, the arrays in flight), a least-squares fit of the
#: relative errors to the workers' peaks of ``benchmarks/bench_distributed.py`` (two workers; the strip blocks of
#: 200, 1000, 2000 and 5000 images, AP model none, the points' cofactors computed on the workers; each within 0.3 %).
#: A share's AP columns and couplings are counted as one process's, split by the shares
WORKER_BASE_MB = 203.4
WORKER_BYTES_PER_OBSERVATION = 705.0
#: the client of such a cluster holds one process's plan less what the shares hold for it (the points' linearisation
#: and inverses, the products of their cofactors and leverages): MB and bytes per image observation, a
#: least-squares fit of the relative errors of the client's peaks on the same runs (each within 4.2 %)
CLIENT_SHED_MB = 39.4
CLIENT_SHED_BYTES_PER_OBSERVATION = 442.0
#: the tested workflow on such a cluster: each worker holds the shares of this many adjustments at once (the one a
#: re-adjustment starts from, which the workflow still holds, and its own): counted on the strip blocks of 200 and
#: 504 images (1.0 points per mm^2), whose workers then peaked at 257 and 463 MB (planned 259 and 487). The client's
#: workflow holds what one process's does (measured 1.11 and 0.97 of it: the shares' part of one adjustment is small
#: beside the workflow's own arrays, and a local cluster's scheduler runs in the client)
WORKFLOW_SHARES = 2

#: seconds per image observation and iteration (linearisation, reduction, back-substitution, the cost at the step:
#: passes over the points on two threads) at probe speed 1 (fitted)
SECONDS_PER_OBSERVATION = 1.73e-6
#: flops per second of the factorisation at probe speed 1: CHOLMOD on OpenBLAS, two threads, factorised the
#: 2000-image strip block's reduced system in 0.31 s (bench_scaling.py --linalg, DESIGN-NOTES "Solver"), 5.1e9 flops
#: as this module counts them (the image graph's factor times the 6 x 6 image block)
FLOPS_PER_SECOND = 1.65e10
#: seconds of the machine probe (:func:`machine_speed`) when the constants above were measured (the median over the
#: six adjustments; 5.2-8.8 ms)
PROBE_SECONDS = 0.0062


@dataclass(frozen=True)
class BlockSizes:
    """What the prediction needs of a block: counts, and the reduced camera system's fill.

    ``image_pairs``: pairs of images that share at least one point (the off-diagonal blocks of the reduced
    system); ``band_images``: the image graph's half bandwidth in reverse Cuthill-McKee order; ``factor_blocks`` and
    ``factor_block_flops``: the number of non-zeros of the image graph's Cholesky factor (CHOLMOD's ordering) and the
    sum of its column counts squared, which times the image block (``image_width``) give the reduced system's fill
    and flops."""

    n_images: int
    n_cameras: int
    n_points: int
    n_observations: int
    image_width: int                 # parameters per image (6 for a frame image)
    n_camera_parameters: int         # free camera parameters of all cameras, APs included
    n_ap: int                        # of which AP coefficients
    n_extra: int                     # trajectory shift/drift terms
    image_pairs: int
    band_images: int
    factor_blocks: int
    factor_block_flops: float

    @property
    def n_theta(self) -> int:
        return self.n_images * self.image_width + self.n_camera_parameters + self.n_extra


@dataclass
class Plan:
    """The prediction: memory by component (MB), seconds per iteration by component, the paths the engine takes."""

    sizes: BlockSizes
    factorisation: str               # dense, banded, cholmod (or superlu without scikit-sparse)
    covariance: str                  # dense-inverse or selected-inverse
    band_width: int                  # half bandwidth of S in unknowns (0: no band)
    memory_mb: dict = field(default_factory=dict)
    seconds: dict = field(default_factory=dict)
    speed: float = 1.0               # this machine's probe against the constants' (> 1: slower now)
    #: the AP model planned for (set by the caller that knows it)
    ap_model: str = ""
    #: the counts the constants multiply (observations, numbers of the system and of Q_theta, flops): for the fit
    numbers: dict = field(default_factory=dict)

    @property
    def peak_mb(self) -> float:
        return float(sum(self.memory_mb.values()))

    @property
    def workflow_peak_mb(self) -> float:
        """The peak of ``selfcal adjust BLOCK`` with its default options (the tested workflow), which holds more
        than the one adjustment of :attr:`peak_mb`."""
        return (self.peak_mb + WORKFLOW_BASE_MB + WORKFLOW_BYTES_PER_OBSERVATION * self.sizes.n_observations / MB
                + WORKFLOW_AP_COLUMN_ARRAYS * self.memory_mb.get("ap_columns", 0.0))

    @property
    def seconds_per_iteration(self) -> float:
        return float(sum(self.seconds.values()))

    def client_peak_mb(self, workers: int, workflow: bool = False) -> float:
        """The peak of the client of ``workers`` workers: one adjustment's (:attr:`peak_mb` less what the shares
        hold for it; all of it for fewer than two workers, where the adjustment runs in the client) or with
        ``workflow`` the default tested workflow's (:attr:`workflow_peak_mb`, :data:`WORKFLOW_SHARES`)."""
        if workflow:
            return self.workflow_peak_mb
        if workers < 2:
            return self.peak_mb
        return self.peak_mb - CLIENT_SHED_MB - CLIENT_SHED_BYTES_PER_OBSERVATION * self.sizes.n_observations / MB

    def worker_peak_mb(self, workers: int, workflow: bool = False) -> float:
        """The peak of each of ``workers`` workers that hold a share of the points (about the same observations each;
        the client's is :meth:`client_peak_mb`), in one adjustment or with ``workflow`` in the
        default tested workflow (:data:`WORKFLOW_SHARES` adjustments' shares at once; the client's is then
        :attr:`workflow_peak_mb`)."""
        share = self.sizes.n_observations / max(workers, 1)
        held = WORKFLOW_SHARES if workflow else 1
        return (WORKER_BASE_MB + held * (WORKER_BYTES_PER_OBSERVATION * share / MB
                + (self.memory_mb.get("ap_columns", 0.0) + self.memory_mb.get("ap_couplings", 0.0)) / max(workers, 1)))

    def as_dict(self) -> dict:
        return {"sizes": {**asdict(self.sizes), "n_theta": self.sizes.n_theta},
                "ap_model": self.ap_model, "factorisation": self.factorisation, "covariance": self.covariance, "band_width": self.band_width,
                "memory_mb": dict(self.memory_mb), "peak_mb": self.peak_mb,
                "workflow_peak_mb": self.workflow_peak_mb, "seconds": dict(self.seconds),
                "seconds_per_iteration": self.seconds_per_iteration, "machine_speed": self.speed,
                "numbers": dict(self.numbers)}


def _band_width(sizes: BlockSizes) -> int:
    """S's half bandwidth in unknowns as :func:`selfcal.adjust.linalg.band_structure` finds it (0: no band): the
    image graph's band times the image block; the camera parameters, which couple more than BORDER_SHARE of the
    images (``linalg.BORDER_SHARE``), form the border."""
    n_inner = sizes.n_images * sizes.image_width
    border = sizes.n_camera_parameters + sizes.n_extra
    if n_inner < 1000 or border > 0.1 * sizes.n_theta:
        return 0
    width = (sizes.band_images + 1) * sizes.image_width - 1
    return width if width <= BAND_SHARE * n_inner else 0


def plan_adjustment(sizes: BlockSizes, speed: float = 1.0, cholmod: bool = CHOLMOD_AVAILABLE) -> Plan:
    """Predict one adjustment's peak memory and seconds per iteration from ``sizes``; ``speed``: the machine probe's
    seconds now over :data:`PROBE_SECONDS` (times are scaled by it)."""
    n = sizes.n_theta
    p = sizes.image_width
    border = sizes.n_camera_parameters + sizes.n_extra
    width = _band_width(sizes)
    band_flops = float(n) * (width + 1) ** 2
    if n <= DENSE_ASSEMBLY_LIMIT:
        path = "dense"
    elif width and (not cholmod or band_flops <= BAND_FLOPS):
        path = "banded"
    else:
        path = "cholmod" if cholmod else "superlu"
    covariance = "selected-inverse" if (path != "dense" and n > DENSE_LIMIT and width) else "dense-inverse"
    # the sparse pattern: each image's block, both triangles of each pair's, the camera columns and rows
    pattern = (sizes.n_images + 2.0 * sizes.image_pairs) * p * p + 2.0 * n * border
    if path == "dense":
        system, flops = float(n) * n, n ** 3 / 3.0
    elif path == "banded":
        system, flops = 1.5 * pattern + (width + 1.0) * (n - border) + 2.0 * n * border, band_flops
    else:
        system = 1.5 * pattern + sizes.factor_blocks * p * p + n * border
        flops = sizes.factor_block_flops * p ** 3 + n * border ** 2
    cofactor = float(n) * n if covariance == "dense-inverse" else n * (width + 1.0 + border)
    ap_flops = 6.0 * sizes.n_points * sizes.n_camera_parameters ** 2 if sizes.n_ap else 0.0
    numbers = {"observations": float(sizes.n_observations), "ap_columns": 2.0 * sizes.n_observations * sizes.n_ap,
               "ap_couplings": 3.0 * sizes.n_points * sizes.n_ap,
               "reduced_system": system, "covariance": cofactor, "factorisation_flops": flops,
               "ap_coupling_flops": ap_flops}
    memory = {"base": BASE_MB,
              "observations": numbers["observations"] * BYTES_PER_OBSERVATION / MB,
              # the AP columns' array itself (observations x 2 x coefficients doubles; not fitted: the blocks had none)
              "ap_columns": numbers["ap_columns"] * 8.0 / MB,
              "ap_couplings": numbers["ap_couplings"] * BYTES_PER_AP_COUPLING / MB,
              "reduced_system": system * BYTES_PER_SYSTEM_NUMBER / MB,
              "covariance": cofactor * BYTES_PER_COVARIANCE_NUMBER / MB}
    seconds = {"observations": speed * SECONDS_PER_OBSERVATION * sizes.n_observations,
               "ap_couplings": speed * ap_flops / AP_COUPLING_FLOPS_PER_SECOND,
               "factorisation": speed * flops / FLOPS_PER_SECOND}
    plan = Plan(sizes, path, covariance, width, memory, seconds, speed)
    plan.numbers = numbers
    return plan


def machine_speed(size: int = 400, repeat: int = 15) -> float:
    """This machine's speed now against the constants': the best of ``repeat`` dense Cholesky factorisations of a
    ``size`` x ``size`` matrix and a pass over 8 MB (the two kinds of work an iteration does), on one BLAS thread, in
    seconds, over :data:`PROBE_SECONDS` (> 1: slower than when the constants were measured). About 0.6 s. On two
    threads the probe was bimodal on this loaded machine (0.4 or 2.6 of itself, one or the other in consecutive
    runs); on one thread the best of 5 spread by 2x between processes (2.8-5.9 at a load average of 8), the best of
    15 by 1.2x (3.5-4.2); the constants were measured with the best of 5."""
    from threadpoolctl import threadpool_limits

    rng = np.random.default_rng(0)
    a = rng.standard_normal((size, size))
    spd = a @ a.T + size * np.eye(size)
    data = rng.standard_normal(1 << 20)
    best = np.inf
    with threadpool_limits(limits=1, user_api="blas"):
        for _ in range(repeat):
            t = time.perf_counter()
            np.linalg.cholesky(spd)
            np.cumsum(data * 1.5)
            best = min(best, time.perf_counter() - t)
    return float(best / PROBE_SECONDS)
