"""Statistical screening of additional parameters: significance and correlation tests.

Screened are the AP coefficients of every camera and the strip-wise
shift/drift parameters of the trajectory observations. After an adjustment,
each active one a_i is tested

* for significance: t_i = |a_i| / sigma(a_i); the coefficient is dropped when
  t_i < ``significance`` (default 1.96: two-sided test at alpha = 5 %, the
  normal quantile, adequate at the redundancies of a photogrammetric block);
* for correlation: when |rho| between an AP and another AP exceeds
  ``max_correlation`` (default 0.9) the less significant of the two is
  dropped; when an AP correlates that strongly with an interior or exterior
  orientation element, the AP is dropped (orientation is not screened).

Seed 000 takes its thresholds from the BINGO manual (Kruck 2021), which is
not public; the defaults above are ours and can be set on the command line.
Dropped coefficients are held at zero and the block is re-adjusted; the tests
are repeated until no coefficient fails (at most ``max_rounds`` times).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .correlation import parameter_groups

__all__ = ["ScreeningOptions", "ScreeningDecision", "screen_once"]


@dataclass(frozen=True)
class ScreeningOptions:
    significance: float = 1.96
    max_correlation: float = 0.9
    max_rounds: int = 20

    def __post_init__(self):
        if self.significance < 0:
            raise ValueError(f"the significance threshold must not be negative, found {self.significance}")
        if not 0 < self.max_correlation <= 1:
            raise ValueError(f"the correlation threshold must be in (0, 1], found {self.max_correlation}")


@dataclass(frozen=True)
class ScreeningDecision:
    camera_id: str          # owner: a camera id, or "GNSS" / "IMU"
    name: str
    t: float
    reason: str


def screen_once(result, options: ScreeningOptions) -> tuple[dict[str, np.ndarray], list[ScreeningDecision]]:
    """The AP activity after one round of tests, and why each dropped coefficient was dropped.

    Returns
    -------
    free : dict camera_id -> bool array over the camera's AP coefficients
    decisions : list of ScreeningDecision (empty when nothing fails)
    """
    problem, Q = result.problem, result.Q_theta
    vf = result.variance_factor
    groups = parameter_groups(problem)
    free = {cam.camera_id: cam.free[3:].copy() for cam in problem.cameras}
    free.update({t.sensor: t.free.copy() for t in problem.trajectory})
    # theta index -> (owner key, position in the owner's mask, name)
    owner = {}
    for cam, start in zip(problem.cameras, problem.d_offset):
        pos = start + np.cumsum(cam.free) - 1
        for i in range(3, cam.size):
            if cam.free[i]:
                owner[int(pos[i])] = (cam.camera_id, i - 3, cam.ap.parameter_names[i - 3])
    start = problem.n_e + problem.n_d
    for t in problem.trajectory:
        pos = start + np.cumsum(t.free) - 1
        for i in np.flatnonzero(t.free):
            owner[int(pos[i])] = (t.sensor, int(i), t.names[i])
        start += int(t.free.sum())
    ap_idx = np.array(sorted(owner), dtype=np.int64)
    if ap_idx.size == 0:
        return free, []
    theta = problem.pack(result.state)
    sigma = np.sqrt(vf * np.diag(Q))
    t = np.abs(theta) / sigma
    decisions: list[ScreeningDecision] = []
    drop: set[int] = set()

    def decide(index: int, reason: str):
        if index in drop:
            return
        drop.add(index)
        key, _, name = owner[index]
        decisions.append(ScreeningDecision(key, name, float(t[index]), reason))

    for index in ap_idx[t[ap_idx] < options.significance]:
        decide(int(index), f"insignificant (t = {t[index]:.2f} < {options.significance:g})")

    d = np.sqrt(np.diag(Q))
    orientation = np.concatenate([groups["IOP"], groups["EOP"]]).astype(np.int64)
    if orientation.size:
        rho = np.abs(Q[np.ix_(ap_idx, orientation)]) / d[ap_idx][:, None] / d[orientation][None, :]
        worst = rho.max(axis=1)
        for index, value, other in zip(ap_idx, worst, orientation[np.argmax(rho, axis=1)]):
            if value > options.max_correlation:
                decide(int(index), f"correlated with {result.theta_names[other]} (|rho| = {value:.2f})")
    rho = np.abs(Q[np.ix_(ap_idx, ap_idx)]) / d[ap_idx][:, None] / d[ap_idx][None, :]
    np.fill_diagonal(rho, 0.0)
    pairs = np.argwhere(np.triu(rho > options.max_correlation))
    for a, b in sorted(pairs.tolist(), key=lambda p: -rho[p[0], p[1]]):
        ia, ib = int(ap_idx[a]), int(ap_idx[b])
        if ia in drop or ib in drop:
            continue
        weaker, stronger = (ia, ib) if t[ia] < t[ib] else (ib, ia)
        decide(weaker, f"correlated with {result.theta_names[stronger]} (|rho| = {rho[a, b]:.2f}), less significant")

    for index in drop:
        key, i, _ = owner[index]
        free[key][i] = False
    return free, decisions
