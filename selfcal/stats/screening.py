"""Statistical screening of additional parameters: significance and correlation tests.

Screened are the AP coefficients of every camera and the strip-wise
shift/drift parameters of the trajectory observations. The tests are those of
seed 000 (Sect. 2.3), applied one parameter at a time (backward elimination):

* significance: t_i = |a_i| / sigma(a_i). The least significant parameter is
  dropped while its t is below ``significance`` (default 1.96: two-sided test
  at alpha = 5 %, the normal quantile, adequate at the redundancies of a
  photogrammetric block);
* correlation: when no parameter is insignificant any more, the largest |rho|
  between an AP and another unknown is looked at. Above ``max_correlation``
  (default 0.9) the AP is dropped when the other unknown is an interior or
  exterior orientation element (orientation is not screened), otherwise the
  less significant AP of the pair is. Then the significance test resumes.

Why one at a time: hundreds of WAPs on a grid are strongly correlated, so most
of them are individually insignificant while the field they form together is
not. Dropping every insignificant one at once removes the field (measured on
the Brown-only Type 3 block, sym4: 229 of 257 dropped, check-point RMSD(Z)
0.05 m -> 0.53 m). Each elimination is therefore followed by the exact update
of the linearised model under the constraint a_i = 0 (the sweep operator on
the cofactor matrix of the orientation and camera unknowns):

    theta <- theta - Q[:, i] theta_i / Q_ii,   Q <- Q - Q[:, i] Q[i, :] / Q_ii,
    Omega <- Omega + theta_i^2 / Q_ii,         redundancy <- redundancy + 1,

so the next test sees the estimates and precision the block would have without
the dropped parameters. A whole elimination costs O(k n^2) for k drops among n
unknowns (0.2 s for 257 WAPs on 28 images) instead of k re-adjustments.
The non-linear block is re-adjusted once per round with the kept set, and the
rounds repeat until one drops nothing (at most ``max_rounds``).

The guard: a parameter is only dropped while everything dropped so far (in
this round and the earlier ones) stays jointly insignificant. The quadratic
form of the dropped set, theta_S' Q_SS^-1 theta_S, is the sum of the Omega
increments; with F = that sum / (|S| sigma0^2) the set passes while F is below
the 1 - ``joint_alpha`` quantile of F(|S|, redundancy) (default alpha 5 %).
Without it, correlated pairs of strongly significant WAPs (t ~ 15 at
|rho| 0.99) lose a member to the correlation test, and dozens of individually
insignificant WAPs jointly carry part of the field. With it, the share of
WAPs removed on the simulated Type 3 block is close to Table 2 of seed 000
(16-30 % here, 19-37 % there).

With GNSS/IMU trajectory terms the guard is applied per group: the APs, each
sensor and each sensor's strip have their own joint test, and a trajectory term
has further guards (selfcal.stats.trajectory_screening): a stricter t (1.355,
before the screening and at the drop), no drop of a term mostly explained by
the interior orientation, and no drop that makes the residuals of its strip's
observations significant. Tested on 30 blocks simulated with trajectory errors
drawn independently of the model (benchmarks/study_trajectory.py).

Practical significance (selfcal.stats.effect): an AP coefficient, or a sensor's parameter held at nothing (a
rolling shutter's readout, held at 0 ms: :func:`_held_at_nothing`), also goes when holding it moves no sampled ray
or point over the observed area by ``min_effect_px``. A sensor's parameters held at nothing are tested first, on
their own (``screen_once(..., sensor_model=True)``, the tested workflow's first round): a block that does not show
a rolling shutter is re-adjusted as a global shutter, and its APs and trajectory terms are then screened as with
the frame model. Tested among the WAPs instead, the readout of a global-shutter block went (t 0.76) in the course of
the WAPs' elimination, and the WAPs dropped with it still free differed from the frame model's screening (check
points 2.9 % apart; benchmarks/study_rolling_shutter.py, serpentine, local + Brown field, seed 105); tested first,
1e-6 apart.

Seed 000 takes its thresholds from the BINGO manual (Kruck 2021), which is not
public; the defaults above are ours and can be set on the command line.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from .distributions import f_ppf

from ..adjust import parameter_table
from ..adjust.linalg import rank_one_update
from ..ap.wavelet import MIN_OBSERVATIONS
from .correlation import parameter_groups
from .effect import MIN_EFFECT_PX, effect_tracker
from .prediction import PredictionPath, paired_se_px
from .trajectory_screening import TRAJECTORY_SIGNIFICANCE, GroupGuards

#: a coefficient of a local basis is determined only by the observations in its support: at least this many, the
#: count that qualifies a wavelet translation (selfcal.ap.wavelet.MIN_OBSERVATIONS). With fewer its estimate rests on
#: a handful of rays (a 2-observation WAP of a real block: -4694 +- 1739 px), and a blunder among them is absorbed
#: rather than found: with n rays of weight phi^2 ~ 0.25 in the support a blunder moves the coefficient by about
#: 4 / n of itself, a tenth at 40, half at 8
MIN_SUPPORT = MIN_OBSERVATIONS
#: the screening's drops may move the interior orientation by at most this share of its sigma (the module's doc): a
#: move of 0.1 sigma adds at most 1 % to its mean square error where all of it is bias
IOP_MOVE_SIGMA = 0.1

__all__ = ["ScreeningOptions", "ScreeningDecision", "ScreeningRound", "screen_once", "kept_by_interior_guard",
           "screening_masks",
           "PredictionGuard", "MIN_SUPPORT", "GUARD_LIMIT", "IOP_MOVE_SIGMA"]


@dataclass(frozen=True)
class ScreeningOptions:
    significance: float = 1.96
    max_correlation: float = 0.9
    max_rounds: int = 20
    joint_alpha: float | None = 0.05
    #: t below which a GNSS/IMU shift/drift term may be dropped, before the screening and when dropped (None:
    #: ``significance``); the default 3 - z(0.95) = 1.355 drops a term only when its estimate shows it smaller
    #: than 3 sigma at 95 % (selfcal.stats.trajectory_screening)
    trajectory_significance: float | None = TRAJECTORY_SIGNIFICANCE
    #: w above which a strip's GNSS/IMU observation after a drop refuses it
    trajectory_w_critical: float = 3.0
    #: an AP coefficient (or a sensor's parameter held at nothing, a rolling shutter's readout: _held_at_nothing)
    #: stays only if holding it moves some adjusted image coordinate over the observed area by at least this much
    #: (px; 0: no test of practical significance; selfcal.stats.effect)
    min_effect_px: float = MIN_EFFECT_PX
    #: an AP coefficient of a local basis (a WAP) stays only if its support holds at least this many observations
    min_support: int = MIN_SUPPORT
    #: the screened set must predict held-out tie points no worse than the unscreened one: screening stops at the
    #: drop where the cross-validated prediction error would exceed the unscreened adjustment's (tested workflow)
    cross_validate: bool = True
    #: the drops may move the interior orientation (every camera's free core parameters: c, x0, y0) by at most this
    #: share of its a-posteriori sigma in the unscreened adjustment, since that adjustment (0: no guard; module doc)
    max_iop_move_sigma: float = IOP_MOVE_SIGMA

    def __post_init__(self):
        if self.significance < 0:
            raise ValueError(f"the significance threshold must not be negative, found {self.significance}")
        if not 0 < self.max_correlation <= 1:
            raise ValueError(f"the correlation threshold must be in (0, 1], found {self.max_correlation}")
        if self.min_effect_px < 0:
            raise ValueError(f"the smallest effect must not be negative, found {self.min_effect_px}")
        if self.min_support < 0:
            raise ValueError(f"the smallest support must not be negative, found {self.min_support}")
        if self.max_iop_move_sigma < 0:
            raise ValueError(f"the interior orientation's largest move must not be negative, found "
                             f"{self.max_iop_move_sigma}")


@dataclass(frozen=True)
class ScreeningDecision:
    camera_id: str          # owner: a camera id, an image id (its sensor's image parameters), or "GNSS" / "IMU"
    name: str
    t: float                # |a| / sigma(a) when dropped (after the earlier drops of its round)
    reason: str
    value: float = float("nan")     # the estimate when dropped (unit of the parameter: px, m, rad, ...)
    sigma: float = float("nan")     # its a-posteriori sigma then
    parameter: str = ""             # its name among the adjustment's unknowns (AdjustmentResult.theta_names)


@dataclass(frozen=True)
class ScreeningRound:
    """The joint test of every parameter dropped so far (this round and the earlier ones).

    ``increase`` is the sum of dOmega / sigma0^2 over the drops (the quadratic
    form of the dropped set in units of sigma0^2); F = increase / n_dropped.
    """

    n_dropped: int
    increase: float
    f_critical: float       # quantile 1 - alpha of F(n_dropped, redundancy)
    group: str = "all"      # what was dropped: "all", or a guarded group ("AP", "GNSS", "IMU", "GNSS S1", ...)
    #: the guarded groups' own joint tests (blocks with trajectory terms: APs, each sensor, each sensor's strip)
    groups: tuple["ScreeningRound", ...] = ()
    #: (name, value, sigma) of every trajectory term in the adjustment before any screening (kept for the later
    #: rounds: a term significant there is never dropped, see selfcal.stats.trajectory_screening)
    reference: tuple[tuple[str, float, float], ...] = ()
    #: how far the coefficients dropped for their small effect moved a sampled ray or point together (px; summed
    #: over the rounds' largest moves): the practical test's joint guard
    effect_moved_px: float = 0.0
    #: the interior orientation of the unscreened adjustment, the guard's reference in the later rounds: (names in
    #: theta, values, sigmas)
    iop_reference: tuple = ()

    @property
    def f_statistic(self) -> float:
        return self.increase / self.n_dropped

    @property
    def jointly_significant(self) -> bool:
        return self.f_statistic > self.f_critical


def screening_masks(problem) -> dict:
    """What a problem estimates of everything screening may hold, by owner (the ``free`` of
    :func:`selfcal.adjust.adjust`): a camera id -> its AP coefficients, ``("core", camera id)`` -> its
    sensor's screened core parameters, ``("image", image id)`` -> an image's parameters where its sensor
    screens them, "GNSS" / "IMU" -> the trajectory terms."""
    free = {cam.camera_id: cam.free[cam.n_core:].copy() for cam in problem.cameras}
    free.update({("core", cam.camera_id): cam.free[:cam.n_core].copy()
                 for cam in problem.cameras if any(cam.core_screened)})
    free.update({("image", i): f.copy() for i, f, s in zip(problem.image_ids, problem.image_free,
                                                           problem.image_screenable) if s.any()})
    free.update({t.sensor: t.free.copy() for t in problem.trajectory})
    return free


def _screenable(problem) -> tuple[dict[int, tuple], np.ndarray]:
    """theta index -> (owner key, position in the owner's mask, name, owner label, calibration, kind, held at
    nothing) of every active screenable parameter, and the reference values of theta (what screening tests a
    parameter against and holds it at: the start value of a sensor's parameter or the reference its sensor
    declares, zero for APs and trajectory terms), from the problem's :class:`~selfcal.adjust.ParameterTable`.
    ``calibration`` marks the parameters of the correlation test (not the trajectory terms); ``kind`` is the
    table's ("core", "ap", "image", "trajectory"); ``held at nothing`` the parameters of the test of practical
    significance (:func:`_held_at_nothing`)."""
    table = parameter_table(problem)
    owner = {}
    reference = np.zeros(problem.n_theta)
    image = np.flatnonzero(table.kind == "image")
    reference[table.index[image]] = table.reference[image]
    declared = {cam.camera_id: cam.core_reference for cam in problem.cameras}
    for k in np.flatnonzero(table.free & (table.index >= 0)):
        column = int(table.index[k])
        if table.kind[k] in ("core", "ap"):
            reference[column] = table.reference[k]
        if table.screenable[k] and (table.kind[k] != "image" or table.free[k]):
            kind, position = str(table.kind[k]), int(table.position[k])
            owner[column] = (table.key[k], position, str(table.name[k]), str(table.owner[k]),
                             kind != "trajectory", kind,
                             _held_at_nothing(kind, declared.get(str(table.owner[k]), ()), position))
    return owner, reference


def _held_at_nothing(kind: str, core_reference: tuple, position: int) -> bool:
    """Whether screening holds a parameter at the value where what it models is absent: the parameters of the test
    of practical significance (:mod:`selfcal.stats.effect`), whose question "does holding it there change the
    result by 0.1 px?" is then "does the block show what it models at all?".

    The rule: an AP coefficient (held at 0, no correction) and a sensor's screened core parameter whose sensor
    declares the reference it is held at (:attr:`selfcal.sensors.base.Parameter.reference`, in
    ``CameraParameters.core_reference``): a rolling shutter's readout, held at 0 ms, a global shutter. Not a core
    parameter held at its start value (a line scanner's calibration parameters, tested against the given
    calibration: holding one returns to a prior, not to nothing), nor a frame camera's c, x0, y0 (not screened),
    an image's parameters or a trajectory term (with their own guards, selfcal.stats.trajectory_screening)."""
    if kind == "ap":
        return True
    return kind == "core" and position < len(core_reference) and bool(np.isfinite(core_reference[position]))


class _Elimination:
    """The linearised block under the constraints of the parameters dropped so far."""

    def __init__(self, theta: np.ndarray, Q: np.ndarray, omega: float, redundancy: int):
        self.theta = theta.copy()
        self.Q = np.array(Q, dtype=float)    # a copy; dense (a BandedCofactor of a large block included)
        self.omega0 = self.omega = omega
        self.redundancy = redundancy
        self.followers: list = []           # told of each drop before its sweep (EffectTracker.drop(i, q))

    @property
    def variance_factor(self) -> float:
        return self.omega / self.redundancy

    def t(self, index: np.ndarray) -> np.ndarray:
        return np.abs(self.theta[index]) / np.sqrt(self.variance_factor * np.diag(self.Q)[index])

    def drop(self, i: int):
        q = self.Q[:, i].copy()
        qii = q[i]
        for follower in self.followers:
            follower.drop(i, q)
        self.omega += self.theta[i] ** 2 / qii
        self.theta -= q * (self.theta[i] / qii)
        rank_one_update(self.Q, -1.0 / qii, q, q)
        self.Q[i, :] = 0.0
        self.Q[:, i] = 0.0
        self.Q[i, i] = 1.0          # keeps the diagonal positive; index i is never tested again
        self.theta[i] = 0.0
        self.redundancy += 1


def screen_once(result, options: ScreeningOptions, before: ScreeningRound | None = None,
                max_drops: int | None = None, sensor_model: bool = False
                ) -> tuple[dict[str, np.ndarray], list[ScreeningDecision], ScreeningRound | None]:
    """One round of screening: backward elimination on the linearised block of ``result``.

    ``before`` is the joint record of the earlier rounds: the guard tests
    everything dropped since the unscreened adjustment, not only this round.
    ``max_drops``: the round stops after that many drops (the cross-validation's guard, in the tested workflow).
    ``sensor_model``: only the sensors' core parameters held at nothing (a rolling shutter's readout,
    :func:`_held_at_nothing`), by the same tests (significance, practical significance, correlation) but before
    any AP coefficient or trajectory term: whether the block shows what the sensor's model adds at all, asked
    first, so that a block that does not (a global shutter) is then screened as with the simpler model (the
    tested workflow's first round, :func:`selfcal.workflows.tested.adjust_with_tests`).

    Returns
    -------
    free : dict owner -> bool array (camera id: over its AP coefficients; "GNSS"/"IMU": shift/drift)
    decisions : list of ScreeningDecision, in the order of elimination (empty when nothing fails)
    joint : ScreeningRound (the joint test of all dropped so far), None when nothing was dropped
    """
    problem = result.problem
    free = screening_masks(problem)
    owner, reference = _screenable(problem)
    candidates = [k for k, o in owner.items() if not sensor_model or (o[5] == "core" and o[6])]
    if not candidates:
        return free, [], None
    groups = parameter_groups(problem)
    is_ap = np.zeros(problem.n_theta, bool)       # the calibration parameters of the correlation test
    is_ap[[k for k, o in owner.items() if o[4]]] = True
    orientation = np.concatenate([groups["IOP"], groups["EOP"]]).astype(np.int64)
    orientation = orientation[~is_ap[orientation] & _active(problem)[orientation]]
    partners = np.concatenate([orientation, groups["GNSS"], groups["IMU"]]).astype(np.int64)
    state = _Elimination(problem.pack(result.state) - reference, result.Q_theta,
                         result.variance_factor * result.redundancy, result.redundancy)
    guards = GroupGuards(result, state, options, before, owner)
    interior = _InteriorGuard(result, state, before, options.max_iop_move_sigma)
    active = np.array(sorted(candidates), dtype=np.int64)
    is_coefficient = np.zeros(problem.n_theta, bool)     # the cameras' AP coefficients (their support)
    is_coefficient[[k for k, o in owner.items() if o[5] == "ap"]] = True
    is_practical = np.zeros(problem.n_theta, bool)       # practical significance: held at nothing (_held_at_nothing)
    is_practical[[k for k, o in owner.items() if o[6]]] = True
    effects = effect_tracker(result, state.Q) if options.min_effect_px > 0 and is_practical.any() else None
    if effects is not None:
        state.followers.append(effects)
    decisions: list[ScreeningDecision] = []

    def drop(index: int, t: float, reason: str):
        nonlocal active
        key, position, name, label = owner[index][:4]
        free[key][position] = False
        sigma = float(np.sqrt(state.variance_factor * state.Q[index, index]))
        decisions.append(ScreeningDecision(label, name, t, reason, float(state.theta[index]), sigma,
                                           result.theta_names[index]))
        guards.record(index)
        state.drop(index)
        active = active[active != index]

    def full() -> bool:
        return max_drops is not None and len(decisions) >= max_drops

    if before is None and options.min_support > 0 and not sensor_model:
        # the first round: the coefficients of local functions that too few observations determine
        for index, count in _support(problem, owner, is_coefficient):
            if count < options.min_support and not full():
                drop(index, float(state.t(np.array([index]))[0]),
                     f"its support holds {count} observations (< {options.min_support})")

    n_before = before.n_dropped if before else 0
    increase_before = before.increase if before else 0.0
    alpha = options.joint_alpha if options.joint_alpha is not None else 0.05   # for the report when unguarded
    trajectory_limit = options.significance if options.trajectory_significance is None \
        else options.trajectory_significance
    protected: set[int] = set()          # trajectory terms a guard keeps (this round)

    def increase() -> float:
        return increase_before + (state.omega - state.omega0) / result.variance_factor

    def significance_step() -> bool:
        """Drop the least significant parameter its guards allow; False when there is none.

        APs are guarded by the joint test of the AP group: when the least significant AP fails it, no AP is
        dropped for significance (the correlation step may still drop one). A trajectory term that one of its
        guards keeps is protected for the rest of the round, and the next one is tried.
        """
        t = state.t(active)
        ap_closed = False
        for k in np.argsort(t, kind="stable"):
            index = int(active[k])
            if ap_closed and not guards.grouped:
                break
            if is_ap[index]:
                if ap_closed or t[k] >= options.significance:
                    ap_closed = True
                    continue
                if guards.ap_jointly_insignificant(active[k:k + 1])[0] and \
                        (not is_coefficient[index] or interior.allows(index)):
                    drop(index, float(t[k]), f"insignificant (t = {t[k]:.2f} < {options.significance:g})")
                    return True
                ap_closed = True
                continue
            if t[k] >= trajectory_limit:
                if ap_closed or t[k] >= options.significance:
                    break
                continue
            if index in protected:
                continue
            allowed, why = guards.trajectory_allows(index, trajectory_limit)
            if allowed:
                drop(index, float(t[k]), f"insignificant (t = {t[k]:.2f} < {trajectory_limit:g})")
                return True
            protected.add(index)
        return False

    moved: list[np.ndarray | None] = [None]      # the sampled rays' and points' move by this round's effect drops (px)
    allowance = options.min_effect_px - (before.effect_moved_px if before else 0.0)

    def effect_step() -> bool:
        """Drop the parameter held at nothing (an AP coefficient, a rolling shutter's readout: _held_at_nothing) of
        the smallest effect if it is below ``min_effect_px`` and the parameters dropped for their effect (in this
        round and before) stay below it together: each alone may be nothing, but twenty WAPs of 0.03-0.1 px each
        dropped from a Brown field made the check-point heights 23 % worse. A set that matters together keeps its
        members, whose effects grow as their partners go."""
        if effects is None:
            return False
        coefficients = active[is_practical[active]]
        if not coefficients.size:
            return False
        size = effects.effects_px(coefficients, state.theta, np.diag(state.Q))
        k = int(np.argmin(size))
        if size[k] >= options.min_effect_px:
            return False
        index = int(coefficients[k])
        move = effects.move_px(index, state.theta, np.diag(state.Q))
        together = move if moved[0] is None else moved[0] + move
        if effects.largest_px(together) >= allowance or (is_coefficient[index] and not interior.allows(index)):
            return False
        moved[0] = together
        drop(index, float(state.t(np.array([index]))[0]),
             f"its effect is {size[k]:.3f} px over the observed area (< {options.min_effect_px:g} px)")
        return True

    while active.size and not full():
        if significance_step() or effect_step():
            continue
        ap = active[is_ap[active]]
        pick = _most_correlated(state.Q, ap, partners, options.max_correlation, state.t(ap),
                                guards.ap_jointly_insignificant(ap))
        if pick is None:
            break
        a, other, rho = pick
        if other >= 0 and is_ap[other]:                   # a pair of APs: the less significant would go
            t_a, t_o = state.t(np.array([a, other]))
            weaker = a if t_a <= t_o else other
            if is_coefficient[weaker] and not interior.allows(weaker):
                break
        elif is_coefficient[a] and not interior.allows(a):
            break
        if other < 0:                                      # traded with the orientation and trajectory terms together
            drop(a, float(state.t(np.array([a]))[0]), f"its estimate is {rho:.3f} correlated with the orientation "
                 "and trajectory terms together (multiple correlation)")
            continue
        if is_ap[other]:                                   # a pair of APs: the less significant goes
            t_a, t_o = state.t(np.array([a, other]))
            weaker, stronger, t_w = (a, other, t_a) if t_a <= t_o else (other, a, t_o)
        else:
            weaker, stronger, t_w = a, other, float(state.t(np.array([a]))[0])
        why = ", less significant" if is_ap[other] else ""
        drop(weaker, float(t_w), f"correlated with {result.theta_names[stronger]} (|rho| = {rho:.3f}){why}")
    if not decisions:
        return free, [], None
    n = n_before + len(decisions)
    joint = ScreeningRound(n, float(increase()), float(f_ppf(1 - alpha, n, result.redundancy)),
                           groups=guards.records() if guards.grouped else (), reference=guards.reference,
                           iop_reference=interior.reference,
                           effect_moved_px=(before.effect_moved_px if before else 0.0)
                           + (effects.largest_px(moved[0]) if effects is not None and moved[0] is not None else 0.0))
    return free, decisions, joint


def kept_by_interior_guard(result, options: ScreeningOptions, before: ScreeningRound | None) -> list[ScreeningDecision]:
    """The AP coefficients a screened adjustment keeps only because of the interior orientation's guard
    (``max_iop_move_sigma``): those one more round of screening from ``result`` would drop without the guard and does
    not drop with it, each with the unguarded round's reason (a dry run: nothing is held). Empty without the guard."""
    if options.max_iop_move_sigma <= 0:
        return []
    _, guarded, _ = screen_once(result, options, before)
    _, unguarded, _ = screen_once(result, replace(options, max_iop_move_sigma=0.0), before)
    dropped = {(d.camera_id, d.name) for d in guarded}
    return [d for d in unguarded if (d.camera_id, d.name) not in dropped]


class _InteriorGuard:
    """Screening that leaves the interior orientation where the unscreened adjustment put it (``max_iop_move_sigma``).

    Holding a parameter at its reference moves every unknown correlated with it; c, x0 and y0 follow the APs, and
    where a few control points hold the heights, c takes the heights with it (H dc / c). No test sees it: on seed
    000's block with a local + Brown field (Type 1, 1 point per mm^2) the ~110 WAPs the t-tests drop are jointly
    insignificant (seed 1: F 1.217 for 116, at its 5 % bound) and predict held-out rays no worse, yet they moved c by
    0.36 of its sigma (4.5 of 12.7 um) and the check-point heights from 0.0381 to 0.0483 m (seed 4); over five seeds
    the mean RMSD(Z) rose 7.7 %. The
    move's squared bias estimated from the data (move^2 less the variance the drops remove) does not see it either:
    the drops' noise could explain it. So the guard bounds the damage instead: the drop of an AP coefficient (for
    significance, effect, correlation; not for too small a support: those coefficients are not determined; a sensor's
    calibration parameters and the GNSS/IMU terms have guards of their own) is refused when it would move a
    free core parameter of a camera that is not itself dropped by more than ``limit`` of its sigma from the unscreened
    adjustment: a move of 0.1 sigma adds at most 1 % to its mean square error where all of it is bias. The move is the
    re-adjusted estimate's (the earlier rounds') plus this round's sweeps (:class:`_Elimination`)."""

    def __init__(self, result, state: "_Elimination", before: ScreeningRound | None, limit: float):
        self.limit, self.state = float(limit), state
        problem = result.problem
        names = result.theta_names
        iop = parameter_groups(problem)["IOP"]
        theta = problem.pack(result.state)
        if before is not None and before.iop_reference:
            self.reference = before.iop_reference
        else:
            sigma = np.sqrt(result.variance_factor * state.Q.diagonal()[iop])     # (the round's dense copy)
            self.reference = (tuple(names[i] for i in iop), theta[iop].copy(), sigma)
        position = {n: i for i, n in enumerate(names)}
        ref_names, ref_values, ref_sigma = self.reference
        kept = [k for k, n in enumerate(ref_names) if n in position]
        self.index = np.array([position[ref_names[k]] for k in kept], np.int64)
        self.sigma = np.asarray(ref_sigma, float)[kept]
        self.start = theta[self.index] - np.asarray(ref_values, float)[kept]      # moved in the earlier rounds
        self.theta0 = state.theta[self.index].copy()

    def allows(self, i: int) -> bool:
        """Whether holding θ_i keeps every other free core parameter within ``limit`` sigma of the reference."""
        if self.limit <= 0 or not self.index.size:
            return True
        s = self.state
        q = s.Q[:, i]
        if not q[i] > 0:
            return True
        after = s.theta[self.index] - q[self.index] * (s.theta[i] / q[i])
        z = np.abs(self.start + after - self.theta0) / np.maximum(self.sigma, 1e-300)
        z[self.index == i] = 0.0
        return bool(z.max() <= self.limit)


def _active(problem) -> np.ndarray:
    """Which entries of theta are estimated (held image parameters are in theta with a unit diagonal)."""
    out = np.ones(problem.n_theta, bool)
    out[:problem.n_e] = problem.image_free.ravel()
    return out


def _support(problem, owner: dict, is_coefficient: np.ndarray) -> list[tuple[int, int]]:
    """(theta index, observations in its support) of every free AP coefficient of a local basis, fewest first."""
    out = []
    cam_of = problem.image_camera[problem.obs_image]
    by_key = {(o[0], o[1]): k for k, o in owner.items() if is_coefficient[k]}
    for c, cam in enumerate(problem.cameras):
        xy = problem.obs_value[cam_of == c]
        counts = cam.ap.support_counts(xy[:, 0], xy[:, 1]) if cam.ap.n_params and len(xy) else None
        if counts is None:
            continue
        out += [(by_key[(cam.camera_id, j)], int(n)) for j, n in enumerate(counts) if (cam.camera_id, j) in by_key]
    return sorted(out, key=lambda item: item[1])


def _most_correlated(Q: np.ndarray, ap: np.ndarray, partners: np.ndarray, threshold: float,
                     t: np.ndarray, droppable: np.ndarray):
    """(AP index, other index, |rho|) of the largest correlation above ``threshold`` among the pairs whose member
    to drop (the AP against an orientation or trajectory unknown, the less significant of two APs) may be dropped,
    or (AP index, -1, R) of the largest multiple correlation R of an AP with all ``partners`` together (the
    orientation and trajectory unknowns: an AP whose estimate they explain between them, as a tilt-like field the
    strips' IMU shifts and the attitudes share) when that is larger; None when there is none. ``t`` and
    ``droppable`` are over ``ap``."""
    if ap.size == 0:
        return None
    d = np.sqrt(np.diag(Q))
    others = np.concatenate([ap, partners])
    rho = np.abs(Q[np.ix_(ap, others)]) / d[ap][:, None] / d[others][None, :]
    rho[np.arange(ap.size), np.arange(ap.size)] = 0.0
    pair = rho[:, :ap.size]
    weaker_row = t[:, None] <= t[None, :]
    pair[~np.where(weaker_row, droppable[:, None], droppable[None, :])] = 0.0
    rho[~droppable, ap.size:] = 0.0
    r, c = np.unravel_index(int(np.argmax(rho)), rho.shape)
    best = (int(ap[r]), int(others[c]), float(rho[r, c]))
    if partners.size and droppable.any():
        multiple = _multiple_correlation(Q, ap, partners)
        multiple[~droppable] = 0.0
        k = int(np.argmax(multiple))
        if multiple[k] > best[2]:
            best = (int(ap[k]), -1, float(multiple[k]))
    return best if best[2] > threshold else None


def _multiple_correlation(Q: np.ndarray, index: np.ndarray, partners: np.ndarray) -> np.ndarray:
    """R of each estimate ``index`` with the estimates ``partners`` together: sqrt(q_iP Q_PP^-1 q_Pi / q_ii)."""
    Q_pp = Q[np.ix_(partners, partners)]
    d = np.sqrt(np.diag(Q_pp))
    try:
        L = np.linalg.cholesky(Q_pp / d[:, None] / d[None, :])
    except np.linalg.LinAlgError:
        return np.zeros(index.size)
    X = np.linalg.solve(L, (Q[np.ix_(partners, index)] / d[:, None]))
    return np.sqrt(np.clip(np.sum(X * X, axis=0) / np.diag(Q)[index], 0.0, 1.0))


#: the cross-validation guard keeps a dozen dense systems of the orientation and camera unknowns: up to this many
GUARD_LIMIT = 1200
#: the screened set predicts worse than the unscreened one when its prediction error is higher by more than this many
#: standard errors of their difference over the folds (one-sided, about 5 % with ten folds): one standard error
#: stopped the screening of a simulated Brown block at b1 (t 1.6, truly zero), whose drop moved the error by
#: 4.1e-6 px against a standard error of 4.0e-6 px
GUARD_STANDARD_ERRORS = 2.0


def _group_of(parameter: str) -> str:
    """The group a screened parameter is reported in: its camera, the image parameters, GNSS or IMU."""
    if parameter.startswith("camera "):
        return parameter.split(":")[0]
    if parameter.startswith("image "):
        return "image parameters"
    return parameter.split(" ")[0]


class PredictionGuard:
    """Screening that pays for itself: the screened parameter set must predict held-out tie points no worse than
    the unscreened one (:mod:`selfcal.stats.prediction`).

    Built on the unscreened adjustment: its fold systems (ten folds of tie points) and the path of the prediction
    error as the screening holds one parameter after another at its reference value (:class:`PredictionPath`, in
    the unscreened adjustment's linearisation: the re-adjustments between rounds move the estimates by a fraction of
    their sigma). :meth:`accepted` says how many of a round's drops keep the prediction error no worse than the
    unscreened one (within :data:`GUARD_STANDARD_ERRORS` standard errors of their difference over the folds: a
    parameter that is truly zero moves the error by a few 1e-6 px either way): the longest prefix of the round's
    drops that does, the screening stopping there if it is not all of them.
    """

    def __init__(self, result):
        from .prediction import converged_fold_systems
        problem = result.problem
        if problem.n_theta > GUARD_LIMIT:
            raise ValueError(f"{problem.n_theta} orientation and camera unknowns (the guard is built up to "
                             f"{GUARD_LIMIT})")
        self.origin = PredictionPath(converged_fold_systems(result), result.block.image_sigma_px)
        self.path = self.origin.copy()
        self.unscreened = self.origin.error()
        _, reference = _screenable(problem)
        self.move = reference - problem.pack(result.state)
        self.index = {name: i for i, name in enumerate(result.theta_names)}
        self.decisions: list[ScreeningDecision] = []
        self.stopped = ""
        self._evaluated: tuple[list[ScreeningDecision], PredictionPath] | None = None     # (decisions, their path)

    def _no_worse(self, path) -> bool:
        error = path.error()
        return bool(error.rmse_px <= self.unscreened.rmse_px
                    + GUARD_STANDARD_ERRORS * paired_se_px(error, self.unscreened))

    def _hold(self, path, decisions: list[ScreeningDecision]) -> None:
        for d in decisions:
            i = self.index.get(d.parameter)
            if i is not None:
                path.hold(i, self.move[i])

    def accepted(self, decisions: list[ScreeningDecision]) -> int:
        """How many of ``decisions`` (in order, after those committed) keep the prediction error no worse than the
        unscreened adjustment's: all of them if their whole set does, else the longest prefix that does."""
        path = self.path.copy()
        self._hold(path, decisions)
        if self._no_worse(path):
            self._evaluated = (list(decisions), path)
            return len(decisions)
        path, accepted = self.path.copy(), 0
        for k, d in enumerate(decisions):
            self._hold(path, [d])
            if self._no_worse(path):
                accepted = k + 1
        if accepted < len(decisions):
            d = decisions[accepted]
            self.stopped = (f"screening stopped before dropping {d.camera_id}.{d.name}: with the drops after it the "
                            f"prediction error of held-out tie points rises above the unscreened "
                            f"{self.unscreened.rmse_px:.6f} px by more than {GUARD_STANDARD_ERRORS:g} standard errors "
                            f"of the difference")
        return accepted

    def commit(self, decisions: list[ScreeningDecision]) -> None:
        if self._evaluated is not None and self._evaluated[0] == decisions:
            self.path = self._evaluated[1]
        else:
            self._hold(self.path, decisions)
        self._evaluated = None
        self.decisions += decisions

    def summary(self) -> dict:
        """screening.json ``prediction``: the prediction error unscreened and screened, and per group what the
        screening removed and what that alone cost (+) or gained (-)."""
        screened = self.path.error()
        groups: dict[str, list[int]] = {}
        for d in self.decisions:
            i = self.index.get(d.parameter)
            if i is not None:
                groups.setdefault(_group_of(d.parameter), []).append(i)
        rows = []
        for name, held in groups.items():
            if len(groups) == 1:
                error = screened
            else:
                path = self.origin.copy()
                for i in held:
                    path.hold(i, self.move[i])
                error = path.error()
            rows.append({"group": name, "n_removed": len(held), "cv_rmse_px": error.rmse_px,
                         "change_px": error.rmse_px - self.unscreened.rmse_px})
        return {"n_folds": self.unscreened.n_folds, "n_rays": self.unscreened.n_rays,
                "unscreened_cv_rmse_px": self.unscreened.rmse_px, "unscreened_cv_se_px": self.unscreened.se_px,
                "screened_cv_rmse_px": screened.rmse_px,
                "change_px": screened.rmse_px - self.unscreened.rmse_px, "stopped": self.stopped or None,
                "groups": rows}

