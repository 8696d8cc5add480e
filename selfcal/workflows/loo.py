"""Leave-one-out validation of the control (issue 40 item 3): each control point of a tested adjustment left out
of the control in turn, the block re-adjusted without it, its error against its surveyed coordinates tested
(:mod:`selfcal.stats.loo`).

What is re-run, per control point: the tested adjustment's block as it ended (its rejections made, its AP set
as the screening left it, the AP basis kept), with that point a check point, adjusted from the converged
estimate with the caller's options: no robust loss, no data snooping, no screening. The estimate moves by the
datum's share of that one point; the engine starts from the downdated estimate
(:func:`selfcal.adjust.update.downdated_start`: the point's control rows taken out of the normal equations) and
one Gauss-Newton iteration converges it (seed 000's block: within 5e-8 m of a re-adjustment converged to 1e-9 of
a sigma). The linear rank-3 downdate alone costs nothing but misses by the re-linearisation's 2e-5 to 1.6e-4 m
(:func:`selfcal.stats.loo.downdate`), beyond the 1e-6 m asked for.

A control point the tests (or the robust cleaning) already checked instead is left out of this adjustment: its
error is the adjustment's own (role ``demoted``).
"""
from __future__ import annotations

import time
from dataclasses import replace
from typing import Callable

import numpy as np

from ..adjust import AdjustOptions, adjust
from ..adjust.residuals.control import control_weights
from ..errors import AdjustmentError
from ..stats.checks import local_axes
from ..stats.loo import LeaveOneOut, downdate, fully_controlled
from .tested import TestedAdjustment

__all__ = ["control_loo", "loo_notes", "loo_summary", "MIN_CONTROL_LOO"]

#: the control is validated point by point only where this many control points hold the datum (one left out,
#: three or more remain) or a trajectory holds it too
MIN_CONTROL_LOO = 4


def _frame(result) -> str:
    return result.problem.sensors[0].sensor.object_frame if result.problem.sensors else "block"


def control_loo(tested: TestedAdjustment, options: AdjustOptions,
                say: Callable[[str], None] | None = None) -> LeaveOneOut | None:
    """Every control point's leave-one-out error (module docstring); None where the block has no control datum
    or too few control points. ``say`` receives a line as the re-adjustments begin and one at most every second
    after (how many are done)."""
    t0 = time.perf_counter()
    said = t0
    result = tested.result
    block = result.block
    control = result.problem.control
    demoted = [name for name, _ in tested.control_demoted]
    if tested.cleaning is not None:
        demoted += [name for name, _ in tested.cleaning.control_demoted]
    ids = list(block.points.point_id)
    demoted_index = [ids.index(name) for name in demoted if name in ids]
    if block.datum == "free" or (len(control.index) < MIN_CONTROL_LOO and not block.has_trajectory):
        return None
    axes = local_axes(block.points.xyz_m[control.index], _frame(result), block.crs)
    models = {cam.camera_id: cam.ap for cam in result.problem.cameras}
    n = len(control.index) + len(demoted_index)
    d = np.full((n, 3), np.nan)
    cov = np.full((n, 3, 3), np.nan)
    # the linear prediction, to say how far it is from the re-adjustments (summary.json)
    linear, _ = downdate(control.W, result.Q_points[control.index], result.state.points[control.index] - control.xyz)
    names, roles = [], []
    whole = fully_controlled(control.W)
    if say is not None:
        say(f"leave-one-out control validation: the block re-adjusted without each of {len(control.index)} "
            "control points")
    for k, p in enumerate(control.index):
        if say is not None and k and time.perf_counter() - said >= 1.0:
            said = time.perf_counter()
            say(f"leave-one-out control validation: {k}/{len(control.index)} done")
        name = str(block.points.point_id[p])
        names.append(name)
        roles.append("gcp")
        if not whole[k]:
            continue                        # (controlled on fewer than three axes: no 3-D test; left undetermined)
        d[k], cov[k] = _left_out(tested, options, models, p, name, np.linalg.inv(control.W[k].T @ control.W[k]))
    gap = np.abs(linear - d[:len(control.index)])
    linear_gap = float(np.nanmax(gap)) if np.isfinite(gap).any() else None
    if demoted_index:
        W = control_weights(block, np.array(demoted_index), _frame(result))
        for k, p in enumerate(demoted_index, start=len(control.index)):
            names.append(str(block.points.point_id[p]))
            roles.append("demoted")
            if not fully_controlled(W[k - len(control.index):k - len(control.index) + 1])[0]:
                continue
            C = np.linalg.inv(W[k - len(control.index)].T @ W[k - len(control.index)])
            d[k] = result.state.points[p] - block.points.xyz_m[p]
            cov[k] = result.Q_points[p] + C
    d = d @ axes.T
    cov = np.einsum("ij,njk,lk->nil", axes, cov, axes)
    return LeaveOneOut(np.array(names, object), np.array(roles, object), d, cov, tested.tests.critical,
                       seconds=time.perf_counter() - t0, linear_gap_m=linear_gap)


def _left_out(tested: TestedAdjustment, options: AdjustOptions, models: dict, p: int, name: str,
              survey: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Control point ``p`` (``name``) left out: its error against its surveyed coordinates and the error's cofactor
    (the re-adjustment's point block plus ``survey``'s); NaN where it is not determined without its coordinates.
    The re-adjustment lives in this call only: one at a time, however many control points there are."""
    result = tested.result
    block = result.block
    role = np.asarray(block.points.role).copy()
    role[p] = "chk"
    without = replace(block, points=replace(block.points, role=role))
    undetermined = np.full(3, np.nan), np.full((3, 3), np.nan)
    try:
        other = adjust(without, options, start=result, free=tested.ap_free, ap_models=models)
    except AdjustmentError:
        return undetermined                 # (the others do not fix the datum)
    try:
        return _error_of(other, name, block.points.xyz_m[p], survey, undetermined)
    finally:
        result.take_back_ap_columns(other)  # (the same observations: the next control point's start carries them)


def _error_of(other, name: str, surveyed_m: np.ndarray, survey: np.ndarray, undetermined: tuple):
    """The left-out control point's error in the re-adjustment ``other`` and its cofactor (see :func:`_left_out`)."""
    where = np.flatnonzero(other.block.points.point_id == name)
    if not where.size or not other.converged:
        return undetermined                 # (too few rays of its own)
    j = int(where[0])
    # the re-adjustment's own cofactor (the downdate's differs by the re-linearisation: 6e-4 of it at an edge)
    cov = other.some_point_cofactors(np.array([j]))[0] + survey
    if np.linalg.eigvalsh(0.5 * (cov + cov.T)).min() <= 0:
        return undetermined                 # (a cofactor that is not positive)
    return other.state.points[j] - surveyed_m, cov


def loo_summary(loo: LeaveOneOut) -> dict:
    """summary.json ``control_loo``: how many control points, how many fail, the worst."""
    t = loo.t3
    worst = loo.worst()
    fails = loo.fails
    return {"n_control": len(loo), "n_determined": int(np.isfinite(t).sum()), "n_failing": int(fails.sum()),
            "failing": [str(p) for p in loo.point_id[fails]], "critical_t3": loo.critical_t3, "method": loo.method,
            "worst_point_id": None if worst is None else str(loo.point_id[worst]),
            "worst_t3": None if worst is None else float(t[worst]),
            "worst_d_m": None if worst is None else [float(x) for x in loo.d_m[worst]],
            "linear_downdate_gap_m": loo.linear_gap_m, "seconds": loo.seconds}


def loo_notes(loo: LeaveOneOut) -> list[str]:
    """The warnings of the validation: the worst control point that fails it (and how many others do), each
    control point that its rays do not determine without its coordinates."""
    notes = []
    t = loo.t3
    fails = loo.fails
    if fails.any():
        k = int(np.nanargmax(np.where(fails, t, -np.inf)))
        others = int(fails.sum()) - 1
        d = loo.d_m[k]
        notes.append(f"control point '{loo.point_id[k]}' fails the leave-one-out test of the control: left out, the "
                     f"block puts it {float(np.linalg.norm(d)):.3f} m from its surveyed coordinates (d {d[0]:+.3f}, "
                     f"{d[1]:+.3f}, {d[2]:+.3f} m; T {t[k]:.1f} > {loo.critical_t3:.1f}, chi2(3)): mis-surveyed or "
                     f"misidentified?" + (f" {others} other control point(s) fail too (control_loo.csv)"
                                          if others else ""))
    lost = [str(p) for p, r, x in zip(loo.point_id, loo.role, t) if not np.isfinite(x)]
    if lost:
        notes.append(f"leave-one-out: control point(s) {', '.join(repr(p) for p in lost)} not determined without "
                     f"their surveyed coordinates (too few rays, or the others do not fix the datum): not validated")
    return notes
