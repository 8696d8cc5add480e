"""The adjustment engine: self-calibrating bundle adjustment of a block.

>>> result = adjust(block, AdjustOptions(ap="none"))        # doctest: +SKIP
>>> result.sigma0_px, result.converged                        # doctest: +SKIP

:func:`adjust` sets up the problem (:mod:`.problem`), finds initial values
(:mod:`.initial`), iterates (:mod:`.solver`) and extracts the cofactor
matrices (:mod:`.covariance`). It never reads files and never prints; progress
goes to an optional callback.
"""
from __future__ import annotations

import contextlib
import time
from types import SimpleNamespace
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ..ap import ap_settings
from ..block import Block, leave_out, prune
from ..errors import AdjustmentError
from .covariance import point_cofactors
from .update import UPDATE_LIMIT, downdated_start
from .datum import FREE_POINT_SIGMA_RATIO, behind_camera, points_not_determined_by_rays
from .initial import initial_state
from .linalg import (DENSE_LIMIT, EIGH_FLOPS, PSEUDO_INVERSE_LIMIT, SingularSystem, blas_threads, dense_assembly,
                     factorise, null_directions, shared_product)
from .ap_columns import carry_ap_columns
from .residuals.image import image_residuals
from .schur import Linearisation, SingularPoints, reduce
from .problem import Problem, State, build_problem, inherited_point_key
from .robust import RobustOptions, RobustWeighting
from .solver import IterationRecord, SolverOptions, solve

__all__ = ["AdjustOptions", "AdjustmentResult", "IterationRecord", "RobustOptions", "adjust", "apply_free", "Problem",
           "State"]


@dataclass(frozen=True)
class AdjustOptions:
    """What to estimate and how.

    Attributes
    ----------
    ap : str
        Additional-parameter model, e.g. ``"none"``, ``"brown"``, ``"wavelet:db4"``.
    grid : (int, int)
        Gx x Gy grid of the wavelet APs (Eq. 10 of seed 000).
    gnss_drift, imu_drift : int
        Order of the strip-wise shift/drift of GNSS positions and IMU attitudes
        (Eq. 12 of seed 000): -1 none, 0 shift, 1 shift + linear drift (default), 2 quadratic.
    lever_arm, boresight : bool
        Estimate the GNSS lever arm and the IMU boresight angles (need the order -1).
    sensor_model : str, optional
        Which parameters of a sensor are estimated, where the sensor offers a choice: seed 001's
        ``M1`` ... ``M7`` or a comma-separated list of parameter names for pushbroom images.
    parameter_sigma : dict, optional
        A-priori sigmas (code units) by parameter name, overriding the sensor model's weights.
    ap_cameras : tuple of str, optional
        The cameras that get additional parameters (default: all).
    ap_sigma_px : float, optional
        A-priori sigma of every AP coefficient (a prior observation of its start value); default free.
    attitude_telemetry : bool
        Pushbroom images: fit the attitude of attitude.csv (False: roll = pitch = yaw = 0 before the
        corrections, seed 001 Table 5).
    solver : SolverOptions
    """

    ap: str = "none"
    grid: tuple[int, int] = (9, 6)
    gnss_drift: int = 1
    imu_drift: int = 1
    lever_arm: bool = False
    boresight: bool = False
    sensor_model: str | None = None
    parameter_sigma: dict | None = None
    ap_cameras: tuple[str, ...] | None = None
    ap_sigma_px: float | None = None
    attitude_telemetry: bool = True
    solver: SolverOptions = field(default_factory=SolverOptions)


@dataclass
class AdjustmentResult:
    """The estimate, its precision and how it was reached.

    Precision is a-posteriori: covariance = variance_factor · cofactor.
    Residuals follow l + v = f(x): v = adjusted - observed, in the observation units of each
    image's sensor (:attr:`residuals_px` in pixels).
    """

    problem: Problem
    state: State
    block: Block                   # the block actually adjusted (after pruning)
    converged: bool
    reason: str
    iterations: int
    history: list[IterationRecord]
    cost: float
    n_observations: int
    n_unknowns: int
    variance_factor: float
    image_sigma_px: float
    theta_names: list[str]
    Q_theta: np.ndarray            # or a BandedCofactor beyond DENSE_LIMIT (Factor.cofactor): index it, .diagonal()
    residuals: np.ndarray          # (m, 2) image residuals in ``block``'s observation order, observation units
    notes: list[str]
    seconds: float
    linearisation: Linearisation = field(repr=False, default=None)
    v_inv: list = field(repr=False, default=None)
    point_cofactor_blocks: np.ndarray | None = field(repr=False, default=None)   # Q_points once computed
    reduced_matrix: np.ndarray | None = field(repr=False, default=None)   # S of the last linearisation (dense, small)
    datum_null: np.ndarray | None = field(repr=False, default=None)       # a free network's datum directions
    robust: RobustWeighting | None = field(repr=False, default=None)      # the robust weights, where robust

    @property
    def Q_points(self) -> np.ndarray:
        """Cofactor blocks of the object points, (n_points, 3, 3), computed on first use: the rounds of a tested
        workflow get them from the observation tests, whose pass over the points shares their products."""
        if self.point_cofactor_blocks is None:
            with blas_threads(self.problem.n_images):
                self.point_cofactor_blocks = point_cofactors(self.problem, self.linearisation, self.v_inv,
                                                             self.Q_theta)
        return self.point_cofactor_blocks

    @property
    def redundancy(self) -> int:
        return self.n_observations - self.n_unknowns

    @property
    def sigma0_px(self) -> float:
        """A-posteriori sigma of an image coordinate of unit weight, pixels."""
        return self.image_sigma_px * float(np.sqrt(self.variance_factor))

    @property
    def residuals_px(self) -> np.ndarray:
        """Image residuals (m, 2) in pixels along the photo axes (x right, y up), ``block``'s order."""
        problem = self.problem
        out = np.empty_like(self.residuals)
        v = self.residuals[problem.obs_order]               # sorted order
        for slot in problem.sensors:
            col_row = slot.bound.pixel_residuals(slot.observations, v[slot.observations])
            out[problem.obs_order[slot.observations]] = np.column_stack([col_row[:, 0], -col_row[:, 1]])
        return out

    def image_sigma(self) -> np.ndarray:
        """A-posteriori standard deviations of the image parameters, (n_images, width) in code units
        (a frame image's X0, Y0, Z0 in m, omega, phi, kappa in rad); NaN where held."""
        n_e = self.problem.n_e
        s = np.sqrt(self.variance_factor * self.Q_theta.diagonal()[:n_e]).reshape(self.problem.n_images, -1)
        return np.where(self.problem.image_free, s, np.nan)

    def camera_sigma(self) -> list[np.ndarray]:
        """A-posteriori standard deviations of each camera's parameters (NaN where fixed)."""
        out = []
        diag = self.Q_theta.diagonal()
        for cam, start in zip(self.problem.cameras, self.problem.d_offset):
            s = np.full(cam.size, np.nan)
            k = int(cam.free.sum())
            s[cam.free] = np.sqrt(self.variance_factor * diag[start:start + k])
            out.append(s)
        return out

    def predict_pixels(self, image_ids, point_ids) -> np.ndarray:
        """Adjusted image positions (col, row) of arbitrary (image, point) pairs, by id.

        NaN where the image or the point is not part of the adjustment (e.g. an
        observation rejected together with its point).
        """
        img_lookup = {i: k for k, i in enumerate(self.block.images.image_id)}
        pt_lookup = {p: k for k, p in enumerate(self.block.points.point_id)}
        img = np.array([img_lookup.get(i, -1) for i in image_ids], dtype=np.int64)
        pt = np.array([pt_lookup.get(p, -1) for p in point_ids], dtype=np.int64)
        out = np.full((len(img), 2), np.nan)
        ok = (img >= 0) & (pt >= 0)
        problem = self.problem
        image_slot = np.zeros(problem.n_images, np.int64)
        for s, slot in enumerate(problem.sensors):
            image_slot[slot.images] = s
        for s, slot in enumerate(problem.sensors):
            sel = np.flatnonzero(ok & (image_slot[np.maximum(img, 0)] == s))
            if sel.size:
                context = slot.bound.context(self.state, False)
                out[sel] = slot.bound.pixels(context, img[sel], self.state.points[pt[sel]])
        return out

    def point_covariance(self) -> np.ndarray:
        """A-posteriori covariance of every object point, (n_points, 3, 3) in m^2."""
        return self.variance_factor * self.Q_points


def _leave_out(block: Block, observations, points, text: str, behind: int = 0, undetermined: int = 0) -> Block:
    """``block`` without the flagged observations / points, pruned (a point left with one ray, an image with too
    few points), its ``dropped`` record counting them and saying ``text``."""
    from ..sensors import sensor_of

    dropped = replace(block.dropped, observations_behind_camera=block.dropped.observations_behind_camera + behind,
                      points_undetermined=block.dropped.points_undetermined + undetermined,
                      messages=block.dropped.messages + (text,))
    need = min((sensor_of(c).min_points_per_image for c in block.cameras.values()), default=6)
    return prune(leave_out(block, observations, points, dropped), min_points_per_image=need)


def _free_network_cofactor(S, notes: list[str], defect_tol: float = 1e-10) -> np.ndarray:
    """Cofactor of theta in a free network: the pseudo-inverse of S (minimum-trace datum).

    The eigenvalues of the scaled S below ``defect_tol`` times the largest are
    the datum defect and are left out.
    """
    S = S.toarray() if hasattr(S, "toarray") else np.asarray(S)
    if S.shape[0] > DENSE_LIMIT:
        raise AdjustmentError("free-network covariance is implemented for up to "
                              f"{DENSE_LIMIT} orientation and camera unknowns")
    d = np.sqrt(np.clip(np.diag(S), 1e-300, None))
    with shared_product(EIGH_FLOPS * S.shape[0] ** 3):
        w, V = np.linalg.eigh(S / d[:, None] / d[None, :])
    keep = w > defect_tol * w.max()
    notes.append(f"free network: datum defect {int((~keep).sum())}; precision in the minimum-trace datum")
    Q = (V[:, keep] / w[keep]) @ V[:, keep].T
    return Q / d[:, None] / d[None, :]


def _offsets(problem: Problem) -> list[int]:
    offsets, start = [], problem.n_e
    for cam in problem.cameras:
        offsets.append(start)
        start += int(cam.free.sum())
    return offsets


def apply_free(problem: Problem, free: dict) -> None:
    """Hold parameters as screening decided: ``free`` maps an owner to a bool mask of what stays
    estimated, a camera id to its AP coefficients, ``("core", camera id)`` to its sensor's own
    parameters, ``("image", image id)`` to an image's parameters, "GNSS" / "IMU" to the
    trajectory terms. Held parameters keep their start value (zero for an AP coefficient)."""
    image_of = {i: k for k, i in enumerate(problem.image_ids)}
    for cam in problem.cameras:
        if cam.camera_id in free:
            cam.free[cam.n_core:] = np.asarray(free[cam.camera_id], bool)
        if ("core", cam.camera_id) in free:
            cam.free[:cam.n_core] = np.asarray(free[("core", cam.camera_id)], bool)
    for key, mask in free.items():
        if isinstance(key, tuple) and key[0] == "image" and key[1] in image_of:
            problem.image_free[image_of[key[1]]] = np.asarray(mask, bool)
    for t in problem.trajectory:
        if t.sensor in free:
            t.free[:] = np.asarray(free[t.sensor], bool)
    problem.d_offset = _offsets(problem)


#: a parameter whose sigma its correlation with the others inflates by more than this (sqrt(Q_kk S_kk), the square
#: root of the variance inflation factor) is determined by the data only in combination with others. Measured:
#: simulated UAV blocks with Brown APs up to 80, the PRISM triplet with M7 35, the LRO NAC pair with degree-3
#: attitude polynomials 2.4e4 - 6.7e4 (bias and drift alone: 2.5)
WEAK_INFLATION = 1000.0


def weakly_determined(S, Q, names: list[str], problem: Problem, limit: float = WEAK_INFLATION,
                      top: int = 4) -> str | None:
    """A note naming the free parameters whose a-posteriori sigma is more than ``limit`` times the sigma they
    would have if the others were known (sqrt of Q_kk times the reduced normal matrix's S_kk); None if none is."""
    diag = np.asarray(S.diagonal() if hasattr(S, "diagonal") else np.diag(S), float).ravel()
    inflation = np.sqrt(np.abs(Q.diagonal() * diag))
    free = np.ones(len(inflation), bool)
    free[:problem.n_e] = problem.image_free.ravel()
    weak = np.flatnonzero(free & (inflation > limit))
    if not weak.size:
        return None
    worst = weak[np.argsort(inflation[weak])[::-1]][:top]
    listed = ", ".join(f"{names[k]} ({inflation[k]:.3g}x)" for k in worst)
    return (f"weakly determined: {weak.size} parameters have sigmas inflated more than {limit:g}x by their "
            f"correlation with others ({listed}{', ...' if weak.size > top else ''}): the data fix them only in "
            f"combination; their values lean on the priors, the datum or the start. Add observations or priors, "
            f"or estimate fewer parameters")


def adjust(block: Block, options: AdjustOptions = AdjustOptions(),
           progress: Callable[[IterationRecord], None] | None = None,
           start: "AdjustmentResult | None" = None, free: dict | None = None,
           ap_models: dict | None = None, robust: RobustOptions | None = None) -> AdjustmentResult:
    """Adjust a block: estimate orientation, object points and camera parameters.

    Parameters
    ----------
    block : Block
        A pruned block (as :func:`selfcal.io.read_block` returns it).
    options : AdjustOptions
    progress : callable, optional
        Called with an :class:`IterationRecord` after every iteration.
    start : AdjustmentResult, optional
        A previous adjustment of (a superset or subset of) this block: its
        estimates are the initial values wherever the ids match (warm start,
        used by data snooping and AP screening). Its kept AP columns are taken
        over, not copied: it stays valid, but would evaluate them afresh if
        linearised again.
    free : dict, optional
        Which screenable parameters are estimated, by owner: a camera id maps to
        a bool array over its AP coefficients, "GNSS" or "IMU" to one over that
        sensor's shift/drift parameters. The others are held at zero.
    ap_models : dict camera_id -> APModel, optional
        Use these AP models instead of building them from ``options.ap``
        (keeps a basis fixed across re-adjustments).
    robust : RobustOptions, optional
        Weight the image observations (and the control points) by a robust loss of their residuals,
        re-computed at every accepted step (:mod:`.robust`); the result's ``robust`` holds the weights.

    Raises
    ------
    AdjustmentError
        When the block has a rank defect (the message names the unknowns
        involved) or cannot be initialised.
    """
    with contextlib.ExitStack() as threads:
        return _adjust(block, options, progress, start, free, ap_models, robust, threads)


def _adjust(block: Block, options: AdjustOptions, progress, start, free, ap_models, robust,
            threads: contextlib.ExitStack) -> AdjustmentResult:
    t0 = time.perf_counter()
    settings = ap_settings(options.ap, options.grid)

    def setup(block: Block, start, ap_models):
        key = None if start is None else inherited_point_key(block, start.block, start.problem)
        problem = build_problem(block, options.ap, settings, ap_models=ap_models,
                                gnss_drift=options.gnss_drift, imu_drift=options.imu_drift,
                                lever_arm=options.lever_arm, boresight=options.boresight, options=options,
                                point_key=key)
        if free:
            apply_free(problem, free)
        if start is not None:
            # the previous estimate moved by the downdated step, before its AP columns are carried away
            with blas_threads(len(block.images)):   # (two BLAS runtimes' threads on two cores: a 350x350
                # Cholesky took 100 ms on two threads just after NumPy's, 1 ms on one)
                start = downdated_start(start, problem, block,
                                        block.datum == "free" or options.solver.free_network) or start
            carry_ap_columns(problem, block.observations.row[problem.obs_order],
                             start.problem, start.block.observations.row[start.problem.obs_order], consume=True)
        state, notes = initial_state(problem, block, start, robust is not None)
        for slot in problem.sensors:
            slot.bound.refine_sigma(state, problem.obs_sigma)
        problem.settle_sigma()
        return problem, state, notes

    problem, state, notes = setup(block, start, ap_models)
    # small blocks on one BLAS thread from here on; the AP basis above keeps them all (a WAP basis's frame sample)
    threads.enter_context(blas_threads(len(block.images)))
    solver_options = options.solver
    free_network = block.datum == "free" or solver_options.free_network
    left_out: list[str] = []
    if free_network:
        solver_options = replace(solver_options, free_network=True,
                                 point_sigma_ratio=solver_options.point_sigma_ratio or FREE_POINT_SIGMA_RATIO)
    if free_network or robust is not None:
        # a free network, or a robust adjustment of matcher output: observations behind their camera at the start
        # go (a robust adjustment also leaves out points whose rays turn out singular, below)
        # at the start values; a warm start comes from an adjustment that left them out already
        behind = behind_camera(problem, state) if start is None else np.zeros(problem.n_image_observations, bool)
        if behind.any():
            flagged = np.zeros(len(block.observations), bool)
            flagged[problem.obs_order[behind]] = True
            text = (f"left out {int(behind.sum())} observations of {len(np.unique(problem.obs_point[behind]))} "
                    f"points behind their camera at the start values (a central projection fits their mirror "
                    f"image; " + ("COLMAP's cost gives them no residual)" if free_network else
                                  "wrong matches, or points intersected from them)"))
            block = _leave_out(block, flagged, None, text, behind=int(behind.sum()))
            left_out.append(text)
            problem, state, notes = setup(block, start, ap_models)
    history: list[IterationRecord] = []
    # a free network's datum directions, carried over a leave-out and from the adjustment this one re-runs (the
    # solver checks they still fit the unknowns and finds them afresh if not)
    datum_null = getattr(start, "datum_null", None)
    while True:
        names = problem.theta_names(block.images.image_id)
        n_obs, n_unk = problem.n_observations(), problem.n_unknowns()
        if n_obs <= n_unk:
            raise AdjustmentError(f"no redundancy: {n_obs} observations for {n_unk} unknowns")
        budget = replace(solver_options, max_iterations=max(1, options.solver.max_iterations - len(history)),
                         initial_damping=history[-1].damping if history else solver_options.initial_damping)
        done = len(history)                 # iterations before a leave-out: the numbering goes on

        def numbered(record: IterationRecord) -> None:
            if progress is not None:
                progress(replace(record, iteration=record.iteration + done))
        weighting = RobustWeighting(robust) if robust is not None else None
        try:
            outcome = solve(problem, state, names, budget, numbered, datum_null,
                            None if weighting is None else weighting.update)
        except SingularPoints as exc:
            ids = ", ".join(f"'{block.points.point_id[i]}'" for i in exc.indices[:5])
            if robust is None:
                raise AdjustmentError(f"{exc} (e.g. {ids}): remove them or check their observations") from None
            # a robust adjustment: points whose rays are all gross errors go, and it starts again from its start
            flagged = np.zeros(len(block.points), bool)
            flagged[exc.indices] = True
            text = f"left out {int(flagged.sum())} points whose rays do not determine them (e.g. {ids})"
            left_out.append(text)
            previous = SimpleNamespace(block=block, state=state, problem=problem)
            block = _leave_out(block, None, flagged, text, undetermined=int(flagged.sum()))
            problem, state, notes = setup(block, previous, {cam.camera_id: cam.ap for cam in problem.cameras})
            continue
        history += [replace(record, iteration=record.iteration + done) for record in outcome.history]
        datum_null = outcome.datum_null
        if outcome.undetermined is None or len(history) >= options.solver.max_iterations:
            break
        # a free network's points that their rays do not determine: left out, and on from the estimate so far
        flagged = np.zeros(len(block.points), bool)
        flagged[outcome.undetermined] = True
        sigma = points_not_determined_by_rays(outcome.linearisation.of_points("V"),
                                              solver_options.point_sigma_ratio)[1]
        worst = outcome.undetermined[np.argsort(-sigma[outcome.undetermined])][:5]
        listed = ", ".join(f"'{block.points.point_id[k]}' ({sigma[k]:.3g} m)" for k in worst)
        text = (f"left out {int(flagged.sum())} points that their rays do not determine after {outcome.iterations} "
                f"iteration(s) (sigma with the orientations held above {solver_options.point_sigma_ratio:g}x the median "
                f"{np.median(sigma[np.isfinite(sigma)]):.3g} m, or a "
                f"singular point block): {listed}{', ...' if flagged.sum() > 5 else ''}")
        left_out.append(text)
        previous = SimpleNamespace(block=block, state=outcome.state, problem=problem)
        block = _leave_out(block, None, flagged, text, undetermined=int(flagged.sum()))
        problem, state, notes = setup(block, previous, {cam.camera_id: cam.ap for cam in problem.cameras})
    notes = left_out + notes
    outcome.history = history
    outcome.iterations = len(history)
    try:
        lin = outcome.linearisation
        dense = dense_assembly(problem.n_theta,
                               solver_options.free_network and problem.n_theta <= PSEUDO_INVERSE_LIMIT)
        if outcome.reduction is not None:
            S, factor, v_inv = outcome.reduction
        else:
            S, _, v_inv = reduce(problem, lin, 0.0, dense)
            factor = None
    except SingularPoints as exc:
        ids = ", ".join(f"'{block.points.point_id[i]}'" for i in exc.indices[:5])
        raise AdjustmentError(f"{exc} (e.g. {ids}): remove them or check their observations") from None
    if solver_options.free_network:
        Q = _free_network_cofactor(S, notes)
    else:
        try:
            factor = factor or factorise(S)
        except SingularSystem as exc:
            directions = null_directions(S, names)
            raise AdjustmentError(f"the normal equations are singular at the solution ({exc}):\n  "
                                  + "\n  ".join(directions)) from None
        Q = factor.cofactor()
        if factor.method == "superlu":
            notes.append("sparse factorisation by SciPy's SuperLU: CHOLMOD (scikit-sparse) is not installed; "
                         "`make install` or `pip install selfcal[cholmod]` installs it (1-2x faster)")
    if not solver_options.free_network:
        note = weakly_determined(S, Q, names, problem)
        if note:
            notes.append(note)
    variance_factor = 2.0 * outcome.cost / (n_obs - n_unk)
    v_sorted = -image_residuals(problem, outcome.state)
    residuals = np.empty_like(v_sorted)
    residuals[problem.obs_order] = v_sorted
    return AdjustmentResult(
        problem=problem,
        state=outcome.state,
        block=block,
        converged=outcome.converged,
        reason=outcome.reason,
        iterations=outcome.iterations,
        history=outcome.history,
        cost=outcome.cost,
        n_observations=n_obs,
        n_unknowns=n_unk,
        variance_factor=variance_factor,
        image_sigma_px=block.image_sigma_px,
        theta_names=names,
        Q_theta=Q,
        residuals=residuals,
        notes=notes,
        seconds=time.perf_counter() - t0,
        linearisation=lin,
        v_inv=v_inv,
        reduced_matrix=(S if isinstance(S, np.ndarray) else S.toarray()) if S.shape[0] <= UPDATE_LIMIT else None,
        datum_null=outcome.datum_null,
        robust=weighting,
    )
