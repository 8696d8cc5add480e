"""Guards of the screening for the strip-wise GNSS/IMU shift/drift terms (issue 25).

Trajectory observations are few and strongly weighted: a shift or drift term
that is really there but dropped is absorbed by the image orientations, and the
block bends to follow it. :func:`selfcal.stats.screening.screen_once` therefore
only drops a trajectory term when all of these hold (each evaluated on the
linearised block with the term and everything dropped before it held at zero):

1. its t is below ``ScreeningOptions.trajectory_significance`` (default
   3 - z(0.95) = 1.355: the estimate shows the term smaller than 3 sigma at
   95 %, one-sided) at the drop *and* in the adjustment before any screening
   (``reference``, carried through the rounds): sequential drops move the
   estimates of correlated terms, and a term must not become droppable only
   because an earlier drop pulled it towards zero;
2. at most half of its variance is shared with the interior orientation
   (R^2 on c, x0, y0 <= ``CONFOUNDED_SHARE``): with c self-calibrated over gently
   rolling ground every strip's GNSS height shift is 80-95 % c; its t then tests
   the camera rather than the term, and dropping one fixes c from the GNSS with
   that strip's shift, after which the other strips' shifts look insignificant
   in turn (the simulated blocks of issue 25 lost three of four that way);
3. the joint test of its *sensor*: the quadratic form of every term of that
   sensor dropped so far stays below the F quantile (the joint guard per group:
   APs, GNSS and IMU are tested separately, so many truly zero WAPs cannot hide
   a real trajectory term);
4. the joint test of its *strip*: the same for the terms of that sensor and
   strip (shift and drift of one strip together);
5. the residuals of that strip's observations of the sensor: neither a w-test
   (Baarda, a-priori sigma, above ``trajectory_w_critical``) nor the group test
   of the strip (sum of squared whitened residuals against the chi-square
   quantile of their redundancy) becomes significant through the drop.

A term one of these keeps is not tried again in the round; the others still are.
This module holds the pieces that know about strips and sensors: which terms and
observation rows belong to which (sensor, strip), the per-group joint tests and
the residual tests. The elimination itself (sweep updates) is
:class:`selfcal.stats.screening._Elimination`; a block without trajectory
terms is screened exactly as before (one group: its APs).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from .distributions import chi2_ppf, f_ppf, normal_ppf

__all__ = ["AP_GROUP", "CONFOUNDED_SHARE", "TRAJECTORY_SIGNIFICANCE", "GroupGuards", "StripObservations",
           "trajectory_strips", "group_of_parameters", "strip_residual_tests", "joint_test_passes"]

AP_GROUP = "AP"

#: a trajectory term is dropped only when its estimate shows it smaller than 3 sigma at 95 % (one-sided):
#: t < 3 - z(0.95), before the screening and at the drop
TRAJECTORY_SIGNIFICANCE = 3.0 - float(normal_ppf(0.95))

#: a trajectory term whose variance is more than this share explained by the interior orientation is not
#: dropped: its t measures the camera calibration, not the term (the strip heights against c over flat ground)
CONFOUNDED_SHARE = 0.5


@dataclass
class StripObservations:
    """The observations of one sensor in one strip, linearised at the round's start.

    ``columns`` are the theta indices the rows depend on (orientation of the
    strip's images, the sensor's free terms); ``J`` the whitened Jacobian over
    them (rows x columns), ``v0`` the whitened residuals l - f at the start.
    """

    sensor: str
    strip: str
    terms: np.ndarray          # theta indices of the strip's free shift/drift terms
    columns: np.ndarray
    J: np.ndarray
    v0: np.ndarray

    @property
    def name(self) -> str:
        return f"{self.sensor} {self.strip}"


def group_of_parameters(problem, owner: dict) -> dict[int, tuple[str, str | None]]:
    """theta index -> (group, strip group) of every free screenable parameter of ``owner`` (the table of
    :func:`selfcal.stats.screening._screenable`): the calibration parameters (APs, a sensor's screened core and
    image parameters) are group "AP" (no strip), trajectory terms their sensor and "SENSOR STRIP" (the mounting
    terms: no strip)."""
    out: dict[int, tuple[str, str | None]] = {k: (AP_GROUP, None) for k, o in owner.items() if o[4]}
    start = problem.n_e + problem.n_d
    for t in problem.trajectory:
        pos = start + np.cumsum(t.free) - 1
        per_strip = (t.order + 1) * 3 if t.order >= 0 else 0
        for i in np.flatnonzero(t.free):
            strip = t.strips[i // per_strip] if i < t.n_strip_params else None
            out[int(pos[i])] = (t.sensor, None if strip is None else f"{t.sensor} {strip}")
        start += int(t.free.sum())
    return out


def trajectory_strips(result) -> dict[str, StripObservations]:
    """The observations of every (sensor, strip) of the adjustment ``result`` with their Jacobian and residuals."""
    problem = result.problem
    J_x, r_x, labels = result.parameter_observations()
    if J_x.shape[0] == 0:
        return {}
    J_x = J_x.tocsr()
    out: dict[str, StripObservations] = {}
    row0 = int(np.sum((labels == "camera") | (labels == "image")))     # the a-priori parameters come first
    start = problem.n_e + problem.n_d
    for t in problem.trajectory:
        pos = start + np.cumsum(t.free) - 1
        per_strip = (t.order + 1) * 3 if t.order >= 0 else 0
        for s, strip in enumerate(t.strips):
            mine = np.flatnonzero(t.strip_of == s)
            rows = row0 + (3 * mine[:, None] + np.arange(3)[None, :]).ravel()
            block = J_x[rows]
            columns = np.unique(block.indices)
            terms = np.array([int(pos[i]) for i in range(s * per_strip, (s + 1) * per_strip) if t.free[i]], np.int64)
            columns = np.union1d(columns, terms)
            out[f"{t.sensor} {strip}"] = StripObservations(t.sensor, strip, terms, columns,
                                                           block[:, columns].toarray(), r_x[rows].copy())
        row0 += 3 * len(t.index)
        start += int(t.free.sum())
    return out


def strip_residual_tests(strip: StripObservations, theta: np.ndarray, theta0: np.ndarray, Q_strip: np.ndarray,
                         alpha: float) -> tuple[float, bool]:
    """Largest |w| of the strip's observations and whether their group test is significant, for the
    linearised block at ``theta`` (``theta0``: where ``v0`` was taken) with the cofactor ``Q_strip`` of the
    strip's columns.

    w = v / sqrt(r) with v the whitened residual and r its redundancy number 1 - (J Q J^T)_ii (Baarda, a-priori
    sigma); the group statistic is sum(v^2) against the 1 - alpha quantile of chi-square with sum(r) degrees of
    freedom.
    """
    c = strip.columns
    v = strip.v0 - strip.J @ (theta[c] - theta0[c])
    r = np.clip(1.0 - np.einsum("ij,jk,ik->i", strip.J, Q_strip, strip.J), 1e-12, None)
    dof = float(np.sum(r))
    significant = bool(dof > 0.5 and np.sum(v * v) > chi2_ppf(1 - alpha, dof))
    return float((np.abs(v) / np.sqrt(r)).max()) if v.size else 0.0, significant


def joint_test_passes(increase: float, n_dropped: int, redundancy: int, alpha: float | None) -> bool:
    """Whether a dropped set with quadratic form ``increase`` (units of sigma0^2) stays jointly insignificant."""
    if alpha is None or n_dropped == 0:
        return True
    return increase / n_dropped <= f_ppf(1 - alpha, n_dropped, redundancy)


class GroupGuards:
    """The joint guards of one screening round, per group of parameters.

    A block without trajectory terms has one group (its APs) and is guarded as
    before: by the joint test of everything dropped, read from the main
    elimination. With trajectory terms, every group (APs, each sensor) and every
    sensor's strip has a joint test of its own dropped set, continued from the
    records of the earlier rounds (``before``). The AP group keeps an
    elimination of its own (its candidates are tested in bulk by the correlation
    step); the trajectory sets are small and their quadratic forms are taken
    directly, theta_S' Q_SS^-1 theta_S at the round's start.
    """

    def __init__(self, result, main, options, before, owner):
        problem = result.problem
        self.options = options
        self.alpha = options.joint_alpha if options.joint_alpha is not None else 0.05
        self.redundancy = result.redundancy
        self.vf0 = result.variance_factor
        self.main = main
        self.group = group_of_parameters(problem, owner)
        self.grouped = bool(problem.trajectory)
        self.theta0 = main.theta.copy()
        self.Q0 = result.Q_theta               # the eliminations work on copies of it
        self.dropped: dict[str, list[int]] = {}
        self.before: dict[str, tuple[int, float]] = {}
        if before is not None:
            if before.groups:
                self.before = {g.group: (g.n_dropped, g.increase) for g in before.groups}
            elif not self.grouped:
                self.before = {AP_GROUP: (before.n_dropped, before.increase)}
        self.ap_state = main
        if self.grouped:
            self.ap_state = type(main)(main.theta, main.Q, main.omega, main.redundancy)
        self.strips = trajectory_strips(result) if self.grouped else {}
        from .correlation import parameter_groups
        self.iop = parameter_groups(problem)["IOP"]
        first = problem.n_e + problem.n_d
        self.names = {first + k: name for k, name in enumerate(problem.extra_names)}
        if before is not None and before.reference:
            self.reference = before.reference
        else:
            index = np.array(sorted(self.names), np.int64)
            sigma = np.sqrt(main.variance_factor * np.diag(main.Q)[index])
            self.reference = tuple((self.names[int(i)], float(main.theta[i]), float(s)) for i, s in zip(index, sigma))
        self.reference_t = {name: abs(value) / sigma for name, value, sigma in self.reference}

    # -- bookkeeping
    def record(self, index: int) -> None:
        group, strip = self.group[index]
        self.dropped.setdefault(group, []).append(index)
        if strip is not None:
            self.dropped.setdefault(strip, []).append(index)
        if group == AP_GROUP and self.grouped:
            self.ap_state.drop(index)

    def _prior(self, name: str) -> tuple[int, float]:
        return self.before.get(name, (0, 0.0))

    def _quadratic_form(self, index: list[int]) -> float:
        """theta_S' Q_SS^-1 theta_S / sigma0^2 of a set at the round's start."""
        if not index:
            return 0.0
        idx = np.array(index, np.int64)
        return float(self.theta0[idx] @ np.linalg.solve(self.Q0[np.ix_(idx, idx)], self.theta0[idx])) / self.vf0

    def increase(self, name: str) -> float:
        n0, inc0 = self._prior(name)
        if name == AP_GROUP:
            return inc0 + (self.ap_state.omega - self.ap_state.omega0) / self.vf0
        return inc0 + self._quadratic_form(self.dropped.get(name, []))

    def shared_with_interior_orientation(self, index: int) -> float:
        """R^2 of a parameter on the interior orientation (c, x0, y0): the share of its variance that the
        camera calibration explains, q_iI Q_II^-1 q_Ii / q_ii (0 without estimated interior orientation)."""
        if not self.iop.size:
            return 0.0
        Q = self.main.Q
        q = Q[index, self.iop]
        return float(q @ np.linalg.solve(Q[np.ix_(self.iop, self.iop)], q) / Q[index, index])

    # -- the tests
    def ap_jointly_insignificant(self, index: np.ndarray) -> np.ndarray:
        """Per AP candidate: would the AP group's dropped set, with it added, pass its joint F-test?"""
        if self.options.joint_alpha is None:
            return np.ones(index.size, bool)
        n0, _ = self._prior(AP_GROUP)
        k = n0 + len(self.dropped.get(AP_GROUP, [])) + 1
        s = self.ap_state
        chi2 = self.increase(AP_GROUP) + s.theta[index] ** 2 / np.diag(s.Q)[index] / self.vf0
        return chi2 / k <= f_ppf(1 - self.alpha, k, self.redundancy)

    def _set_passes(self, name: str, index: int) -> bool:
        n0, inc0 = self._prior(name)
        members = self.dropped.get(name, []) + [index]
        return joint_test_passes(inc0 + self._quadratic_form(members), n0 + len(members), self.redundancy,
                                 self.options.joint_alpha)

    def trajectory_allows(self, index: int, limit: float) -> tuple[bool, str]:
        """Whether the trajectory term ``index`` (insignificant now: t < ``limit``) may be dropped; the
        reason when not."""
        sensor, strip = self.group[index]
        reference = self.reference_t.get(self.names[index], 0.0)
        if reference >= limit:
            return False, f"significant before the screening (t = {reference:.2f})"
        shared = self.shared_with_interior_orientation(index)
        if shared > CONFOUNDED_SHARE:
            return False, f"confounded with the interior orientation ({100 * shared:.0f} % of its variance)"
        if not self._set_passes(sensor, index):
            return False, f"the {sensor} terms dropped with it would be jointly significant"
        if strip is None:
            return True, ""
        if not self._set_passes(strip, index):
            return False, f"the {strip} terms dropped with it would be jointly significant"
        obs = self.strips.get(strip)
        if obs is None or obs.J.shape[0] == 0:
            return True, ""
        m, c = self.main, obs.columns
        Qc = m.Q[np.ix_(c, c)]
        w_before, group_before = strip_residual_tests(obs, m.theta, self.theta0, Qc, self.alpha)
        q = m.Q[:, index]                                  # the drop, tentatively (the sweep of _Elimination.drop)
        theta = m.theta - q * (m.theta[index] / q[index])
        w_after, group_after = strip_residual_tests(obs, theta, self.theta0, Qc - np.outer(q[c], q[c]) / q[index],
                                                    self.alpha)
        if w_after > self.options.trajectory_w_critical and w_after > w_before:
            return False, f"a {strip} observation would fail its w-test (|w| = {w_after:.2f})"
        if group_after and not group_before:
            return False, f"the {strip} observations would fail their group test"
        return True, ""

    def records(self):
        """The joint test of each guarded group and strip with drops (this round and before)."""
        from .screening import ScreeningRound
        names = list(dict.fromkeys(list(self.before) + list(self.dropped)))
        out = []
        for name in names:
            n = self._prior(name)[0] + len(self.dropped.get(name, []))
            if n:
                out.append(ScreeningRound(n, float(self.increase(name)),
                                          float(f_ppf(1 - self.alpha, n, self.redundancy)), name))
        return tuple(out)

