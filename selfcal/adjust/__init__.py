"""The adjustment engine: self-calibrating bundle adjustment of a block.

>>> result = adjust(block, AdjustOptions(ap="none"))        # doctest: +SKIP
>>> result.sigma0_px, result.converged                        # doctest: +SKIP

:func:`adjust` sets up the problem (:mod:`.problem`), finds initial values
(:mod:`.initial`), iterates (:mod:`.solver`) and extracts the cofactor
matrices (:mod:`.covariance`). It never reads files and never prints; progress
goes to an optional callback.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ..block import Block
from ..errors import AdjustmentError
from .covariance import point_cofactors
from .initial import initial_state
from .linalg import DENSE_LIMIT, SingularSystem, factorise, null_directions
from .normal import Linearisation, SingularPoints, carry_ap_columns, image_residuals, reduce
from .problem import Problem, State, build_problem
from .solver import IterationRecord, SolverOptions, solve

__all__ = ["AdjustOptions", "AdjustmentResult", "IterationRecord", "adjust", "Problem", "State"]


@dataclass(frozen=True)
class AdjustOptions:
    """What to estimate and how.

    Attributes
    ----------
    ap : str
        Additional-parameter model, e.g. ``"none"``, ``"brown"``, ``"wavelet:db4"``.
    grid : (int, int)
        Gx x Gy grid of the wavelet APs (Eq. 10 of seed 000).
    gnss_drift, imu_drift : int
        Order of the strip-wise shift/drift of GNSS positions and IMU attitudes
        (Eq. 12 of seed 000): -1 none, 0 shift, 1 shift + linear drift (default), 2 quadratic.
    lever_arm, boresight : bool
        Estimate the GNSS lever arm and the IMU boresight angles (need the order -1).
    solver : SolverOptions
    """

    ap: str = "none"
    grid: tuple[int, int] = (9, 6)
    gnss_drift: int = 1
    imu_drift: int = 1
    lever_arm: bool = False
    boresight: bool = False
    solver: SolverOptions = field(default_factory=SolverOptions)


@dataclass
class AdjustmentResult:
    """The estimate, its precision and how it was reached.

    Precision is a-posteriori: covariance = variance_factor · cofactor.
    Residuals follow l + v = f(x): v = adjusted - observed.
    """

    problem: Problem
    state: State
    block: Block                   # the block actually adjusted (after pruning)
    converged: bool
    reason: str
    iterations: int
    history: list[IterationRecord]
    cost: float
    n_observations: int
    n_unknowns: int
    variance_factor: float
    image_sigma_px: float
    theta_names: list[str]
    Q_theta: np.ndarray
    Q_points: np.ndarray
    residuals_mm: np.ndarray       # (m, 2) image residuals in ``block``'s observation order, photo axes
    notes: list[str]
    seconds: float
    linearisation: Linearisation = field(repr=False, default=None)
    v_inv: list = field(repr=False, default=None)

    @property
    def redundancy(self) -> int:
        return self.n_observations - self.n_unknowns

    @property
    def sigma0_px(self) -> float:
        """A-posteriori sigma of an image coordinate of unit weight, pixels."""
        return self.image_sigma_px * float(np.sqrt(self.variance_factor))

    def eop_sigma(self) -> np.ndarray:
        """A-posteriori standard deviations of the exterior orientation, (n_images, 6) (m, rad)."""
        n_e = self.problem.n_e
        return np.sqrt(self.variance_factor * np.diag(self.Q_theta)[:n_e]).reshape(-1, 6)

    def camera_sigma(self) -> list[np.ndarray]:
        """A-posteriori standard deviations of each camera's parameters (NaN where fixed)."""
        out = []
        diag = np.diag(self.Q_theta)
        for cam, start in zip(self.problem.cameras, self.problem.d_offset):
            s = np.full(cam.size, np.nan)
            k = int(cam.free.sum())
            s[cam.free] = np.sqrt(self.variance_factor * diag[start:start + k])
            out.append(s)
        return out

    def predict_pixels(self, image_ids, point_ids) -> np.ndarray:
        """Adjusted image positions (col, row) of arbitrary (image, point) pairs, by id.

        NaN where the image or the point is not part of the adjustment (e.g. an
        observation rejected together with its point).
        """
        from ..sensors.frame import pixel_from_photo, project
        img_lookup = {i: k for k, i in enumerate(self.block.images.image_id)}
        pt_lookup = {p: k for k, p in enumerate(self.block.points.point_id)}
        img = np.array([img_lookup.get(i, -1) for i in image_ids], dtype=np.int64)
        pt = np.array([pt_lookup.get(p, -1) for p in point_ids], dtype=np.int64)
        out = np.full((len(img), 2), np.nan)
        ok = (img >= 0) & (pt >= 0)
        if not ok.any():
            return out
        cam_idx = self.problem.image_camera[img[ok]]
        iop = np.array([c[:3] for c in self.state.cameras])[cam_idx]
        xy = project(self.state.points[pt[ok]], self.state.eop[img[ok]], iop)
        for k, cam in enumerate(self.problem.cameras):
            sel = np.flatnonzero(cam_idx == k)
            if sel.size and cam.ap.n_params:
                # Delta is evaluated at the observed position; at the adjusted one it differs by a second-order term
                dx, dy = cam.ap.displacement_px(xy[sel, 0], xy[sel, 1], self.state.cameras[k][3:] * cam.free[3:])
                xy[sel, 0] += cam.pixel_size_mm * dx
                xy[sel, 1] += cam.pixel_size_mm * dy
        cfg = self.block.cameras
        ids = [self.problem.cameras[k].camera_id for k in cam_idx]
        w = np.array([cfg[c].width_px for c in ids], float)
        h = np.array([cfg[c].height_px for c in ids], float)
        p = np.array([cfg[c].pixel_size_mm for c in ids], float)
        out[ok] = pixel_from_photo(xy, w, h, p)
        return out

    def point_covariance(self) -> np.ndarray:
        """A-posteriori covariance of every object point, (n_points, 3, 3) in m^2."""
        return self.variance_factor * self.Q_points


def _free_network_cofactor(S, notes: list[str], defect_tol: float = 1e-10) -> np.ndarray:
    """Cofactor of theta in a free network: the pseudo-inverse of S (minimum-trace datum).

    The eigenvalues of the scaled S below ``defect_tol`` times the largest are
    the datum defect and are left out.
    """
    S = S.toarray() if hasattr(S, "toarray") else np.asarray(S)
    if S.shape[0] > DENSE_LIMIT:
        raise AdjustmentError("free-network covariance is implemented for up to "
                              f"{DENSE_LIMIT} orientation and camera unknowns")
    d = np.sqrt(np.clip(np.diag(S), 1e-300, None))
    w, V = np.linalg.eigh(S / d[:, None] / d[None, :])
    keep = w > defect_tol * w.max()
    notes.append(f"free network: datum defect {int((~keep).sum())}; precision in the minimum-trace datum")
    Q = (V[:, keep] / w[keep]) @ V[:, keep].T
    return Q / d[:, None] / d[None, :]


def _offsets(problem: Problem) -> list[int]:
    offsets, start = [], problem.n_e
    for cam in problem.cameras:
        offsets.append(start)
        start += int(cam.free.sum())
    return offsets


def adjust(block: Block, options: AdjustOptions = AdjustOptions(),
           progress: Callable[[IterationRecord], None] | None = None,
           start: "AdjustmentResult | None" = None, free: dict | None = None,
           ap_models: dict | None = None) -> AdjustmentResult:
    """Adjust a block: estimate orientation, object points and camera parameters.

    Parameters
    ----------
    block : Block
        A pruned block (as :func:`selfcal.io.read_block` returns it).
    options : AdjustOptions
    progress : callable, optional
        Called with an :class:`IterationRecord` after every iteration.
    start : AdjustmentResult, optional
        A previous adjustment of (a superset or subset of) this block: its
        estimates are the initial values wherever the ids match (warm start,
        used by data snooping and AP screening).
    free : dict, optional
        Which screenable parameters are estimated, by owner: a camera id maps to
        a bool array over its AP coefficients, "GNSS" or "IMU" to one over that
        sensor's shift/drift parameters. The others are held at zero.
    ap_models : dict camera_id -> APModel, optional
        Use these AP models instead of building them from ``options.ap``
        (keeps a basis fixed across re-adjustments).

    Raises
    ------
    AdjustmentError
        When the block has a rank defect (the message names the unknowns
        involved) or cannot be initialised.
    """
    t0 = time.perf_counter()
    settings = {"grid": options.grid} if options.ap.startswith("wavelet") else {}
    problem = build_problem(block, options.ap, settings, ap_models=ap_models,
                            gnss_drift=options.gnss_drift, imu_drift=options.imu_drift,
                            lever_arm=options.lever_arm, boresight=options.boresight)
    if free:
        for cam in problem.cameras:
            if cam.camera_id in free:
                cam.free[3:] = np.asarray(free[cam.camera_id], bool)
        for t in problem.trajectory:
            if t.sensor in free:
                t.free[:] = np.asarray(free[t.sensor], bool)
        problem.d_offset = _offsets(problem)
    if start is not None:
        carry_ap_columns(problem, block.observations.row[problem.obs_order],
                         start.problem, start.block.observations.row[start.problem.obs_order])
    state, notes = initial_state(problem, block, start)
    names = problem.theta_names(block.images.image_id)
    solver_options = options.solver
    if block.datum == "free" and not solver_options.free_network:
        solver_options = replace(solver_options, free_network=True)
    try:
        outcome = solve(problem, state, names, solver_options, progress)
        lin = outcome.linearisation
        dense = problem.n_theta <= DENSE_LIMIT
        if outcome.reduction is not None:
            S, factor, v_inv = outcome.reduction
        else:
            S, _, v_inv = reduce(problem, lin, 0.0, dense)
            factor = None
    except SingularPoints as exc:
        ids = ", ".join(f"'{block.points.point_id[i]}'" for i in exc.indices[:5])
        raise AdjustmentError(f"{exc} (e.g. {ids}): remove them or check their observations") from None
    if solver_options.free_network:
        Q = _free_network_cofactor(S, notes)
    else:
        try:
            factor = factor or factorise(S)
        except SingularSystem as exc:
            directions = null_directions(S, names)
            raise AdjustmentError(f"the normal equations are singular at the solution ({exc}):\n  "
                                  + "\n  ".join(directions)) from None
        Q = factor.inverse()
    Q_points = point_cofactors(problem, lin, v_inv, Q)
    n_obs, n_unk = problem.n_observations(), problem.n_unknowns()
    if n_obs <= n_unk:
        raise AdjustmentError(f"no redundancy: {n_obs} observations for {n_unk} unknowns")
    variance_factor = 2.0 * outcome.cost / (n_obs - n_unk)
    v_sorted = -image_residuals(problem, outcome.state)
    residuals = np.empty_like(v_sorted)
    residuals[problem.obs_order] = v_sorted
    return AdjustmentResult(
        problem=problem,
        state=outcome.state,
        block=block,
        converged=outcome.converged,
        reason=outcome.reason,
        iterations=outcome.iterations,
        history=outcome.history,
        cost=outcome.cost,
        n_observations=n_obs,
        n_unknowns=n_unk,
        variance_factor=variance_factor,
        image_sigma_px=block.image_sigma_px,
        theta_names=names,
        Q_theta=Q,
        Q_points=Q_points,
        residuals_mm=residuals,
        notes=notes,
        seconds=time.perf_counter() - t0,
        linearisation=lin,
        v_inv=v_inv,
    )
