"""Choosing the AP model by what it predicts (``--ap auto``; beyond seed 000, which leaves the choice open).

1. **Blunders first, with a reference.** The richest candidate of at most :data:`REFERENCE_LIMIT` coefficients
   is adjusted with the robust cleaning (when asked for) and data snooping; the observations it rejects are left
   out for every candidate. A model that cannot follow the distortion would reject the distortion itself, and each
   candidate would be scored on data of its own choosing. Its estimate is where every candidate is linearised.
2. **A pre-filter by BIC in image space** (more than :data:`SHORTLIST` candidates, frame cameras): the field the
   reference leaves (its residuals plus its own correction) is fitted by each candidate's basis and the six fields
   the orientation takes up (:mod:`selfcal.stats.field_fit`), BIC = n ln(Omega/n) + k ln n; the
   :data:`SHORTLIST` best go on. Cheap (a small solve per candidate, the basis built without choosing its
   independent functions), so families x grids x levels can be searched: a level V_{j+1} on a grid G is V_j on
   2G, so the grid ladder 3x2, 6x4, 12x8 spans two levels above 3x2.
3. **Cross-validation** (:mod:`selfcal.stats.prediction`): each remaining candidate is linearised at the
   reference's estimate (one Gauss-Newton step from it: the candidate's adjustment for a linear model), and ten
   folds of tie points are held out in turn; each fold's rays are predicted by the adjustment without them, the
   points intersected again from their own rays. The prediction error (px) and its standard error over the folds
   go to model_choice.csv, with the linearised adjustment's Omega and BIC.
4. **The one-standard-error rule**: the simplest candidate (fewest camera parameters, the interior orientation
   included) whose prediction error exceeds the best one's by no more than the standard error of their difference
   over the folds (``paired_se=False``: the best one's own standard error), or by no more than a camera field of
   ``min_effect_px`` over the frame would (:func:`selfcal.stats.prediction.simplest_within_one_se`).

The check-point RMSD of every cross-validated candidate (its linearised adjustment) is reported next to its score
and never used to choose (check points stay independent, and are never held out).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from types import SimpleNamespace
from typing import Any, Callable

import numpy as np

from ..adjust import AdjustOptions, RobustOptions, adjust, camera_models, problem_at
from ..adjust.folds import FOLD_LIMIT, fold_systems, point_folds
from ..ap import create_ap, takes_grid
from ..block import Block
from ..errors import AdjustmentError
from ..stats.checks import intersected
from ..stats.effect import MIN_EFFECT_PX
from ..stats.field_fit import camera_fields, field_fit
from ..stats.prediction import FOLDS, PredictionError, prediction_error, simplest_within_one_se
from ..stats.snooping import SnoopingOptions
from .tested import adjust_with_tests

__all__ = ["CandidateScore", "ModelChoice", "parse_candidate", "choose_ap_model", "REFERENCE_LIMIT", "SHORTLIST",
           "GRID_LADDER"]

#: the reference (blunder step, linearisation point) is the richest candidate with at most this many coefficients
#: per camera: rich enough to follow a lens field of a few hundred pixels' scale (the wavelets on 9 x 6: 228-286),
#: so that data snooping does not take the field for blunders, without the cost of the finest grids (up to 570)
REFERENCE_LIMIT = 300
#: candidates that the image-space BIC passes on to the cross-validation
SHORTLIST = 3
#: the wavelet grids of ``--ap auto`` (3:2 frames, square cells): V_{j+1} on a grid is V_j on the doubled grid, so
#: 3x2, 6x4 and 12x8 are three levels of one grid
GRID_LADDER = ((3, 2), (6, 4), (9, 6), (12, 8), (15, 10))


@dataclass(frozen=True)
class CandidateScore:
    model: str
    grid: tuple[int, int]
    n_ap: int                       # camera parameters (APs and interior orientation); 0 where not cross-validated
    n_observations: int
    n_unknowns: int
    omega: float                    # v^T P v of the linearised adjustment (a-priori weights)
    sigma0_px: float
    bic: float | None               # of the linearised adjustment; None when not cross-validated or failed
    rmsd_chk_xy_m: float | None     # for the log only, never for the choice
    rmsd_chk_z_m: float | None
    error: str | None = None
    field_bic: float | None = None  # the image-space pre-filter's BIC (None: no pre-filter ran)
    field_k: int | None = None      # the coefficients it counted
    prediction: PredictionError | None = None       # the cross-validated prediction error

    @property
    def label(self) -> str:
        return f"{self.model}@{self.grid[0]}x{self.grid[1]}" if takes_grid(self.model) else self.model


@dataclass(frozen=True)
class ModelChoice:
    model: str
    grid: tuple[int, int]
    candidates: list[CandidateScore]
    n_blunders: int                 # observations left out for every candidate (step 1)
    #: False when no candidate could be cross-validated: the first one is chosen, so that the tested adjustment
    #: says why (and a failed run writes its files where failed runs go)
    by_prediction: bool = True
    reference: str = ""             # the label of the reference (step 1)
    #: how it was chosen: "prediction", "bic" (a block too large for the fold systems) or "" (the first or the
    #: reference, nothing could be scored)
    rule: str = "prediction"
    #: the reference's tested adjustment (step 1) where the chosen model is the reference's: the tested adjustment of
    #: the chosen model with the same tests, which the caller need not run again (None otherwise)
    tested: Any = field(default=None, repr=False, compare=False)


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


def _with(options: AdjustOptions, model: str, grid: tuple[int, int]) -> AdjustOptions:
    return replace(options, ap=replace(options.ap, model=model, grid=grid))


def _label(model: str, grid: tuple[int, int]) -> str:
    return f"{model}@{grid[0]}x{grid[1]}" if takes_grid(model) else model


def _span_models(block: Block, options: AdjustOptions, candidates) -> tuple[list, dict | None]:
    """Per candidate: camera id -> a model of its span (:func:`selfcal.ap.create_ap` ``span_only``), or the error
    that building it raised; and the frame cameras' problem (None: a camera not on a frame)."""
    problem, _ = problem_at(block, _with(options, "none", options.ap.grid))
    cams = options.ap.cameras
    frames = {}
    for k, cam in enumerate(problem.cameras):
        frame = getattr(cam.ap, "frame", None)
        if frame is None:
            return [], None
        if cams is None or cam.camera_id in cams:
            observed = problem.obs_value[problem.image_camera[problem.obs_image] == k]
            frames[cam.camera_id] = (frame, observed)
    models: list = []
    for model, grid in candidates:
        try:
            models.append({cid: create_ap(model, frame, observed, grid=grid, span_only=True)
                           for cid, (frame, observed) in frames.items()})
        except ValueError as exc:
            models.append(exc)
    return models, frames


def choose_ap_model(block: Block, candidates: list[tuple[str, tuple[int, int]]],
                    options: AdjustOptions = AdjustOptions(), snooping: SnoopingOptions | None = SnoopingOptions(),
                    progress: Callable[[CandidateScore], None] | None = None,
                    robust: RobustOptions | None = None, shortlist: int = SHORTLIST,
                    n_folds: int = FOLDS, paired_se: bool = True, min_effect_px: float = MIN_EFFECT_PX) -> ModelChoice:
    """Choose the AP model of ``block`` (pruned) among ``candidates`` (model, grid) by the cross-validated
    prediction error and the one-standard-error rule (module docstring).

    ``options`` gives everything but the AP model and grid (trajectory drift orders, solver); ``robust``: the robust
    cleaning of the blunder step (matcher data: least squares alone would not reach the blunders). Raises
    AdjustmentError when no candidate can be adjusted.
    """
    if not candidates:
        raise ValueError("no candidate AP models")
    spans, frames = _span_models(block, options, candidates) if len(candidates) > shortlist else ([], None)
    if frames is not None and spans:
        sizes = [-1 if isinstance(m, Exception) else max((x.n_params for x in m.values()), default=0) for m in spans]
        built: list = [None] * len(candidates)
    else:
        built, sizes = [], []
        for model, grid in candidates:
            try:
                models, _ = camera_models(block, _with(options, model, grid))
            except (AdjustmentError, ValueError) as exc:
                built.append(exc)
                sizes.append(-1)
            else:
                built.append(models)
                sizes.append(max((m.n_params for m in models.values()), default=0))
    reference, n_blunders, failures, ran = _reference(block, candidates, built, sizes, options, snooping, robust)
    errors = dict(failures)
    if reference is None:
        failed = [CandidateScore(m, g, 0, 0, 0, np.nan, np.nan, None, None, None, errors.get(i, "not adjusted"))
                  for i, (m, g) in enumerate(candidates)]
        if ran:
            first = min(ran)
            return ModelChoice(candidates[first][0], candidates[first][1], failed, 0, by_prediction=False, rule="")
        raise AdjustmentError("no candidate AP model could be adjusted:\n  "
                              + "\n  ".join(f"{s.label}: {s.error}" for s in failed))
    index, result, reference_tested = reference
    data = result.block
    folds = point_folds(data.points.point_id, data.points.role, n_folds)
    free_network = data.datum == "free" or options.solver.free_network
    field_scores: list[tuple[float | None, int | None]] = [(None, None)] * len(candidates)
    chosen_for_cv = list(range(len(candidates)))
    done: dict[int, CandidateScore] = {}
    if spans and frames is not None:
        # the pre-filter: the field that the adjustment without APs (linearised at the reference) leaves, fitted by
        # every candidate in image space. Not the reference's own field: its orientations moved with its APs, and
        # the field it leaves with its correction added back favours the reference's own span (a distortion-free
        # block: brown's span 430 below none in Omega with brown as the reference)
        plain, stepped = _cross_validated(data, result, "none", options.ap.grid, options, None, folds, n_folds,
                                          free_network, False)
        fields = camera_fields(stepped) if stepped is not None else None
        if fields is not None:
            for i, models in enumerate(spans):
                if isinstance(models, Exception):
                    errors[i] = str(models)
                    continue
                fit = field_fit(fields, models, data.image_sigma_px)
                field_scores[i] = (fit.bic, fit.k)
            ranked = sorted((i for i in range(len(candidates)) if field_scores[i][0] is not None
                             and candidates[i][0] != "none"),
                            key=lambda i: field_scores[i][0])                  # type: ignore[arg-type,return-value]
            # no APs, where it is a candidate, is always cross-validated: the simplest model of the rule
            done = {i: plain for i, (m, _) in enumerate(candidates) if m == "none"}
            chosen_for_cv = ranked[:shortlist] + list(done)
    scores: list[CandidateScore] = []
    for i, (model, grid) in enumerate(candidates):
        bic_f, k_f = field_scores[i]
        if i not in chosen_for_cv or i in errors:
            score = CandidateScore(model, grid, 0, 0, 0, np.nan, np.nan, None, None, None, errors.get(i),
                                   bic_f, k_f)
        else:
            score = done[i] if i in done else _cross_validated(data, result, model, grid, options, built[i], folds,
                                                               n_folds, free_network, i == index)[0]
            score = replace(score, field_bic=bic_f, field_k=k_f)
        scores.append(score)
        if progress is not None:
            progress(score)
    pick = simplest_within_one_se([s.prediction for s in scores], [s.n_ap for s in scores], paired_se, min_effect_px)
    if pick is None:
        # no candidate could be cross-validated: a block too large for the fold systems, whose candidates were
        # adjusted and scored by BIC (the smallest wins, as before issue 44), or one without points to hold out
        # (the reference, the model its tested adjustment ran)
        by_bic = [i for i, s in enumerate(scores) if s.bic is not None]
        if by_bic:
            best = min(by_bic, key=lambda i: scores[i].bic)                  # type: ignore[arg-type,return-value]
            return ModelChoice(scores[best].model, scores[best].grid, scores, n_blunders, False,
                               _label(*candidates[index]), rule="bic")
        return ModelChoice(candidates[index][0], candidates[index][1], scores, n_blunders, False,
                           _label(*candidates[index]), rule="")
    return ModelChoice(scores[pick].model, scores[pick].grid, scores, n_blunders, True, _label(*candidates[index]),
                       tested=reference_tested if pick == index else None)


def _reference(block: Block, candidates, built, sizes, options, snooping, robust):
    """((index, the adjustment, its tested adjustment or None) of the reference, observations it rejected, {index:
    why a candidate failed}, the candidates adjusted without converging): the richest candidate of at most
    REFERENCE_LIMIT coefficients (else the poorest) adjusted with the tests (its result's block is the block without
    what they rejected), or the next if it fails; (None, 0, failures, ran) when none converges."""
    order = sorted((i for i in range(len(candidates)) if sizes[i] >= 0),
                   key=lambda i: (sizes[i] > REFERENCE_LIMIT, -sizes[i] if sizes[i] <= REFERENCE_LIMIT else sizes[i]))
    failures = {i: str(built[i]) for i in range(len(candidates)) if isinstance(built[i], Exception)}
    ran: list[int] = []                 # adjusted, but not converged
    test = robust is not None or snooping is not None and snooping.critical > 0
    for i in order:
        model, grid = candidates[i]
        models = built[i] if isinstance(built[i], dict) else None
        tested = None
        try:
            if test:
                tested = adjust_with_tests(block, _with(options, model, grid), snooping, ap_models=models,
                                           robust=robust)
                result, n_blunders = tested.result, len(tested.rejected_rows)
                if tested.failure:
                    raise AdjustmentError(tested.failure)
            else:
                result, n_blunders = adjust(block, _with(options, model, grid), ap_models=models), 0
        except (AdjustmentError, ValueError) as exc:
            failures[i] = str(exc)
            continue
        if not result.converged:
            failures[i] = result.reason
            ran.append(i)
            continue
        return (i, result, tested), n_blunders, failures, ran
    return None, 0, failures, ran


def _cross_validated(data: Block, reference, model: str, grid, options: AdjustOptions, models, folds, n_folds: int,
                     free_network: bool, is_reference: bool) -> tuple[CandidateScore, SimpleNamespace | None]:
    """The candidate linearised at the reference's estimate (the reference: its own problem, at its estimate), its
    fold systems and prediction error; and its linearised adjustment (problem, block, state) or None."""
    try:
        if is_reference:
            problem, state = reference.problem, reference.state
        else:
            problem, state = problem_at(data, _with(options, model, grid), start=reference,
                                        ap_models=models if isinstance(models, dict) else None)
        if problem.n_theta > FOLD_LIMIT:
            return _adjusted(data, reference, model, grid, options, models, is_reference), None
        systems = fold_systems(problem, state, folds, n_folds, free_network)
        prediction = prediction_error(systems, data.image_sigma_px)
    except (AdjustmentError, ValueError, np.linalg.LinAlgError) as exc:
        return CandidateScore(model, grid, 0, 0, 0, np.nan, np.nan, None, None, None, str(exc)), None
    n, k = problem.n_observations(), problem.n_unknowns()
    omega = systems.omega
    stepped = SimpleNamespace(block=data, state=systems.stepped, problem=problem)
    checks = intersected(stepped)
    return CandidateScore(model, grid, problem.n_d, n, k, float(omega),
                          float(data.image_sigma_px * np.sqrt(max(omega, 0.0) / (n - k))),
                          float(n * np.log(omega / n) + k * np.log(n)), checks.rmsd_xy_m(), checks.rmsd_z_m(),
                          None, prediction=prediction), stepped


def _adjusted(data: Block, reference, model: str, grid, options: AdjustOptions, models,
              is_reference: bool) -> CandidateScore:
    """A candidate of a block too large for the fold systems (more than FOLD_LIMIT unknowns): adjusted from the
    reference's estimate, scored by its BIC alone (the choice before issue 44), with a note why."""
    result = reference if is_reference else adjust(data, _with(options, model, grid), start=reference,
                                                    ap_models=models if isinstance(models, dict) else None)
    n, k = result.n_observations, result.n_unknowns
    omega = result.variance_factor * (n - k)
    checks = intersected(result)
    return CandidateScore(model, grid, result.problem.n_d, n, k, float(omega), result.sigma0_px,
                          float(n * np.log(omega / n) + k * np.log(n)) if result.converged else None,
                          checks.rmsd_xy_m(), checks.rmsd_z_m(),
                          None if result.converged else result.reason)
