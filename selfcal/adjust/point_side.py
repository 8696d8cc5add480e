"""The points' side of the solver: what an iteration asks of the object points and their observations.

The solver (:func:`selfcal.adjust.solver.solve`) works on theta, the unknowns that remain once the points are
eliminated; everything it needs of the points is a sum over them (the points' part of the normal equations and of
the reduced system, the cost, a few products with the points' correction) or their correction itself. A point side
gives these. :class:`LocalPoints` holds every point in this process (the engine's passes over the chunks, on its
threads); :class:`selfcal.adjust.distributed.ClusterPoints` holds shares of the points on the workers of a Dask
cluster, each answering for its own, and adds their parts. The solver is the same for both.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .covariance import point_cofactors, some_point_cofactors
from .datum import points_centroid, points_not_determined_by_rays, similarity_sums
from .leverage import image_leverages
from .problem import Problem, State
from .schur import (Linearisation, ReducedSums, add_point_schur, assemble, back_substitute, linearise_points,
                    points_cost_and_residuals)

__all__ = ["PointStep", "PointSide", "LocalPoints"]


@dataclass(frozen=True)
class PointStep:
    """What the solver needs of the points' correction d_p (besides d_p): its products with the points' part of
    the right-hand side and of the normal matrix's diagonal (the predicted decrease of the cost, the damping's
    term), and its largest entry in units of its conditional sigma."""

    g_dot: float            # sum of d_p . g_p
    diag_dot: float         # sum of diag(V) d_p^2
    max_sigma: float        # max of |d_p| sqrt(diag(V))


class PointSide(Protocol):
    """The points' side of one problem's solve (module docstring)."""

    def linearise(self, state: State) -> Linearisation:
        """The points' part of the normal equations at ``state`` (:func:`~selfcal.adjust.schur.linearise_points`),
        kept for the calls below."""

    def undetermined(self, ratio: float) -> np.ndarray:
        """The points (block numbering) that their rays do not determine at the last linearisation."""

    def reduce(self, lin: Linearisation, lam: float, dense: bool) -> tuple:
        """(S, g): the reduced system of the last linearisation completed as ``lin`` (the observations of theta
        alone), damped by ``lam``; the damped point blocks' inverses are kept for :meth:`back_substitute`."""

    def back_substitute(self, d_theta: np.ndarray) -> tuple[np.ndarray, PointStep]:
        """The points' correction (n_points, 3) of the last reduction for ``d_theta``, and its sums."""

    def cost(self, state: State) -> tuple[float, np.ndarray | None]:
        """The cost's part of the image observations and the observations of points at ``state``, with the image
        residuals where this side has them (None where they stay with the points)."""

    def reweighted(self) -> None:
        """The problem's weight factors moved (a robust weighting's): the side's copies follow."""

    def similarity_sums(self, state: State) -> np.ndarray:
        """A free network's sum over the points of :func:`~selfcal.adjust.datum.similarity_directions` at the last
        linearisation, about the centroid of ``state``'s points."""

    def gathered(self, lin: Linearisation) -> tuple[Linearisation, list | None]:
        """``lin`` with the points' part of the last linearisation (its chunks) and the last reduction's
        point inverses in this process (a re-adjustment's downdated start reads them)."""

    # -- the results after the solve, from the last linearisation and reduction (undamped) ------------------
    def point_cofactors(self, Q) -> np.ndarray:
        """The points' cofactor blocks (n_points, 3, 3) (:func:`~selfcal.adjust.covariance.point_cofactors`) for
        ``Q`` = Q_theta."""

    def some_point_cofactors(self, Q, points: np.ndarray) -> np.ndarray:
        """The cofactor blocks (len(points), 3, 3) of the points ``points`` (block numbering) alone."""

    def image_leverages(self, state: State, Q, Q_points: np.ndarray | None) -> tuple:
        """(h, r, Q_points) of :func:`~selfcal.adjust.leverage.image_leverages`: every image coordinate's
        leverage and whitened residual (the problem's sorted order) and the points' cofactor blocks (``Q_points``
        where given)."""

    def close(self) -> None:
        """Nothing more will be asked: what the side holds elsewhere goes."""


class LocalPoints:
    """Every point in this process: the engine's passes over the chunks (:mod:`.parallel`). The last
    linearisation's chunks and the last reduction's point inverses stay for the results."""

    def __init__(self, problem: Problem):
        self.problem = problem
        self.lin: Linearisation | None = None
        self.v_inv: list | None = None

    def linearise(self, state: State) -> Linearisation:
        self.lin = linearise_points(self.problem, state)
        self.v_inv = None
        return self.lin

    def undetermined(self, ratio: float) -> np.ndarray:
        assert self.lin is not None
        return points_not_determined_by_rays(geometric_blocks(self.problem, self.lin), ratio)[0]

    def reduce(self, lin: Linearisation, lam: float, dense: bool) -> tuple:
        sums = ReducedSums.start(self.problem, lin)
        self.v_inv = add_point_schur(self.problem, lin.chunks, lam, sums)
        return assemble(self.problem, lin, sums, lam, dense), sums.g

    def back_substitute(self, d_theta: np.ndarray) -> tuple[np.ndarray, PointStep]:
        assert self.lin is not None and self.v_inv is not None
        d_p = back_substitute(self.problem, self.lin, self.v_inv, d_theta)
        return d_p, point_step(d_p, self.lin.of_points("V"), self.lin.of_points("g_p"))

    def cost(self, state: State) -> tuple[float, np.ndarray | None]:
        return points_cost_and_residuals(self.problem, state)

    def reweighted(self) -> None:
        """Nothing: the side works on the problem itself."""

    def similarity_sums(self, state: State) -> np.ndarray:
        assert self.lin is not None
        return similarity_sums(self.problem, self.lin, state.points, points_centroid(state.points))

    def gathered(self, lin: Linearisation) -> tuple[Linearisation, list | None]:
        return lin, self.v_inv

    def point_cofactors(self, Q) -> np.ndarray:
        assert self.lin is not None and self.v_inv is not None
        return point_cofactors(self.problem, self.lin, self.v_inv, Q)

    def some_point_cofactors(self, Q, points: np.ndarray) -> np.ndarray:
        assert self.lin is not None and self.v_inv is not None
        return some_point_cofactors(self.problem, self.lin, self.v_inv, Q, points)

    def image_leverages(self, state: State, Q, Q_points: np.ndarray | None) -> tuple:
        assert self.lin is not None and self.v_inv is not None
        return image_leverages(self.problem, state, self.lin, self.v_inv, Q, Q_points)

    def close(self) -> None:
        """Let go of the linearisation and the inverses (an adjustment that starts again from here builds its own
        while this side's would still be held)."""
        self.lin = self.v_inv = None


def point_step(d_p: np.ndarray, V: np.ndarray, g_p: np.ndarray) -> PointStep:
    """The :class:`PointStep` of points' corrections ``d_p`` with their normal blocks ``V`` and right-hand sides
    ``g_p`` (the same points, in the same order)."""
    diag_p = np.einsum("nii->ni", V)
    return PointStep(float(np.sum(d_p * g_p)), float(np.sum(diag_p * d_p * d_p)),
                     float(np.max(np.abs(d_p) * np.sqrt(diag_p), initial=0.0)))


def geometric_blocks(problem: Problem, lin: Linearisation) -> np.ndarray:
    """The points' normal blocks as their rays' geometry makes them: each divided by its strongest ray's weight
    factor (a robust weighting takes weight from a point's rays, not geometry from the point: a point whose rays
    all weigh little is not undetermined but doubtful, and the cleaning decides about it)."""
    V = lin.of_points("V")
    if problem.obs_weight is None or np.all(problem.obs_weight == 1.0):
        return V
    strongest = np.zeros(problem.n_points)
    np.maximum.at(strongest, problem.obs_point, problem.obs_weight)
    return V / np.maximum(strongest, 1e-300)[:, None, None]
