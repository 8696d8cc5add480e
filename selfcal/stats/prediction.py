"""What an adjustment predicts for observations it has not seen: k-fold cross-validation over tie points.

The design (docs/DESIGN-NOTES.md, "Model choice by prediction"): the tie and check points are split into ``FOLDS``
folds by a hash of their ids (:func:`selfcal.adjust.folds.point_folds`; control points are never held out, and a
check point's surveyed coordinates are never used). For
each fold the block is adjusted without the fold's points, all their rays left out; each held-out point is then
intersected from its own rays with the fold's orientations and camera, and its rays' residuals are the prediction
errors. Every image keeps nine tenths of its points, so its orientation is determined by points the held-out ones
never touched, and the held-out rays test the camera model wherever the image has points. A held-out image
resected from its own rays would absorb six degrees of freedom of the field it tests (the shifts, the scale and
the rotations of a camera-fixed field are those of a resection), and a held-out GNSS/IMU trajectory observation
tests the trajectory model rather than the camera's.

The fold adjustments are the linearised adjustment downdated by the fold's points (:mod:`selfcal.adjust.folds`):
one Gauss-Newton step from the state, exact for the linear model (measured against a re-adjustment without the
fold: the held-out cost agrees to 1e-6). Each held-out point's own three unknowns take three of its 2 m ray
coordinates, whatever the model, so the error is normalised by the rays' degrees of freedom, sum of (2 m - 3):

    CV = sigma_px * sqrt( sum_f E_f / sum_f dof_f ),   E_f the whitened squared sum of fold f's rays,

the root mean square prediction error of an image coordinate in pixels (sigma_px the a-priori sigma the rows are
whitened by). Its standard error is that of the mean over the folds of E_f / dof_f, carried to the root.

The one-standard-error rule (:func:`simplest_within_one_se`) compares candidates on the same held-out rays: the
fold-to-fold scatter of one candidate's error is mostly the noise of those rays, common to all candidates, so the
rule measures a candidate's distance from the best against the standard error over the folds of their difference
(the paired standard error); ``paired=False`` takes the best one's own standard error instead (Breiman's rule).
A gain must also matter: a candidate within the mean squared error that a camera field of ``min_effect_px`` over
the whole frame adds (min_effect^2 / 2 per coordinate; :data:`selfcal.stats.effect.MIN_EFFECT_PX`, the bound of
screening's practical significance) counts as near the best whatever the standard error. With 80,000 observations
the paired standard error resolves 1e-5 px: on simulated distortion-free blocks Brown's seven terms fit a
0.005 px field (Omega 17-24 lower than without, 2-4 sigma of chi2(7) in four seeds of four) and predicted the
held-out rays 2e-5 px better, 1.7 paired standard errors, while their correlation with c and the heights made the
check points 11-19 % worse.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..adjust.linalg import rank_one_update
from .effect import MIN_EFFECT_PX

__all__ = ["FOLDS", "PredictionError", "PredictionPath", "prediction_error", "paired_se_px", "simplest_within_one_se",
           "converged_fold_systems"]

#: folds of the cross-validation (the fold systems' cost does not grow with them: each point is held out once)
FOLDS = 10


@dataclass(frozen=True)
class PredictionError:
    """The cross-validated prediction error of an adjustment (module docstring)."""

    rmse_px: float              # pooled RMS prediction error of a held-out image coordinate
    se_px: float                # its standard error over the folds
    fit_px: float               # the same rays' RMS in the adjustment that saw them (same normalisation)
    n_folds: int
    n_rays: int                 # held-out image observations in all
    fold_mse_px2: tuple[float, ...] = field(default=())     # each fold's mean squared error (px^2, per dof)

    def as_dict(self) -> dict:
        return {"cv_rmse_px": self.rmse_px, "cv_se_px": self.se_px, "fit_rmse_px": self.fit_px,
                "n_folds": self.n_folds, "n_rays": self.n_rays}


def prediction_error(systems, sigma_px: float, hold: np.ndarray | None = None,
                     move: np.ndarray | None = None) -> PredictionError:
    """The prediction error of the adjustment whose fold systems are ``systems``
    (:class:`selfcal.adjust.folds.FoldSystems`), with the θ entries ``hold`` moved by ``move`` and held (a
    screened parameter set: the dropped parameters at their held values) and the rest adjusted."""
    k = systems.n_folds
    used = np.flatnonzero(systems.dof > 0)
    if used.size < 2:
        raise ValueError("cross-validation needs tie points with at least two rays in two folds")
    full = systems.solve(None, hold, move)
    held_out = np.array([systems.held_out_cost(f, systems.solve(f, hold, move)) for f in used])
    fitted = np.array([systems.held_out_cost(f, full) for f in used])
    return _error(held_out, fitted, systems.dof[used], systems.n_rays[used], k, sigma_px)


def converged_fold_systems(result, n_folds: int = FOLDS):
    """The fold systems (:func:`selfcal.adjust.folds.fold_systems`) of a converged adjustment, its reduced matrix
    reused where it kept one. Raises ValueError for a system too large or without points to hold out."""
    from ..adjust.folds import fold_systems, point_folds
    problem = result.problem
    folds = point_folds(result.block.points.point_id, result.block.points.role, n_folds)
    S = getattr(result, "reduced_matrix", None)
    return fold_systems(problem, result.state, folds, n_folds, getattr(result, "datum_null", None) is not None,
                        None if S is None or not result.converged else (S, result.variance_factor * result.redundancy))


def _error(held_out: np.ndarray, fitted: np.ndarray, dof: np.ndarray, n_rays: np.ndarray, k: int,
           sigma_px: float) -> PredictionError:
    """The prediction error from the folds' held-out costs (whitened), their rays' costs in the adjustment that
    saw them, degrees of freedom and rays."""
    mse = held_out.sum() / dof.sum()
    per_fold = held_out / dof
    se_mse = float(np.std(per_fold, ddof=1) / np.sqrt(len(dof)))
    rmse = float(np.sqrt(max(mse, 0.0)))
    return PredictionError(sigma_px * rmse, sigma_px * se_mse / (2.0 * max(rmse, 1e-300)),
                           sigma_px * float(np.sqrt(max(fitted.sum() / dof.sum(), 0.0))), k,
                           int(n_rays.sum()), tuple(float(sigma_px ** 2 * v) for v in per_fold))


def paired_se_px(error: PredictionError, best: PredictionError) -> float:
    """The standard error over the folds of the difference between ``error`` and ``best`` (the same folds), px."""
    if error is best or len(error.fold_mse_px2) != len(best.fold_mse_px2) or len(best.fold_mse_px2) < 2:
        return 0.0 if error is best else float("nan")
    d = np.subtract(error.fold_mse_px2, best.fold_mse_px2)
    return float(np.std(d, ddof=1) / np.sqrt(len(d)) / (2.0 * best.rmse_px))


def simplest_within_one_se(errors: list[PredictionError | None], sizes: list[int], paired: bool = True,
                           min_effect_px: float = MIN_EFFECT_PX) -> int | None:
    """The one-standard-error rule: the index of the candidate with the fewest parameters (``sizes``; ties: the
    smaller error) among those whose prediction error exceeds the best one's by no more than one standard error
    (``paired``: of their difference over the folds; else the best one's own) or by no more than a camera field of
    ``min_effect_px`` would add (module docstring); None when no candidate has one."""
    scored = [i for i, e in enumerate(errors) if e is not None and np.isfinite(e.rmse_px)]
    if not scored:
        return None
    best_error = errors[min(scored, key=lambda i: errors[i].rmse_px)]        # type: ignore[union-attr]
    assert best_error is not None

    practical = min_effect_px ** 2 / (4.0 * max(best_error.rmse_px, 1e-300))    # (a^2 / 2 in the mean square)

    def within(e: PredictionError) -> bool:
        se = paired_se_px(e, best_error) if paired else best_error.se_px
        return bool(e.rmse_px <= best_error.rmse_px + max(se, practical))
    near = [i for i in scored if within(errors[i])]                          # type: ignore[arg-type]
    return min(near, key=lambda i: (sizes[i], errors[i].rmse_px))           # type: ignore[union-attr]


class PredictionPath:
    """The prediction error of a linearised adjustment as its parameters are held one after another.

    Each system (the whole adjustment and every fold's) keeps its inverse and solution; holding θ_i at the state's
    value plus ``move`` is the sweep δ <- δ - Q[:, i] (δ_i - move) / Q_ii, Q <- Q - Q[:, i] Q[i, :] / Q_ii (the
    constrained least-squares solution), n^2 per system, so a screening path of a few hundred drops costs less than
    one adjustment. A free network's systems are inverted in the minimum-norm sense (its datum directions do not
    involve the camera or trajectory parameters that screening holds).
    """

    def __init__(self, systems, sigma_px: float):
        self.systems, self.sigma_px = systems, sigma_px
        self.used = np.flatnonzero(systems.dof > 0)
        if self.used.size < 2:
            raise ValueError("cross-validation needs tie points with at least two rays in two folds")
        self.Q = [_inverse(systems.S if f is None else systems.S - systems.C[f], systems.free_network)
                  for f in [None, *self.used]]
        self.delta = [Q @ (systems.g if f is None else systems.g - systems.b[f])
                      for Q, f in zip(self.Q, [None, *self.used])]
        self.held: list[int] = []

    def copy(self) -> "PredictionPath":
        other = object.__new__(PredictionPath)
        other.systems, other.sigma_px, other.used = self.systems, self.sigma_px, self.used
        other.Q = [Q.copy() for Q in self.Q]
        other.delta = [d.copy() for d in self.delta]
        other.held = list(self.held)
        return other

    def hold(self, index: int, move: float) -> None:
        for Q, delta in zip(self.Q, self.delta):
            q = Q[:, index].copy()
            qii = q[index]
            if qii <= 0:
                continue
            delta -= q * ((delta[index] - move) / qii)
            rank_one_update(Q, -1.0 / qii, q, q)
            delta[index] = move
        self.held.append(index)

    def error(self) -> PredictionError:
        s = self.systems
        held_out = np.array([s.held_out_cost(f, d) for f, d in zip(self.used, self.delta[1:])])
        fitted = np.array([s.held_out_cost(f, self.delta[0]) for f in self.used])
        return _error(held_out, fitted, s.dof[self.used], s.n_rays[self.used], s.n_folds, self.sigma_px)


def _inverse(S: np.ndarray, free_network: bool) -> np.ndarray:
    d = np.sqrt(np.clip(np.diag(S), 1e-300, None))
    Ss = S / d[:, None] / d[None, :]
    if not free_network:
        try:
            L_inv = np.linalg.inv(np.linalg.cholesky(Ss))
            return L_inv.T @ L_inv / d[:, None] / d[None, :]
        except np.linalg.LinAlgError:
            pass
    w, V = np.linalg.eigh(Ss)
    keep = w > 1e-10 * w.max()
    return (V[:, keep] / w[keep]) @ V[:, keep].T / d[:, None] / d[None, :]
