"""Robust estimation: iteratively reweighted least squares with a chosen loss, its scale from the residuals.

Each image point's two whitened residuals (v / sigma, sigma its a-priori standard deviation) give one
normalised size u = |v / sigma| / s, s the robust scale of the block (unitless; 1 = the a-priori sigma); each
control point's three coordinates likewise. The loss turns u into a weight factor w(u) in (0, 1] of the
observation's rows (a re-weighted observation is one with sigma / sqrt(w), :mod:`.residuals.image`):

=========  =========================================  ===================  =================
loss       w(u)                                       c (default)          inliers with w<1
=========  =========================================  ===================  =================
huber      1 for u <= c, c / u beyond                 2.5                  4.4 %
cauchy     1 / (1 + (u / c)^2)                        2.5                  all
danish     1 for u <= c, exp(1 - (u / c)^2) beyond    3.0                  1.1 %
=========  =========================================  ===================  =================

(the last column for a blunder-free block: u of an image point is Rayleigh distributed, P(u > c) =
exp(-c^2 / 2)). ``danish`` is a continuous form of Krarup's Danish method (Krarup, Juhl & Kubik 1980): least
squares in the core, a Gaussian decay beyond, so that gross errors end with weights of 1e-4 and less.
Every w is non-increasing in u, so each re-weighted least-squares step lowers the robust objective
sum rho(u) (the weights define a quadratic that majorises it): the reweighting is an MM algorithm.

The scale s: ``mad`` from the residuals, the median of u over the observations below three scales, divided
by the median of a Rayleigh distribution truncated there (1.1678; 1.1774 untruncated), iterated from the
plain median (the plain median of a block with 30 % gross errors is 1.34x the inliers' scale, the trimmed one
within 2 %), but never below 1: an observation within its a-priori sigma keeps its full weight however well the
bulk fits (real matcher residuals have a narrow core and long tails: the bulk of COPR's COLMAP observations is at
0.30 of their a-priori sigma, BAL problem-49's at 0.18, and a scale of their own took most of their tails for
gross errors); a scale above 1 says the a-priori sigmas are too small or the model misses something. ``apriori``:
s = 1, the a-priori sigmas taken as they are.

The weights are re-computed at every accepted step of the solver (:func:`selfcal.adjust.solver.solve` calls
:meth:`RobustWeighting.update`); a weight is changed only where it moves by more than ``tolerance`` (0.02),
so that the rows whose weight stays (the inliers of a loss with a core) keep their kept AP columns and Gram
matrix, and the adjustment has converged when the step is below the tolerances and no weight moved.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["LOSSES", "Loss", "Huber", "Cauchy", "Danish", "RobustOptions", "RobustWeighting", "robust_scale",
           "RAYLEIGH_MEDIAN"]

#: the median of a Rayleigh distribution of unit scale, sqrt(2 ln 2)
RAYLEIGH_MEDIAN = float(np.sqrt(2.0 * np.log(2.0)))
#: the median of a chi variable with three degrees of freedom (a control point's three whitened residuals)
CHI3_MEDIAN = 1.5382
#: smallest weight factor the engine applies (a row weighted 1e-8 of itself is gone; zero would make a point's
#: block singular where all its rays go)
MIN_WEIGHT = 1e-8
#: the least weight factor of a control or check point's rays (measured by hand)
HAND_WEIGHT = 0.1
#: the control points' coordinates are weighted only in a block with more control points than this: with few, the
#: datum itself would lose weight and the block float away from it (seed 001's triplet with 4 GCPs: 3 were then
#: "off" by 30 sigmas)
MIN_ROBUST_CONTROL = 6
#: updates of the weights at most in one solve
MAX_UPDATES = 40


@dataclass(frozen=True)
class Loss:
    """A robust loss: the weight w(u) of a normalised residual size u >= 0 and the objective rho(u)."""

    c: float

    name = ""

    def weight(self, u: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def rho(self, u: np.ndarray) -> np.ndarray:
        """The objective, with rho(u) = u^2 / 2 near zero."""
        raise NotImplementedError


@dataclass(frozen=True)
class Huber(Loss):
    c: float = 2.5
    name = "huber"

    def weight(self, u):
        u = np.asarray(u, float)
        return np.where(u <= self.c, 1.0, self.c / np.maximum(u, self.c))

    def rho(self, u):
        u = np.asarray(u, float)
        return np.where(u <= self.c, 0.5 * u * u, self.c * u - 0.5 * self.c * self.c)


@dataclass(frozen=True)
class Cauchy(Loss):
    c: float = 2.5
    name = "cauchy"

    def weight(self, u):
        u = np.asarray(u, float)
        return 1.0 / (1.0 + (u / self.c) ** 2)

    def rho(self, u):
        u = np.asarray(u, float)
        return 0.5 * self.c * self.c * np.log1p((u / self.c) ** 2)


@dataclass(frozen=True)
class Danish(Loss):
    c: float = 3.0
    name = "danish"

    def weight(self, u):
        u = np.asarray(u, float)
        return np.where(u <= self.c, 1.0, np.exp(1.0 - np.minimum(u / self.c, 1e3) ** 2))

    def rho(self, u):
        # rho' = u w(u): beyond c the integral of u exp(1 - u^2/c^2), i.e. c^2/2 (1 - exp(1 - u^2/c^2))
        u = np.asarray(u, float)
        core = 0.5 * u * u
        tail = 0.5 * self.c * self.c * (2.0 - np.exp(1.0 - np.minimum(u / self.c, 1e3) ** 2))
        return np.where(u <= self.c, core, tail)


#: loss name -> its class (``--robust NAME``)
LOSSES: dict[str, type[Huber | Cauchy | Danish]] = {"huber": Huber, "cauchy": Cauchy, "danish": Danish}


@dataclass(frozen=True)
class RobustOptions:
    """How the robust adjustment weights its observations.

    Attributes
    ----------
    loss : str
        ``huber``, ``cauchy`` or ``danish`` (:data:`LOSSES`).
    c : float, optional
        The loss's tuning constant in units of the scale (default: the loss's own).
    scale : str
        ``mad`` (from the residuals) or ``apriori`` (the a-priori sigmas as they are).
    tolerance : float
        A weight is changed only where it moves by more than this.
    settled : float
        The weights have settled (and stay as they are) once no more than this share of the observations (or
        ten) would change by more than ``tolerance``: the last few weights of a redescending loss creep for
        dozens of iterations, each moving a handful of observations near the loss's knee. 1 %: the robust stage
        only sorts the gross errors out (u beyond ``reject``, far from the knee) and gives the least-squares
        adjustment its start; on the paper-scale block 0.1 % took 8 iterations (the last four moving 563, 273, 144
        and 84 of 80,634 weights) where 1 % takes 4, with the same check points.
    reject : float
        After the robust adjustment, observations with u above this (in units of the scale: a blunder-free image
        point exceeds 5 with probability 4e-6) are gross errors:
        the tested workflow rejects them before its tests (:mod:`selfcal.workflows.tested`).
    control : bool
        Weight the control points' coordinates too (a misidentified target).
    hand : tuple of str
        The roles of the points whose rays are measured by hand, not matched (targets: ``gcp``, ``chk``): their rays
        keep a tenth of their weight at least and are judged one by one (no shared weight of a two-ray point).
    """

    loss: str = "danish"
    c: float | None = None
    scale: str = "mad"
    tolerance: float = 0.02
    settled: float = 1e-2
    reject: float = 5.0
    control: bool = True
    hand: tuple[str, ...] = ("gcp", "chk")

    def __post_init__(self):
        if self.loss not in LOSSES:
            raise ValueError(f"unknown robust loss '{self.loss}' (known: {', '.join(LOSSES)}, or none)")
        if self.scale not in ("mad", "apriori"):
            raise ValueError(f"the robust scale is 'mad' or 'apriori', found '{self.scale}'")
        if self.c is not None and not self.c > 0:
            raise ValueError(f"the loss's tuning constant must be positive, found {self.c}")
        if not self.reject > 0:
            raise ValueError(f"the rejection threshold must be positive, found {self.reject}")

    def make_loss(self) -> Loss:
        cls = LOSSES[self.loss]
        return cls() if self.c is None else cls(self.c)


def _rays(problem, hand: tuple[str, ...] = ()) -> np.ndarray:
    """The number of rays of each image observation's point (problem order); a control point's, and a point of a
    role in ``hand`` (measured by hand), counts as many (a control point's coordinates check each ray)."""
    rays = np.bincount(problem.obs_point, minlength=problem.n_points)
    rays[problem.control_index] = np.iinfo(np.int64).max // 4
    if problem.point_role is not None and hand:
        rays[np.isin(problem.point_role, hand)] = np.iinfo(np.int64).max // 4
    return rays[problem.obs_point]


def robust_scale(u: np.ndarray, trim: float = 3.0, iterations: int = 5, dof: int = 2) -> float:
    """The scale of normalised residual sizes ``u`` (module docstring): the median over those below ``trim``
    scales, divided by the truncated median of their distribution, from the plain median on. ``dof``: 2 for the
    sizes of image points (Rayleigh), 1 for those of two-ray points, whose rays share one parallax (half-normal)."""
    from ..stats.distributions import chi_cdf, chi_ppf
    u = np.asarray(u, float)
    u = u[np.isfinite(u)]
    if not u.size:
        return 1.0
    scale = float(np.median(u)) / float(chi_ppf(0.5, dof))
    # the median of the distribution truncated at `trim` scales, in units of its scale
    truncated = float(chi_ppf(0.5 * chi_cdf(trim, dof), dof))
    for _ in range(iterations):
        inside = u[u <= trim * scale]
        if inside.size < 10:
            break
        new = float(np.median(inside)) / truncated
        if abs(new - scale) <= 1e-3 * scale:
            scale = new
            break
        scale = new
    return max(scale, 1e-12)


@dataclass
class RobustWeighting:
    """The weights of one adjustment's observations, updated from its residuals (module docstring).

    ``image`` (n_obs,) are the image observations' weight factors in the problem's order; ``control`` (n_gcp,)
    the control points'. ``history`` records the scale and the number of weights changed at every update."""

    options: RobustOptions
    loss: Loss = field(init=False)
    image: np.ndarray | None = None
    control: np.ndarray | None = None
    scale: float = 1.0
    residual_scale: float = 1.0      # the residuals' own (trimmed MAD), which ``scale`` never goes below 1 of
    control_scale: float = 1.0
    history: list = field(default_factory=list)

    def __post_init__(self):
        self.loss = self.options.make_loss()

    def sizes(self, problem, state, residuals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """u * scale of every image point and control point at ``state`` (whose image residuals l - f, sorted order,
        are ``residuals`` where the caller has them): the length of its whitened residuals
        (a-priori sigmas), an image point's over the square root of its point's share of redundancy, 1 - 3 / (2 n)
        for n rays (a two-ray point's rays share one parallax: 1/4; a point seen ten times: 0.85), as the w-test
        divides by the redundancy number."""
        from .residuals.image import image_residuals
        v = (image_residuals(problem, state) if residuals is None else residuals) / problem.obs_sigma_apriori
        image = np.sqrt(np.sum(v * v, axis=1) / (1.0 - 1.5 / np.maximum(_rays(problem, self.options.hand), 2)))
        control = np.zeros(0)
        block = problem.control
        if len(block):
            r, _ = block.whitened_rows(state.points[block.index])
            control = np.sqrt(np.sum(r * r, axis=1))
        return image, control

    def update(self, problem, state, residuals: np.ndarray | None = None) -> bool:
        """Re-weight ``problem``'s observations from the residuals at ``state`` (its image residuals, if the caller
        has them: :meth:`sizes`); whether any weight moved. After
        :data:`MAX_UPDATES` updates the weights stay (a weight flipping about the tolerance would go on)."""
        from .residuals.image import reweight_observations
        if len(self.history) >= MAX_UPDATES:
            return False
        image, control = self.sizes(problem, state, residuals)
        rays = _rays(problem, self.options.hand)
        scale = 1.0
        if self.options.scale == "mad":
            # from the points with three rays or more where there are enough: a two-ray point's residuals are one
            # parallax shared by its rays, in any split a robust weight gives them
            many = rays >= 3
            bulk = robust_scale(image[many]) if many.sum() >= 50 else robust_scale(image, dof=1)
            self.residual_scale = bulk
            scale = max(bulk, 1.0)
        new = np.maximum(self.loss.weight(image / scale), MIN_WEIGHT)
        # the rays of a two-ray point share the smaller weight: the data cannot tell which of them is wrong, and
        # weights of their own would move the point onto the heavier ray, its residual onto the lighter one (and
        # the scale with it, towards zero: a redescending loss makes the even split unstable)
        # (the hand-measured points count as many rays here: their own weights)
        pair = np.flatnonzero(rays == 2)
        if pair.size:
            lowest = np.full(problem.n_points, np.inf)
            np.minimum.at(lowest, problem.obs_point[pair], new[pair])
            new[pair] = lowest[problem.obs_point[pair]]
        # a control or check point's rays keep a tenth of their weight at least: they are few, measured by hand, and a
        # point whose rays all lose their weight floats away from them (the cleaning and the tests judge each ray)
        if problem.point_role is not None and self.options.hand:
            hand = np.isin(problem.point_role[problem.obs_point], self.options.hand)
            new[hand] = np.maximum(new[hand], HAND_WEIGHT)
        tolerance = self.options.tolerance
        block = problem.control
        # the control is weighted only where there is plenty of it (it is the datum), and keeps a tenth of its weight
        weigh_control = self.options.control and control.size > MIN_ROBUST_CONTROL
        control_scale = self.scale_of_control(control)
        w = np.maximum(self.loss.weight(control / control_scale), HAND_WEIGHT) if weigh_control else None
        moving = int(np.sum(np.abs(new - problem.obs_weight) > tolerance))
        moving += int(np.sum(np.abs(w - block.weight) > tolerance)) if weigh_control else 0
        if self.history and moving <= max(10, self.options.settled * len(image)):
            # settled: the weights stay as the last linearisation had them, and they are the weights of this scale
            # (those at it moved no more than the tolerance), so the scale is this one: the scale of an update at a
            # poor start (a pushbroom image's attitude bias uncorrected: 45x the a-priori sigma) would otherwise
            # judge the gross errors and make the diagnosis after the adjustment has removed that bias
            self.scale, self.control_scale = scale, control_scale
            self.history.append((self.scale, 0))
            return False
        self.scale, self.control_scale = scale, control_scale
        reweight_observations(problem, new, tolerance)
        if weigh_control:
            block.weight = np.where(np.abs(w - block.weight) > tolerance, w, block.weight)
        self.image = problem.obs_weight.copy()
        self.control = block.weight.copy() if len(block) else np.zeros(0)
        self.history.append((self.scale, moving))
        return moving > 0

    def normalised(self, problem, state) -> tuple[np.ndarray, np.ndarray]:
        """u of every image point (problem order) and control point at ``state``, each in units of its scale."""
        image, control = self.sizes(problem, state)
        return image / self.scale, control / self.control_scale

    def scale_of_control(self, control: np.ndarray) -> float:
        """The control points' own scale: their a-priori sigmas (1), or more where five or more of them say so (the
        median of u over that of a chi distribution with three degrees of freedom, 1.5382): a block's surveyed
        sigmas stated too small are not gross errors of every point."""
        if self.options.scale != "mad" or control.size < 5:
            return 1.0
        return max(1.0, float(np.median(control)) / CHI3_MEDIAN)
