"""The tested adjustment: data snooping and screening, repeated until stable, for every sensor.

Each round tests the current adjustment: screening of the APs, the sensors' calibration
parameters and the trajectory terms (significance and correlation, :mod:`selfcal.stats.screening`)
and Baarda's data snooping (:mod:`selfcal.stats.snooping`). What fails is removed (parameters
held at their start values, observations rejected) and the block is re-adjusted from the
previous estimate moved by the downdated Gauss-Newton step (:mod:`selfcal.adjust.update`: the
previous normal equations without the rejected rows, the held parameters at their held values),
until a round removes nothing. A round's adjustment stops at :data:`ROUND_TOLERANCE` of a sigma, as it
only chooses the next rejections; the adjustment that passes the tests is taken on to the caller's
tolerance and tested again (BAL problem-49: 63 -> 40 iterations, the same rejections). Each round starts
from the block the previous adjustment kept: what a free network's re-adjustment left out (points its
rays no longer determine) stays out. The AP basis is built once, from all observations, and kept.

Data snooping stops with a failure rather than reject more than :data:`MAX_REJECTED_SHARE` of
the image observations: so many outliers are a model that does not fit (an uncalibrated focal
length, too few parameters), not blunders; and rather than leave the block undetermined: a round whose
rejections make the re-adjustment singular (a model without APs for a strong lens rejects the rays between
strips, at the frame's edges) is taken back, and the result is the round before's.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Callable

import numpy as np

from ..adjust import AdjustmentResult, AdjustOptions, RobustOptions, adjust
from ..block import Block, prune
from ..errors import AdjustmentError
from ..stats.cleaning import Cleaning, clean, readmissible
from ..stats.reliability import ObservationTests, observation_tests
from ..stats.screening import (PredictionGuard, ScreeningDecision, ScreeningOptions, ScreeningRound,
                               kept_by_interior_guard, screen_once, screening_masks)
from ..stats.loo import LeaveOneOut
from ..stats.snooping import (SnoopingOptions, SnoopingRound, image_w, left_without_rays, reject_candidates, terrain_w,
                              with_terrain)
from ..stats.variance import (TRAJECTORY_GROUPS, VarianceComponent, VarianceOptions, estimate_variance_components,
                              reweighted)
from .terrain import name_terrain_points, readmissible_terrain, terrain_notes

if TYPE_CHECKING:
    from .half_block import HalfBlock

__all__ = ["TestedAdjustment", "adjust_with_tests", "MAX_REJECTED_SHARE", "prune_for"]

#: data snooping stops with a failure rather than reject more than this share of the image observations
MAX_REJECTED_SHARE = 0.1
#: a round's adjustment, which only chooses the next round's rejections, stops once no estimate moves by this
#: share of its sigma (the caller's function tolerance is 0.01 by default); the last is converged as asked
ROUND_TOLERANCE = 0.1


def prune_for(block: Block) -> Block:
    """:func:`selfcal.block.prune` with the fewest points per image that the block's sensors need."""
    from ..sensors import sensor_of
    need = min((sensor_of(c).min_points_per_image for c in block.cameras.values()), default=6)
    return prune(block, min_points_per_image=need)


def _meets(result: AdjustmentResult, options: AdjustOptions) -> bool:
    """Whether the last step of ``result`` (converged with a rough tolerance) also meets ``options``' tests."""
    last = result.history[-1] if result.history else None
    return last is None or (last.accepted and (last.moved_sigma < options.solver.function_tolerance
                                               or last.max_step_sigma < options.solver.step_tolerance))


def _converge(result: AdjustmentResult, options: AdjustOptions, critical: float, progress, free, models):
    """``result``'s block adjusted from its estimate to ``options``' tolerance, and its tests."""
    result = adjust(result.block, options, progress=progress, start=result, free=free, ap_models=models)
    return result, observation_tests(result, critical)


@dataclass
class TestedAdjustment:
    result: AdjustmentResult
    tests: ObservationTests
    rejected_rows: np.ndarray                       # rows of the block as read
    rejected_w: np.ndarray                          # |w| of each rejected observation when it was rejected
    rejected_mdb_px: np.ndarray                     # (n, 2) its minimal detectable blunders (x, y) then
    ap_free: dict[str, np.ndarray]
    n_ap_initial: int
    rounds: list[SnoopingRound] = field(default_factory=list)
    screening_log: list[tuple[int, ScreeningDecision]] = field(default_factory=list)
    screening_rounds: list[tuple[int, ScreeningRound]] = field(default_factory=list)
    variance_components: list[VarianceComponent] | None = None
    variance_converged: bool | None = None
    failure: str = ""                                # why the tests stopped short, if they did
    cleaning: Cleaning | None = None                 # the robust cleaning before the tests, if there was one
    control_demoted: list[tuple[str, float]] = field(default_factory=list)   # (point id, |w|) checked instead
    loo: LeaveOneOut | None = None                   # the control's leave-one-out validation (workflows.loo)
    half_block: HalfBlock | None = None              # the half-block check of the calibration (workflows.half_block)
    #: what the screening cost or gained in prediction error (stats.screening.PredictionGuard.summary), or why it
    #: was not cross-validated (``{"note": ...}``); None without screening
    screening_prediction: dict | None = None
    #: the GNSS/IMU groups' weights against the images and control, estimated before the tests
    #: (``adjust_with_tests(trajectory_weights=...)``, opt-in); None: the declared sigmas were used (no trajectory,
    #: or not asked for)
    trajectory_weights: list[VarianceComponent] | None = None
    #: (point id, |w|) of each tie point's terrain height that data snooping rejected (issue 42), in order
    terrain_rejected: list[tuple[str, float]] = field(default_factory=list)
    #: the AP coefficients kept only because of the interior orientation's guard (the unguarded screening would
    #: drop them from the final adjustment: :func:`selfcal.stats.screening.kept_by_interior_guard`), with the reason
    guard_kept: list[ScreeningDecision] = field(default_factory=list)

    @property
    def robust_rows(self) -> np.ndarray:
        """The rows rejected by the robust cleaning (the others of ``rejected_rows`` by data snooping)."""
        return np.zeros(0, np.int64) if self.cleaning is None else self.cleaning.rejected_rows

    @property
    def n_ap_significant(self) -> int:
        cams = {c.camera_id for c in self.result.problem.cameras}
        return int(sum(int(v.sum()) for k, v in self.ap_free.items() if k in cams))


def adjust_with_tests(block: Block, options: AdjustOptions = AdjustOptions(),
                      snooping: SnoopingOptions | None = SnoopingOptions(),
                      screening: ScreeningOptions | None = None,
                      progress: Callable | None = None,
                      report: Callable[[SnoopingRound], None] | None = None,
                      variance: VarianceOptions | None = None, ap_models: dict | None = None,
                      robust: RobustOptions | None = None,
                      trajectory_weights: VarianceOptions | None = None) -> TestedAdjustment:
    """Adjust ``block`` (pruned, as read) with data snooping and AP screening.

    With ``robust``, the block is first adjusted with that robust loss and cleaned of what it finds to be gross
    errors (:mod:`selfcal.stats.cleaning`); the screening and the tests then see only the cleaned observations.

    ``snooping=None`` (or a critical value of 0) disables snooping;
    ``screening=None`` disables screening. With ``variance``, a variance
    component per observation group is estimated at the end, on the block that
    the tests left (:mod:`.variance`); the returned adjustment and tests are
    then those of the reweighted block. ``ap_models`` (camera id -> APModel)
    replaces the models built from ``options.ap``.
    """
    block = name_terrain_points(block, options)     # (the tie points on the DEM, from the start values)
    given = block
    snoop = snooping if snooping is not None and snooping.critical > 0 else None     # None: no snooping
    critical = snoop.critical if snoop is not None else 3.0
    max_rounds = max(snoop.max_rounds if snoop is not None else 0, screening.max_rounds if screening else 0)
    # a round's adjustment only chooses the next round's rejections: it stops once no estimate moves by
    # ROUND_TOLERANCE of its sigma; the adjustment the tests end with is converged to the caller's tolerance
    rough = options if not max_rounds else replace(options, solver=replace(
        options.solver, function_tolerance=max(options.solver.function_tolerance, ROUND_TOLERANCE)))
    cleaning = None
    readmitted: Block | None = None             # the cleaned block with the observations taken back
    if robust is not None:
        # the robust cleaning judges the rays among themselves: terrain heights (issue 42) are left out of its
        # adjustment, or the rays of an area where the DEM is wrong would be cut in their place; the tests judge them
        terrain = block.terrain_observations
        first = adjust(block if terrain is None else replace(block, terrain_observations=None), rough,
                       progress=progress, ap_models=ap_models, robust=robust)
        read, (block, cleaning) = first.block, clean(first, robust.reject, prune_for)
        if terrain is not None:
            read, block = (replace(b, terrain_observations=terrain) for b in (read, block))
        models = {cam.camera_id: cam.ap for cam in first.problem.cameras}
        try:
            result = adjust(block, rough, progress=progress, start=first, ap_models=models)
        except AdjustmentError as exc:
            # the gross errors were what held the block together (a model without APs for a strong lens puts its
            # largest residuals on the rays between strips): nothing is rejected, and the tests judge them
            cleaning.revoke(f"without them the block is undetermined ({_first_clause(str(exc))}): a model that "
                            f"misses a systematic error, not gross errors; see the diagnosis, try another AP model")
            block = cleaning.apply(read, prune_for)
            result = adjust(block, rough, progress=progress, start=first, ap_models=models)
        del first
        # the good rays pulled along by a point's blunder in the robust adjustment fit the cleaned one: taken back,
        # into the first round's re-adjustment (or one of their own, if the tests of this one find nothing)
        back = readmissible(cleaning, read, result)
        if back.size:
            cleaning.readmit(back)
            readmitted = cleaning.apply(read, prune_for)
    else:
        result = adjust(block, rough, progress=progress, ap_models=ap_models)
    weights = None
    if trajectory_weights is not None and result.problem.trajectory:
        # the GNSS/IMU sigmas against the images' and the control's as the block gives them, before any test:
        # issue 44 item 6 (DESIGN-NOTES "GNSS/IMU never hurts")
        result, _, weights, _ = estimate_variance_components(
            result.block, rough, replace(trajectory_weights, groups=TRAJECTORY_GROUPS), start=result,
            ap_models={cam.camera_id: cam.ap for cam in result.problem.cameras}, critical=critical, progress=progress)
        scale = {c.group: c.scale for c in weights if c.estimated}
        if readmitted is not None and scale:
            readmitted = reweighted(readmitted, scale)
    finished = rough is options or _meets(result, options)
    block = result.block                # a free network's adjustment leaves out what it cannot determine
    models = {cam.camera_id: cam.ap for cam in result.problem.cameras}
    free = screening_masks(result.problem)
    n_ap_initial = int(sum(cam.ap.n_params for cam in result.problem.cameras))
    screenable = sum(int(v.sum()) for v in free.values())
    tests = observation_tests(result, critical)
    rejected = np.zeros(0, np.int64) if cleaning is None else cleaning.rejected_rows
    rejected_w = np.full(len(rejected), np.nan)          # (no w-test: the robust cleaning's u is in cleaning)
    rejected_mdb = np.full((len(rejected), 2), np.nan)
    snooped = 0
    control_demoted: list[tuple[str, float]] = []
    terrain_rejected: list[tuple[str, float]] = []
    terrain_settled = False             # the rejected terrain heights were tested again (once)
    control_settled = False             # a demotion was not confirmed: the control group is not tested again
    control_notes: list[str] = []       # what the test of the control group did, for the final result's notes
    rounds: list[SnoopingRound] = []
    log: list[tuple[int, ScreeningDecision]] = []
    joint_tests: list[tuple[int, ScreeningRound]] = []
    failure = ""
    limit = max(1, int(MAX_REJECTED_SHARE * len(block.observations)))
    guard: PredictionGuard | None = None
    guard_note = ""
    while len(rounds) < max_rounds:
        k = len(rounds) + 1
        dropped = 0
        if screening is not None and screenable:
            before = joint_tests[-1][1] if joint_tests else None
            decisions: list[ScreeningDecision] = []
            joint: ScreeningRound | None = None
            if k == 1:
                # the sensors' own parameters held at nothing first (a rolling shutter's readout): a block that does
                # not show them is re-adjusted without them, and screened from there as with the simpler model
                new_free, decisions, _ = screen_once(result, screening, sensor_model=True)
            if not decisions:
                new_free, decisions, joint = screen_once(result, screening, before)
            if joint is not None and screening.cross_validate and guard is None and not guard_note:
                try:
                    guard = PredictionGuard(result)
                except ValueError as exc:            # (too large a system, no tie points in two folds)
                    guard_note = f"the screening was not cross-validated: {exc}"
            if joint is not None and guard is not None:
                accepted = guard.accepted(decisions)
                if accepted < len(decisions):       # screening stops where it started to lose
                    screenable = 0
                    new_free, decisions, joint = screen_once(result, screening, before, max_drops=accepted) \
                        if accepted else (free, [], None)
                guard.commit(decisions)
            if decisions:
                free = new_free
                dropped = len(decisions)
                log += [(k, d) for d in decisions]
                if joint is not None:                   # (the joint test of what the round dropped; the sensors'
                    joint_tests.append((k, joint))      # parameters alone: their own tests, not the APs' guard)
        picks = np.zeros(0, np.int64)
        terrain_picks = np.zeros(0, np.int64)
        largest = 0.0
        demoted = None
        if snoop is not None:
            w = image_w(tests, snoop.min_redundancy)
            largest = float(w.max()) if w.size else 0.0
            # the control group is tested too: a control point whose coordinates fail the test, worse than any
            # image observation, is checked instead (alone in its round: it pulls the image observations near it)
            demoted = None if control_settled else \
                control_candidate(result, tests, critical, snoop.min_redundancy, largest)
            picks = np.zeros(0, np.int64) if demoted is not None else \
                reject_candidates(result.block, w, critical, snoop.mode)
            terrain = result.problem.terrain
            if demoted is None and terrain is not None and len(terrain):
                # the terrain heights are tested with the rays (issue 42): a DEM that is wrong there is rejected
                w_terrain = terrain_w(tests, snoop.min_redundancy)
                picks, terrain_picks = with_terrain(result.block, w, picks, terrain.index, w_terrain, critical,
                                                    snoop.mode)
                terrain_rejected += [(str(result.block.points.point_id[terrain.index[k]]), float(w_terrain[k]))
                                     for k in terrain_picks]
            if picks.size and snooped + picks.size > limit:
                failure = _too_many(tests, largest, snooped, robust is not None)
                break
            snooped += picks.size
            rejected = np.concatenate([rejected, result.block.observations.row[picks]])
            rejected_w = np.concatenate([rejected_w, w[picks]])
            rejected_mdb = np.concatenate([rejected_mdb, tests.image_mdb_px[picks]])
        if readmitted is not None:
            block, readmitted = readmitted, None
            if dropped == 0 and picks.size == 0 and terrain_picks.size == 0 and demoted is None:
                result = adjust(block, rough, progress=progress, start=result, free=free, ap_models=models)
                finished = rough is options or _meets(result, options)
                block = result.block
                tests = observation_tests(result, critical)
                continue                # (not a round: the tests of the block with them)
        if demoted is not None:
            point, w_control = demoted
            name = str(result.block.points.point_id[point])
            worst = control_w(tests, snoop.min_redundancy if snoop is not None else 0.0)
            others_before = float(np.delete(worst, np.flatnonzero(result.problem.control_index == point)).max())
            control_demoted.append((name, w_control))
            control_notes.append(f"control point '{name}' fails the test of the control group (|w| {w_control:.1f}): "
                                f"its surveyed coordinates do not fit the block (a misidentified target? a typing "
                                f"error?); it is checked instead of used as control")
            where = np.flatnonzero(block.points.point_id == name)
            roles = np.asarray(block.points.role).copy()
            roles[where] = "chk"
            block = replace(block, points=replace(block.points, role=roles))
        if terrain_picks.size:
            spec = block.terrain_observations
            assert spec is not None
            block = replace(block, terrain_observations=replace(spec, rejected=spec.rejected + tuple(
                name for name, _ in terrain_rejected[len(terrain_rejected) - terrain_picks.size:])))
        taken_back: list[str] = []
        if dropped == 0 and picks.size == 0 and terrain_picks.size == 0 and demoted is None and terrain_rejected \
                and not terrain_settled:
            # the tests pass: the terrain heights rejected in a batch, tested against this adjustment without them,
            # are taken back where they fit it (once: DESIGN-NOTES "Terrain as observations")
            terrain_settled = True
            taken_back = readmissible_terrain(result, critical)
            if taken_back:
                spec = block.terrain_observations
                assert spec is not None
                block = replace(block, terrain_observations=replace(
                    spec, rejected=tuple(p for p in spec.rejected if p not in taken_back)))
                terrain_rejected = [(p, w) for p, w in terrain_rejected if p not in taken_back]
        if dropped == 0 and picks.size == 0 and terrain_picks.size == 0 and demoted is None and not taken_back:
            if finished:
                break
            # the rough adjustment passed the tests: converge it, and test again (reported, not a round of its own)
            if report is not None:
                report(SnoopingRound(k, 0, 0, largest, result.sigma0_px))
            result, tests = _converge(result, options, critical, progress, free, models)
            block, finished = result.block, True
            continue
        record = SnoopingRound(k, int(picks.size), dropped, largest, result.sigma0_px,
                               demoted[1] if demoted is not None else None)
        rounds.append(record)
        if report is not None:
            report(record)
        keep = ~np.isin(block.observations.row, rejected)
        sub = prune_for(replace(block, observations=block.observations.take(np.flatnonzero(keep))))
        try:
            result = adjust(sub, rough, progress=progress, start=result, free=free, ap_models=models)
        except AdjustmentError as exc:
            if not picks.size and not terrain_picks.size:
                raise
            if terrain_picks.size:
                del terrain_rejected[len(terrain_rejected) - terrain_picks.size:]
            # the round's rejections cut what held the block together (the rays between strips, where a model
            # that misses the lens puts its largest residuals): they are taken back and the tests stop there
            n = int(picks.size)
            if n:
                rejected, rejected_w, rejected_mdb = rejected[:-n], rejected_w[:-n], rejected_mdb[:-n]
            snooped -= n
            rounds.pop()
            failure = _disconnected(k, n, largest, str(exc))
            block, finished = result.block, False       # (converged below with the round's screening)
            break
        finished = rough is options or _meets(result, options)
        block = result.block            # what a free network's re-adjustment left out stays out
        tests = observation_tests(result, critical)
        if demoted is not None:
            assert snoop is not None
            holds, norm, others_now = demotion_holds(result, tests, name, others_before, snoop.min_redundancy)
            if not holds:               # the control as a whole disagrees with the block: the point stays control
                control_demoted.pop()
                control_settled = True
                roles = np.asarray(block.points.role).copy()
                roles[block.points.point_id == name] = "gcp"
                block = replace(block, points=replace(block.points, role=roles))
                result = adjust(block, rough, progress=progress, start=result, free=free, ap_models=models)
                block = result.block
                finished = rough is options or _meets(result, options)
                tests = observation_tests(result, critical)
                control_notes[-1] = (
                    f"control point '{name}' failed the test of the control group (|w| {demoted[1]:.1f}), but checked "
                    f"instead it {'fits its rays' if norm <= CONTROL_CRITICAL else 'leaves the others fitting worse'} "
                    f"({norm:.1f} sigma off; the other control points' largest |w| {others_before:.1f} -> "
                    f"{others_now:.1f}): the control disagrees with the block as a whole (a deformation the model "
                    f"does not capture?), not at one target; it stays control and no control point is demoted")
    if readmitted is not None:          # no round of tests (or a failure before the first re-adjustment)
        result = adjust(readmitted, rough, progress=progress, start=result, free=free, ap_models=models)
        finished = rough is options or _meets(result, options)
        tests = observation_tests(result, critical)
    if not finished:                    # stopped by a failure or the round limit
        try:
            result, tests = _converge(result, options, critical, progress, free, models)
        except AdjustmentError as exc:
            if not failure:
                raise
            # a block the failure left barely determined (its normal matrix singular to rounding at the finer
            # tolerance): the round's estimate, converged to ROUND_TOLERANCE, is the result
            failure += (f"; the last adjustment is converged to {ROUND_TOLERANCE:g} of a sigma only (further, "
                        f"{_first_clause(str(exc))})")
    terrain_note = terrain_notes(result.block, terrain_rejected)     # (with the sigma given, before any rescaling)
    components = converged = None
    if variance is not None:
        result, tests, components, converged = estimate_variance_components(
            result.block, options, variance, start=result, free=free, ap_models=models, critical=critical,
            progress=progress)
    if weights is not None and any(c.estimated for c in weights):
        result.notes.append("the GNSS/IMU sigmas were scaled by their variance components against the image and "
                            "control observations before the tests: " + ", ".join(
                                f"{c.group} x{c.scale:.3g}" for c in weights if c.estimated))
    result.notes[:0] = control_notes + left_without_rays(
        given, result.block, rejected, () if cleaning is None else cleaning.control_lost)
    result.notes += terrain_note
    if cleaning is not None:
        result.notes[:0] = cleaning.messages
    prediction = guard.summary() if guard is not None else {"note": guard_note} if guard_note else None
    if guard is not None and guard.stopped:
        result.notes.append(guard.stopped)
    guard_kept: list[ScreeningDecision] = []
    if screening is not None and screenable and not failure:
        guard_kept = kept_by_interior_guard(result, screening, joint_tests[-1][1] if joint_tests else None)
        if guard_kept:
            result.notes.append(
                f"{len(guard_kept)} AP coefficient(s) kept because dropping them would move the interior orientation "
                f"(c, x0, y0) by more than {screening.max_iop_move_sigma:g} of its sigma since the unscreened "
                f"adjustment (--max-iop-move; screening.json kept_by_interior_guard)")
    order = np.argsort(rejected)
    return TestedAdjustment(result, tests, rejected[order], rejected_w[order], rejected_mdb[order], free, n_ap_initial,
                            rounds, log, joint_tests, components, converged, failure, cleaning, control_demoted,
                            screening_prediction=prediction, trajectory_weights=weights,
                            terrain_rejected=terrain_rejected, guard_kept=guard_kept)


#: the control group is tested only while at least this many control points remain (a datum and redundancy)
MIN_CONTROL = 4
#: a control point is checked instead only when a coordinate's |w| is beyond this (and the critical value): a
#: false alarm of 6e-5 per coordinate, one block in 200 with 27 control points, where 3.0 took a good one in one
#: block of four (seed 000's Type 3, eight seeds); good control lost costs more than a small control error kept
CONTROL_CRITICAL = 4.0


def control_candidate(result: AdjustmentResult, tests: ObservationTests, critical: float, min_redundancy: float,
                      largest_image_w: float) -> tuple[int, float] | None:
    """The control point (its index among the block's points) whose coordinates fail Baarda's test worst, with
    its |w|, if that is above ``critical`` and :data:`CONTROL_CRITICAL` and above every image observation's; None
    otherwise, or when no more than :data:`MIN_CONTROL` control points are left."""
    index = result.problem.control_index
    if len(index) <= MIN_CONTROL or not tests.control_w.size:
        return None
    worst = control_w(tests, min_redundancy)
    k = int(np.argmax(worst))
    if worst[k] > max(critical, CONTROL_CRITICAL) and worst[k] > largest_image_w:
        return int(index[k]), float(worst[k])
    return None


def control_w(tests: ObservationTests, min_redundancy: float) -> np.ndarray:
    """The largest |w| of each control point's coordinates (those with a redundancy number of at least
    ``min_redundancy``; 0 where none has)."""
    w = np.abs(tests.control_w)
    w[tests.control_redundancy < min_redundancy] = 0.0
    return w.max(axis=1) if w.size else np.zeros(0)


def demotion_holds(result: AdjustmentResult, tests: ObservationTests, name: str, others_before: float,
                   min_redundancy: float) -> tuple[bool, float, float]:
    """Whether the re-adjustment ``result``, in which control point ``name`` is a check point, confirms that its
    surveyed coordinates do not fit: their discrepancy from the point's rays beyond :data:`CONTROL_CRITICAL` of its
    sigma (the Mahalanobis norm of the difference with the survey's and the estimate's covariance), and the other
    control points fitting no worse than before (their largest |w| not above ``others_before``). A wrong target
    pulls the block: without it the others fit better. A block that deforms against its control (a bowl, a
    calibration that the APs do not capture) does not fit at any one control point: leave one out and the
    others' |w| grow. Returns (holds, the norm, the others' largest |w| now)."""
    points = result.block.points
    where = np.flatnonzero(points.point_id == name)
    others = control_w(tests, min_redundancy)
    others_now = float(others.max()) if others.size else 0.0
    if not where.size:                  # (left out of the re-adjustment: no rays to compare with)
        return True, float("nan"), others_now
    k = int(where[0])
    d = result.state.points[k] - points.xyz_m[k]
    cov = result.point_covariance()[k] + np.diag(np.nan_to_num(points.sigma_m[k]) ** 2)
    norm = float(np.sqrt(d @ np.linalg.solve(cov, d)))
    return bool(norm > CONTROL_CRITICAL and others_now <= others_before), norm, others_now


def _first_clause(error: str) -> str:
    """An adjustment error's first line without the list of the undetermined unknowns that follows it."""
    return error.splitlines()[0].split("; undetermined")[0]


def _disconnected(k: int, n: int, largest: float, error: str) -> str:
    """Why data snooping stops where a round's rejections leave the block undetermined."""
    return (f"data snooping stopped at round {k}: rejecting its {n} observations (largest |w| {largest:.1f}) would "
            f"leave the block undetermined ({_first_clause(error)}); they are kept, and the results are those "
            f"of the round before. So many rejections that the block falls apart are a model that misses a "
            f"systematic error (the lens, the trajectory), not blunders: see the diagnosis, and try another AP "
            f"model")


def _too_many(tests: ObservationTests, largest: float, snooped: int, cleaned: bool) -> str:
    """Why data snooping stops: the bulk of the observations fitting (their w's robust sigma near 1: a block
    contaminated with gross errors), or not (a model that misses something)."""
    w = np.abs(tests.image_w[tests.image_redundancy >= 0.01])
    bulk = float(np.median(w) / 0.6745) if w.size else float("nan")
    share = f"{MAX_REJECTED_SHARE:.0%}"
    if bulk <= 1.5:
        advice = ("after the robust cleaning: lower --robust-reject" if cleaned else
                  "clean it first with a robust loss (--robust danish)")
        return (f"data snooping would reject more than {share} of the image observations (|w| up to {largest:.1f} "
                f"after {snooped} rejected), while the bulk of them fits the model (robust sigma of w {bulk:.2f}): "
                f"the block is contaminated with gross errors; {advice}")
    return (f"data snooping would reject more than {share} of the image observations (|w| up to {largest:.1f} after "
            f"{snooped} rejected), and the bulk of them does not fit either (robust sigma of w {bulk:.2f}): the model "
            f"does not fit the data (a focal length not calibrated? too few parameters?) or the a-priori sigma of "
            f"the image coordinates is too small")
