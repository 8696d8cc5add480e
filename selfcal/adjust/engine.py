"""The adjustment engine's entry: :func:`adjust` sets up the problem (:mod:`.problem`), finds initial values
(:mod:`.initial`), iterates (:mod:`.solver`), weights robustly where asked (:mod:`.robust`) and extracts the
cofactor matrices (:mod:`.covariance`) into one :class:`~selfcal.adjust.result.AdjustmentResult`. It never reads
files and never prints; progress goes to an optional callback.

Where the APs are evaluated. Eq. (1) of seed 000 adds Delta at the measured image coordinates l = m + e (m the
true position, e the noise). Evaluated there, a basis function's column B(l) carries the noise it is regressed
on: to first order E[B(l)ᵀ v] = -sigma^2 div B at the true parameters, so the normal equations are biased by
sigma^2 times the summed divergence of the basis, and the estimate by Q (that sum): nothing in a fit of white
noise, but in a block where the APs trade with c, x0, y0 and the scale of the object (a free close-range network:
c with Brown's affinity b1 at -0.96) the bias is many sigmas (DESIGN-NOTES "Honest precision": on a simulated
block with the true camera, c 11 sigma off at 0.45 px of noise, back to 0.7 sigma with the basis at the true
positions). The adjusted coordinates l + v (v = f - l) are uncorrelated with the residuals (cov(l_hat, v) = 0
in a linear adjustment), so with ``APOptions.evaluated_at == "adjusted"`` (default) an adjustment that starts with
the basis at the measured coordinates converges, moves it to the adjusted ones
(:func:`at_adjusted_coordinates`, ``Observations.ap_at_px``) and converges again from there, :data:`AP_MOVES`
times; a re-adjustment of its block (snooping, screening) keeps them."""
from __future__ import annotations

import contextlib
import time
import weakref
from dataclasses import replace
from types import SimpleNamespace
from typing import Callable

import numpy as np

from ..block import Block, leave_out, prune
from ..errors import AdjustmentError
from . import distributed
from .ap_columns import carry_ap_columns
from .datum import FREE_POINT_SIGMA_RATIO, behind_camera, points_not_determined_by_rays
from .initial import PointsNotIntersected, initial_state
from .linalg import (DENSE_LIMIT, EIGH_FLOPS, PSEUDO_INVERSE_LIMIT, SingularSystem, blas_threads, dense_assembly,
                     factorise, null_directions, shared_product)
from .options import AdjustOptions
from .parameters import apply_free
from .ordering import inherited_point_key
from .problem import Problem, build_problem
from .residuals.image import image_residuals
from .result import AdjustmentResult
from .robust import RobustOptions, RobustWeighting
from .point_side import LocalPoints, PointSide
from .schur import SingularPoints
from .solver import IterationRecord, solve
from .update import UPDATE_LIMIT, downdated_start

__all__ = ["adjust", "start_values", "camera_models", "problem_at", "weakly_determined", "WEAK_INFLATION"]


def start_values(block: Block, options: AdjustOptions = AdjustOptions()):
    """The initial values an adjustment of ``block`` starts from (:mod:`.initial`), as a
    :class:`~selfcal.adjust.problem.State`: its images' orientations, and its points where the block gives them
    or intersected from the rays."""
    problem = build_problem(block, options)
    return initial_state(problem, block)[0]


def problem_at(block: Block, options: AdjustOptions = AdjustOptions(), start: "AdjustmentResult | None" = None,
               free: dict | None = None, ap_models: dict | None = None):
    """The problem an adjustment of ``block`` with ``options`` sets up, and its state at ``start``'s estimates
    (where the ids match; the others at their initial values) as :func:`adjust` would begin from them without a
    downdated step: what a linearisation at another adjustment's estimate needs (the model choice's candidates,
    :mod:`selfcal.workflows.model_choice`)."""
    key = None if start is None else inherited_point_key(block, start.block, start.problem)
    problem = build_problem(block, options, ap_models=ap_models, point_key=key)
    if free:
        apply_free(problem, free)
    return problem, _initial(problem, block, start, False)[0]


def _initial(problem: Problem, block: Block, start, robust: bool):
    """The initial state and its notes (:func:`~selfcal.adjust.initial.initial_state`), the sensors' sigmas refined
    at it and settled as the a-priori ones."""
    state, notes = initial_state(problem, block, start, robust)
    for slot in problem.sensors:
        slot.bound.refine_sigma(state, problem.obs_sigma)
    problem.settle_sigma()
    return state, notes


def camera_models(block: Block, options: AdjustOptions = AdjustOptions()) -> tuple[dict, int]:
    """The additional-parameter model of each camera an adjustment of ``block`` with ``options`` builds
    (camera id -> APModel: pass them to :func:`adjust` as ``ap_models`` to keep one basis), and the number of
    camera parameters it estimates."""
    problem = build_problem(block, options)
    return {cam.camera_id: cam.ap for cam in problem.cameras}, problem.n_d


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


#: how often an adjustment that starts with the AP basis at the measured coordinates moves it to the adjusted ones:
#: the first move leaves the errors-in-variables bias; the second starts from an estimate without it and moved c,
#: x0, y0 and the APs by up to 0.22 sigma on the simulated close-range block (1 px of noise), a third by less than
#: 0.001 sigma
AP_MOVES = 2


def _moves_ap_positions(options: AdjustOptions, problem: Problem, moves_left: int) -> bool:
    """Whether the adjustment just converged is to move its free frame APs' basis to the adjusted image
    coordinates (``options.ap.evaluated_at``; ``moves_left`` of :data:`AP_MOVES`)."""
    if options.ap.evaluated_at != "adjusted" or moves_left <= 0:
        return False
    with_aps = {k for k, cam in enumerate(problem.cameras) if cam.ap.n_params and cam.free[cam.n_core:].any()}
    if not with_aps:
        return False
    for slot in problem.sensors:
        if getattr(slot.bound, "adjusted_ap_positions", False) and \
                np.isin(problem.image_camera[slot.images], list(with_aps)).any():
            return True
    return False


def at_adjusted_coordinates(problem: Problem, block: Block, state) -> Block:
    """``block`` whose observations carry, as where their AP correction is evaluated
    (``Observations.ap_at_px``), their adjusted image coordinates at ``state``: the measured (col, row) plus the
    residual f - l, i.e. the model's prediction with the APs. Observations of sensors that keep the basis at the
    measured coordinates keep their measured pixels there."""
    l_minus_f = image_residuals(problem, state)                 # problem (sorted) order
    at = np.array(block.observations.pixel, float, copy=True)
    for slot in problem.sensors:
        if getattr(slot.bound, "adjusted_ap_positions", False):
            o = slot.observations
            at[problem.obs_order[o]] -= slot.bound.pixel_residuals(o, l_minus_f[o])
    return replace(block, observations=replace(block.observations, ap_at_px=at))


def _adjust(block: Block, options: AdjustOptions, progress, start, free, ap_models, robust,
            threads: contextlib.ExitStack) -> AdjustmentResult:
    t0 = time.perf_counter()
    # a block whose observations carry where their APs are evaluated (a re-adjustment) keeps it
    moves = AP_MOVES if block.observations.ap_at_px is None else 0

    def setup(block: Block, start, ap_models):
        key = None if start is None else inherited_point_key(block, start.block, start.problem)
        problem = build_problem(block, options, ap_models=ap_models, point_key=key)
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
        state, notes = _initial(problem, block, start, robust is not None)
        return problem, state, notes

    left_out: list[str] = []
    try:
        problem, state, notes = setup(block, start, ap_models)
    except PointsNotIntersected as exc:
        if robust is None:
            raise
        # a robust adjustment of matcher output: points whose (wrong) rays meet nowhere go, and the rest starts
        flagged = np.zeros(len(block.points), bool)
        flagged[exc.indices] = True
        ids = ", ".join(f"'{block.points.point_id[i]}'" for i in exc.indices[:5])
        text = (f"left out {int(flagged.sum())} points whose rays do not meet at a useful angle at the start "
                f"(e.g. {ids})")
        left_out.append(text)
        block = _leave_out(block, None, flagged, text, undetermined=int(flagged.sum()))
        problem, state, notes = setup(block, start, ap_models)
    # small blocks on one BLAS thread from here on; the AP basis above keeps them all (a WAP basis's frame sample)
    threads.enter_context(blas_threads(len(block.images)))
    solver_options = options.solver
    free_network = block.datum == "free" or solver_options.free_network
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
        # the points on a Dask cluster's workers, where the adjustment runs inside distributed.on_cluster
        side: PointSide = distributed.point_side(problem, block, options) or LocalPoints(problem)
        try:
            outcome = solve(problem, state, names, budget, numbered, datum_null,
                            None if weighting is None else weighting.update, side)
        except SingularPoints as exc:
            side.close()
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
        except BaseException:
            side.close()
            raise
        history += [replace(record, iteration=record.iteration + done) for record in outcome.history]
        datum_null = outcome.datum_null
        if outcome.undetermined is None or len(history) >= options.solver.max_iterations:
            if len(history) >= options.solver.max_iterations or not _moves_ap_positions(options, problem, moves):
                break
            # the AP basis moves to the adjusted image coordinates, and the estimate converges again from where it
            # is (module docstring)
            moves -= 1
            side.close()
            previous = SimpleNamespace(block=block, state=outcome.state, problem=problem)
            block = at_adjusted_coordinates(problem, block, outcome.state)
            # the columns at the old positions serve no more (nothing carries them to the new ones), nor does the
            # linearisation: neither is held while the new problem evaluates its own (a WAP basis on the paper's
            # block: 316 MiB of columns, 92 MiB of the points' camera couplings)
            problem.ap_cache.forget()
            outcome.linearisation = None        # type: ignore[assignment]
            problem, state, notes = setup(block, previous, {cam.camera_id: cam.ap for cam in problem.cameras})
            continue
        # a free network's points that their rays do not determine: left out, and on from the estimate so far
        flagged = np.zeros(len(block.points), bool)
        flagged[outcome.undetermined] = True
        assert solver_options.point_sigma_ratio is not None         # (the solver finds such points by it)
        try:
            sigma = points_not_determined_by_rays(side.gathered(outcome.linearisation)[0].of_points("V"),
                                                  solver_options.point_sigma_ratio)[1]
        finally:
            side.close()
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
        return _result(problem, block, outcome, side, names, notes, solver_options, n_obs, n_unk, weighting, t0)
    except BaseException:
        side.close()
        raise


def _result(problem: Problem, block: Block, outcome, side: PointSide, names: list[str], notes: list[str],
            solver_options, n_obs: int, n_unk: int, weighting, t0: float) -> AdjustmentResult:
    """The result of the converged (or stopped) ``outcome``: Q_theta from the undamped reduced system at its
    linearisation; the point side keeps that system's point inverses for the results of the points."""
    try:
        lin = outcome.linearisation
        dense = dense_assembly(problem.n_theta,
                               solver_options.free_network and problem.n_theta <= PSEUDO_INVERSE_LIMIT)
        if outcome.reduction is not None:
            S, factor = outcome.reduction
        else:
            S, _ = side.reduce(lin, 0.0, dense)
            factor = None
        problem.sparse_pattern = None               # (no more assemblies: its memory goes before Q_theta's comes)
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
    result = AdjustmentResult(
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
        points=side,
        reduced_matrix=(S if isinstance(S, np.ndarray) else S.toarray()) if S.shape[0] <= UPDATE_LIMIT else None,
        datum_null=outcome.datum_null,
        robust=weighting,
    )
    # the side's shares on a cluster's workers stay while the result does (or its cluster: distributed.on_cluster)
    weakref.finalize(result, side.close)
    return result

