"""Choosing the AP model automatically (``--ap auto``; beyond seed 000, which leaves the choice open).

1. **Blunders first.** The candidate with the most parameters is adjusted with
   the robust cleaning (when asked for) and data snooping, and the observations
   it rejects are left out for every candidate. A model that cannot follow the distortion would reject the
   distortion itself (without APs, a quarter of the observations of a
   wide-angle block), and each candidate would be scored on data of its own
   choosing.
2. **The same data for all.** Every candidate (family, order, grid) is adjusted
   on those observations, without tests.
3. **Bayesian information criterion** with the variance factor unknown:

       BIC = n ln(Omega / n) + k ln(n),

   n scalar observations, Omega = v^T P v, k unknowns. The candidates share
   the orientations and points, so k differs by their camera parameters;
   ln(n) (about 12 for a UAV block) per parameter, where AIC's 2 would let
   any grid refinement that lowers Omega by 2 per coefficient win.

The smallest BIC wins. The check-point RMSD of every candidate is reported
next to its score and never used to choose (check points stay independent).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from ..adjust import AdjustOptions, RobustOptions, adjust, camera_models
from ..ap import takes_grid
from ..block import Block
from ..errors import AdjustmentError
from ..stats.snooping import SnoopingOptions
from ..stats.checks import intersected
from .tested import adjust_with_tests, prune_for

__all__ = ["CandidateScore", "ModelChoice", "parse_candidate", "choose_ap_model"]


@dataclass(frozen=True)
class CandidateScore:
    model: str
    grid: tuple[int, int]
    n_ap: int                       # camera parameters estimated (APs and interior orientation)
    n_observations: int
    n_unknowns: int
    omega: float                    # v^T P v (a-priori weights)
    sigma0_px: float
    bic: float | None               # None when the candidate failed
    rmsd_chk_xy_m: float | None     # for the log only, never for the choice
    rmsd_chk_z_m: float | None
    error: str | None = None

    @property
    def label(self) -> str:
        return f"{self.model}@{self.grid[0]}x{self.grid[1]}" if takes_grid(self.model) else self.model


@dataclass(frozen=True)
class ModelChoice:
    model: str
    grid: tuple[int, int]
    candidates: list[CandidateScore]
    n_blunders: int                 # observations left out for every candidate (step 1)
    #: False when no candidate converged: the first one adjusted is chosen, so that the tested adjustment says why
    #: it does not converge (and a failed run writes its files where failed runs go)
    by_bic: bool = True


def parse_candidate(text: str, grid: tuple[int, int]) -> tuple[str, tuple[int, int]]:
    """``MODEL`` or ``MODEL@GxXGy`` (a wavelet grid) -> (model, grid)."""
    model, _, grid_text = text.strip().partition("@")
    if grid_text:
        try:
            gx, gy = (int(v) for v in grid_text.lower().split("x"))
        except ValueError:
            raise ValueError(f"candidate '{text}': the grid must look like 9x6") from None
        grid = (gx, gy)
    return model, grid


def _rmsd_chk(result) -> tuple[float | None, float | None]:
    found = intersected(result)
    return found.rmsd_xy_m(), found.rmsd_z_m()


def choose_ap_model(block: Block, candidates: list[tuple[str, tuple[int, int]]],
                    options: AdjustOptions = AdjustOptions(), snooping: SnoopingOptions | None = SnoopingOptions(),
                    progress: Callable[[CandidateScore], None] | None = None,
                    robust: RobustOptions | None = None) -> ModelChoice:
    """Adjust ``block`` (pruned) with every candidate (model, grid) and pick the smallest BIC.

    ``options`` gives everything but the AP model and grid (trajectory drift
    orders, solver); ``robust``: the robust cleaning of the blunder step (matcher
    data: least squares alone would not reach the blunders). Raises
    AdjustmentError when no candidate can be adjusted.
    """
    if not candidates:
        raise ValueError("no candidate AP models")
    models: list[dict | AdjustmentError | ValueError] = []     # camera id -> APModel, or why it could not be built
    sizes: list[int] = []
    for model, grid in candidates:
        try:
            built, n_camera = camera_models(block, replace(options, ap=replace(options.ap, model=model, grid=grid)))
        except (AdjustmentError, ValueError) as exc:
            models.append(exc)
            sizes.append(-1)
        else:
            models.append(built)
            sizes.append(n_camera)
    data = block
    n_blunders = 0
    if (robust is not None or snooping is not None and snooping.critical > 0) and max(sizes) >= 0:
        richest = int(np.argmax(sizes))
        model, grid = candidates[richest]
        richest_models = models[richest]
        assert isinstance(richest_models, dict)             # (its size is not -1: they were built)
        tested = adjust_with_tests(block, replace(options, ap=replace(options.ap, model=model, grid=grid)), snooping,
                                   ap_models=richest_models, robust=robust)
        n_blunders = len(tested.rejected_rows)
        keep = np.flatnonzero(~np.isin(block.observations.row, tested.rejected_rows))
        data = prune_for(replace(block, observations=block.observations.take(keep)))
    scores = []
    for (model, grid), ap_models in zip(candidates, models):
        try:
            if isinstance(ap_models, Exception):
                raise ap_models
            result = adjust(data, replace(options, ap=replace(options.ap, model=model, grid=grid)), ap_models=ap_models)
        except (AdjustmentError, ValueError) as exc:
            score = CandidateScore(model, grid, 0, 0, 0, np.nan, np.nan, None, None, None, str(exc))
        else:
            n, k = result.n_observations, result.n_unknowns
            omega = result.variance_factor * (n - k)
            xy, z = _rmsd_chk(result)
            bic = n * np.log(omega / n) + k * np.log(n) if result.converged else None
            score = CandidateScore(model, grid, result.problem.n_d, n, k, float(omega), result.sigma0_px,
                                   None if bic is None else float(bic), xy, z,
                                   None if result.converged else result.reason)
        scores.append(score)
        if progress is not None:
            progress(score)
    valid = [(s, s.bic) for s in scores if s.bic is not None]
    ran = [s for s in scores if s.n_observations > 0]
    if not valid and ran:
        return ModelChoice(ran[0].model, ran[0].grid, scores, n_blunders, by_bic=False)
    if not valid:
        raise AdjustmentError("no candidate AP model could be adjusted:\n  "
                              + "\n  ".join(f"{s.label}: {s.error}" for s in scores))
    best = min(valid, key=lambda scored: scored[1])[0]
    return ModelChoice(best.model, best.grid, scores, n_blunders)
