"""Weighted Gauss-Newton on the reduced normal equations, with a line search and Levenberg-Marquardt damping.

A Gauss-Newton step that does not lower the cost is first shortened along
its own direction (halving, down to 1/64). Self-calibration makes this the
common case: with ground control only, a camera-fixed rotation (all phi of
the block turning with the flight direction) trades against the principal
point and the AP field almost exactly, so the block has a long, slightly
curved valley. The full step overshoots across it; a shortened step follows
it (db4 with 257 APs on Type 1: 13 iterations, where damping crawled for 32).
Only when no shortened step helps is damping switched on.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from ..errors import AdjustmentError
from .datum import similarity_directions
from .linalg import PSEUDO_INVERSE_LIMIT, dense_assembly, SingularSystem, factorise, null_directions, pseudo_factorise
from .options import SolverOptions
from .point_side import LocalPoints, PointSide
from .schur import Linearisation, parameter_cost, with_parameter_observations
from .problem import Problem, State

__all__ = ["IterationRecord", "SolverOutcome", "solve"]


@dataclass(frozen=True)
class IterationRecord:
    """One iteration: the cost after it, the damping used, the largest
    correction in units of its conditional sigma, and sigma0 (unitless) so far.
    ``moved_sigma``: how far the step moves any function of the unknowns at most, in units of its
    a-posteriori sigma (sqrt(d^T N d) / sigma0, the function test's measure); infinite for a damped or
    shortened step, which the function test does not judge."""

    iteration: int
    cost: float
    damping: float
    max_step_sigma: float
    accepted: bool
    sigma0: float
    moved_sigma: float = float("inf")


@dataclass
class SolverOutcome:
    """The estimate and the normal equations its precision comes from.

    After convergence the last correction (below the tolerances) is applied to
    ``state``, and ``linearisation`` is the one it was solved from, as in the
    classic adjustment (the cofactors of the last normal equations): linearising
    again at a point that moved by less than 1e-3 sigma changes no reported digit and
    costs a full assembly. ``reduction`` is then that system's undamped
    (S, factor), or None when the last step was damped; the point side (``points``)
    keeps that system's point inverses.
    """

    state: State
    linearisation: Linearisation
    converged: bool
    reason: str
    iterations: int
    history: list[IterationRecord]
    cost: float                     # at ``state``
    reduction: tuple | None = None
    undetermined: np.ndarray | None = None     # points to leave out (``point_sigma_ratio``), else None
    datum_null: np.ndarray | None = None       # a free network's datum directions at the last factorisation


def _singular_message(problem: Problem, S, names: list[str], detail: str) -> str:
    directions = null_directions(S, names)
    text = f"the normal equations are singular ({detail})"
    if directions:
        text += "; undetermined combinations of unknowns:\n  " + "\n  ".join(directions)
    return text


def _cost(problem: Problem, points: PointSide, state: State) -> tuple[float, np.ndarray | None]:
    """0.5 v^T P v of all observation groups at ``state`` (the points' part from their side), and the image
    residuals where the side has them."""
    cost, residuals = points.cost(state)
    return cost + parameter_cost(problem, state), residuals


def _shortened(problem: Problem, points: PointSide, state: State, cost: float, d_theta: np.ndarray,
               d_p: np.ndarray, predicted: float, halvings: int):
    """The Gauss-Newton step halved until it lowers the cost (at most ``halvings`` >= 1 times).

    For the undamped step the model predicts a decrease (a - a^2/2) d^T g for
    the share a of the step; the full step's prediction is d^T g / 2.
    Returns the last step tried, its share of the full step, its state, cost and predicted decrease.
    """
    share = 1.0
    for _ in range(halvings):
        share *= 0.5
        candidate = problem.apply(state, share * d_theta, share * d_p)
        new_cost = _cost(problem, points, candidate)[0]
        if new_cost < cost:
            break
    return (share * d_theta, share * d_p, share, candidate, new_cost,
            2.0 * predicted * (share - 0.5 * share * share))


def _converged(options: SolverOptions, step_sigma: float, moved_sigma: float, cost: float, new_cost: float) -> str | None:
    """Why an accepted step ends the iteration, or None."""
    if step_sigma < options.step_tolerance:
        return f"corrections below {options.step_tolerance:g} sigma"
    # below the tolerance, no estimate moved by a visible share of its a-posteriori sigma (the conditional
    # step_sigma above can stay large in a correlated block)
    if moved_sigma < options.function_tolerance:
        return f"no estimate moves by {options.function_tolerance:g} of its sigma"
    if cost - new_cost <= options.cost_tolerance * max(new_cost, 1e-300):
        return "cost no longer decreases"
    return None


def solve(problem: Problem, state: State, names: list[str], options: SolverOptions = SolverOptions(),
          progress: Callable[[IterationRecord], None] | None = None,
          datum_null: np.ndarray | None = None,
          reweight: Callable[..., bool] | None = None, points: PointSide | None = None) -> SolverOutcome:
    """Iterate to the least-squares estimate.

    ``datum_null``: a free network's datum directions from an earlier solve of the same unknowns
    (``SolverOutcome.datum_null``), followed from there instead of found by an eigendecomposition.
    ``reweight``: called with the problem and the state at the start and after every accepted step (there with
    the step's image residuals too, as the cost evaluated them), it may
    change the observations' weight factors (a robust loss: :mod:`selfcal.adjust.robust`) and says whether it
    did; the estimate has converged only once a step passes the tests and no weight moved.
    ``points``: the points' side (:mod:`.point_side`); by default every point in this process.

    Raises
    ------
    AdjustmentError
        When the normal equations are singular (rank defect); the message names
        the unknowns involved.
    """
    pseudo = options.free_network and problem.n_theta <= PSEUDO_INVERSE_LIMIT
    dense = dense_assembly(problem.n_theta, pseudo)
    side: PointSide = LocalPoints(problem) if points is None else points
    if reweight is not None:
        reweight(problem, state)
        side.reweighted()
    lin = with_parameter_observations(problem, state, side.linearise(state))
    if not np.isfinite(lin.cost):
        raise AdjustmentError("the initial residuals are not finite (points behind a camera?)")
    redundancy = max(problem.n_observations() - problem.n_unknowns(), 1)
    lam, nu = options.initial_damping, 2.0
    damped_free = options.free_network and not pseudo
    min_damping = 1e-9 if damped_free else 0.0
    if damped_free and lam == 0.0:
        lam = 1e-4
    history: list[IterationRecord] = []
    converged, reason = False, f"no convergence within {options.max_iterations} iterations"
    iteration = 0
    reduction = None
    checked = None
    null = datum_null if datum_null is not None and len(datum_null) == problem.n_theta else None
    if pseudo and null is None:
        # the similarity's directions, checked by the factorisation (an eigendecomposition where they are not the
        # null space): 0.17 s of a 200-image block's first iteration
        null = similarity_directions(problem, state, lin, side.similarity_sums(state))
    def outcome(state: State, lin: Linearisation, converged: bool, reason: str, iterations: int, cost: float,
                reduction: tuple | None = None, undetermined: np.ndarray | None = None) -> SolverOutcome:
        return SolverOutcome(state, lin, converged, reason, iterations, history, cost, reduction, undetermined, null)

    for iteration in range(1, options.max_iterations + 1):
        if options.point_sigma_ratio and checked is not lin:
            checked = lin
            bad = side.undetermined(options.point_sigma_ratio)
            if bad.size:
                return outcome(state, lin, False, f"{bad.size} points not determined by their rays", iteration - 1,
                               lin.cost, undetermined=bad)
        while True:
            S, g = side.reduce(lin, lam, dense)
            try:
                if pseudo and lam == 0.0:
                    factor = pseudo_factorise(S, null)
                    null = factor.null
                else:
                    factor = factorise(S)
                break
            except SingularSystem as exc:
                if lam == 0.0 and iteration == 1 and not options.free_network:
                    # undamped normal equations singular at the start: a rank defect, not bad luck
                    raise AdjustmentError(_singular_message(problem, S, names, str(exc))) from None
                lam = max(lam * 10, 1e-8)
                if lam > 1e12:
                    raise AdjustmentError("the damped normal equations cannot be factorised") from None
        d_theta = factor.solve(g)
        d_p, step = side.back_substitute(d_theta)
        candidate = problem.apply(state, d_theta, d_p)
        residuals: np.ndarray | None
        new_cost, residuals = _cost(problem, side, candidate)
        predicted = 0.5 * (d_theta @ lin.g_theta + step.g_dot
                           + lam * (d_theta @ (lin.diag_theta * d_theta) + step.diag_dot))
        # d^T N d of the undamped N ((N + lam D) d = g): how far the step moves any function of the unknowns
        # in units of its sigma; blind to the datum directions, along which N is null
        moved = 2.0 * predicted - 2.0 * lam * (d_theta @ (lin.diag_theta * d_theta) + step.diag_dot)
        full_gauss_newton = lam == 0.0
        if full_gauss_newton and not damped_free and np.isfinite(new_cost) and not new_cost < lin.cost:
            sigma0_now = float(np.sqrt(2.0 * lin.cost / redundancy))
            moved_now = float(np.sqrt(max(2.0 * predicted, 0.0))) / sigma0_now
            if moved_now < options.function_tolerance:
                # a Gauss-Newton step that moves no estimate by the tolerance of its sigma, and a cost that does not
                # fall: what the step would gain is below the rounding of the cost's sum (a line search and damped
                # steps would chase that rounding for many iterations). The estimate stays where it is.
                step_sigma = max(float(np.max(np.abs(d_theta) * np.sqrt(lin.diag_theta), initial=0.0)),
                                 step.max_sigma)
                record = IterationRecord(iteration, lin.cost, lam, step_sigma, True, sigma0_now, moved_now)
                history.append(record)
                if progress is not None:
                    progress(record)
                return outcome(state, lin, True, f"no estimate moves by {options.function_tolerance:g} of its sigma",
                               iteration, lin.cost, (S, factor))
        if (full_gauss_newton and options.line_search and not damped_free and not new_cost < lin.cost
                and abs(new_cost - lin.cost) > 1e-12 * lin.cost):
            d_theta, d_p, share, candidate, new_cost, predicted = _shortened(
                problem, side, state, lin.cost, d_theta, d_p, predicted, options.line_search)
            # (the share is a power of two: the points' largest scaled entry is the full step's times it, exactly)
            step = replace(step, max_sigma=share * step.max_sigma)
            full_gauss_newton = False
            residuals = None
        step_sigma = max(float(np.max(np.abs(d_theta) * np.sqrt(lin.diag_theta), initial=0.0)), step.max_sigma)
        rho = (lin.cost - new_cost) / predicted if predicted > 0 else -1.0
        # a step that changes the cost by no more than rounding is as good as accepted
        negligible = abs(new_cost - lin.cost) <= 1e-12 * lin.cost
        accepted = bool(np.isfinite(new_cost) and (rho > 0 or negligible))
        cost_now = new_cost if accepted else lin.cost
        sigma0 = float(np.sqrt(2.0 * cost_now / redundancy))
        # an undamped step d changes any function a^T x by at most sqrt(d^T N d) = sqrt(2 predicted) times its
        # sigma (unit weight); a damped free network's by sqrt(d^T N d) of the undamped N once the damping is small
        moved_sigma = float("inf")
        if full_gauss_newton:
            moved_sigma = float(np.sqrt(2.0 * predicted)) / sigma0
        elif damped_free and lam <= 1e-6:
            moved_sigma = float(np.sqrt(max(moved, 0.0))) / sigma0
        record = IterationRecord(iteration, cost_now, lam, step_sigma, accepted, sigma0, moved_sigma)
        history.append(record)
        if progress is not None:
            progress(record)
        if accepted:
            state = candidate
            # the weights follow the estimate; while they move, the objective does, and nothing has converged
            moved_weights = reweight is not None and reweight(problem, state, residuals)
            if moved_weights:
                side.reweighted()
            done = None if moved_weights else _converged(options, step_sigma, moved_sigma, lin.cost, new_cost)
            if done is not None:
                converged, reason = True, done
                if lam == 0.0:
                    reduction = (S, factor)
                return outcome(state, lin, converged, reason, iteration, new_cost, reduction)
            lin = with_parameter_observations(problem, state, side.linearise(state))
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * min(max(rho, 0.0), 1.0) - 1.0) ** 3)
            lam = min_damping if lam < 1e-9 else lam
            nu = 2.0
        else:
            lam = 1e-4 if lam == 0.0 else lam * nu
            nu *= 2.0
            if lam > 1e12:
                reason = "diverged: no step lowers the cost"
                break
    return outcome(state, lin, converged, reason, iteration, lin.cost)
