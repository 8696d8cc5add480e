"""Weighted Gauss-Newton with Levenberg-Marquardt damping on the reduced normal equations."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import AdjustmentError
from .linalg import DENSE_LIMIT, SingularSystem, factorise, null_directions
from .normal import Linearisation, back_substitute, evaluate_cost, linearise, reduce
from .problem import Problem, State

__all__ = ["SolverOptions", "IterationRecord", "SolverOutcome", "solve"]


@dataclass(frozen=True)
class SolverOptions:
    """How to iterate.

    Attributes
    ----------
    max_iterations : int
    step_tolerance : float
        Converged when every correction is below this share of its conditional
        standard deviation (|dx_i| · sqrt(N_ii) < tol, unit variance).
    cost_tolerance : float
        ... or when an accepted step lowers the cost by less than this share.
    initial_damping : float
        Levenberg-Marquardt damping of the first step (relative to diag(N)).
        Zero (pure Gauss-Newton) by default: damping slows progress along the
        weakly determined directions a photogrammetric block always has (c
        against Z0, x0 against X0 and phi); it is switched on only when a step
        fails to lower the cost, and off again once steps succeed.
    free_network : bool
        The block has no datum (no control, no trajectory observations): the
        normal equations are singular by the datum defect (7 for a similarity).
        Levenberg-Marquardt damping then stays on (never below 1e-12), as in
        Ceres, and the estimate is one of the equivalent solutions. Meant for
        relative problems such as BAL benchmarks; no covariance follows.
    """

    max_iterations: int = 50
    step_tolerance: float = 1e-3
    cost_tolerance: float = 1e-12
    initial_damping: float = 0.0
    free_network: bool = False


@dataclass(frozen=True)
class IterationRecord:
    """One iteration: the cost after it, the damping used, the largest
    correction in units of its conditional sigma, and sigma0 (unitless) so far."""

    iteration: int
    cost: float
    damping: float
    max_step_sigma: float
    accepted: bool
    sigma0: float


@dataclass
class SolverOutcome:
    state: State
    linearisation: Linearisation
    converged: bool
    reason: str
    iterations: int
    history: list[IterationRecord]


def _singular_message(problem: Problem, S, names: list[str], detail: str) -> str:
    directions = null_directions(S, names)
    text = f"the normal equations are singular ({detail})"
    if directions:
        text += "; undetermined combinations of unknowns:\n  " + "\n  ".join(directions)
    return text


def solve(problem: Problem, state: State, names: list[str], options: SolverOptions = SolverOptions(),
          progress: Callable[[IterationRecord], None] | None = None) -> SolverOutcome:
    """Iterate to the least-squares estimate.

    Raises
    ------
    AdjustmentError
        When the normal equations are singular (rank defect); the message names
        the unknowns involved.
    """
    dense = problem.n_theta <= DENSE_LIMIT
    lin = linearise(problem, state)
    if not np.isfinite(lin.cost):
        raise AdjustmentError("the initial residuals are not finite (points behind a camera?)")
    redundancy = max(problem.n_observations() - problem.n_unknowns(), 1)
    lam, nu = options.initial_damping, 2.0
    min_damping = 1e-12 if options.free_network else 0.0
    if options.free_network:
        lam = max(lam, 1e-4)
    history: list[IterationRecord] = []
    converged, reason = False, f"no convergence within {options.max_iterations} iterations"
    iteration = 0
    for iteration in range(1, options.max_iterations + 1):
        while True:
            S, g, v_inv = reduce(problem, lin, lam, dense)
            try:
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
        d_p = back_substitute(problem, lin, v_inv, d_theta)
        candidate = problem.apply(state, d_theta, d_p)
        new_cost = evaluate_cost(problem, candidate)
        diag_p = np.concatenate([np.einsum("nii->ni", ch.V) for ch in lin.chunks])
        g_p = np.concatenate([ch.g_p for ch in lin.chunks])
        predicted = 0.5 * (d_theta @ lin.g_theta + np.sum(d_p * g_p)
                           + lam * (d_theta @ (lin.diag_theta * d_theta) + np.sum(diag_p * d_p * d_p)))
        step_sigma = max(float(np.max(np.abs(d_theta) * np.sqrt(lin.diag_theta), initial=0.0)),
                         float(np.max(np.abs(d_p) * np.sqrt(diag_p), initial=0.0)))
        rho = (lin.cost - new_cost) / predicted if predicted > 0 else -1.0
        # a step that changes the cost by no more than rounding is as good as accepted
        negligible = abs(new_cost - lin.cost) <= 1e-12 * lin.cost
        accepted = bool(np.isfinite(new_cost) and (rho > 0 or negligible))
        cost_now = new_cost if accepted else lin.cost
        record = IterationRecord(iteration, cost_now, lam, step_sigma, accepted,
                                 float(np.sqrt(2.0 * cost_now / redundancy)))
        history.append(record)
        if progress is not None:
            progress(record)
        if accepted:
            old_cost = lin.cost
            state = candidate
            lin = linearise(problem, state)
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * min(max(rho, 0.0), 1.0) - 1.0) ** 3)
            lam = min_damping if lam < 1e-9 else lam
            nu = 2.0
            if step_sigma < options.step_tolerance:
                converged, reason = True, f"corrections below {options.step_tolerance:g} sigma"
                break
            if old_cost - lin.cost <= options.cost_tolerance * max(lin.cost, 1e-300):
                converged, reason = True, "cost no longer decreases"
                break
        else:
            lam = 1e-4 if lam == 0.0 else lam * nu
            nu *= 2.0
            if lam > 1e12:
                reason = "diverged: no step lowers the cost"
                break
    return SolverOutcome(state, lin, converged, reason, iteration, history)
