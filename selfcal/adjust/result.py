"""The result of an adjustment: the estimate, its precision and how it was reached, as one object that the
statistics, the reports and the workflows read (:class:`AdjustmentResult`)."""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from enum import Enum

import numpy as np

from ..block import Block
from .linalg import blas_threads
from .point_side import PointSide
from .problem import Problem, State
from .robust import RobustWeighting
from .schur import Linearisation
from .solver import IterationRecord

__all__ = ["AdjustmentResult", "Termination"]


class Termination(str, Enum):
    """How an adjustment ended (``AdjustmentResult.termination``)."""

    CONVERGED = "converged"             # the tolerances met
    ITERATION_LIMIT = "iteration limit"  # no convergence within the iterations allowed
    DIVERGED = "diverged"               # no step lowered the cost
    COLLAPSED = "collapsed"             # converged to an absurd solution (selfcal.stats.plausibility)


@dataclass
class AdjustmentResult:
    """The estimate, its precision and how it was reached.

    Precision is a-posteriori: covariance = variance_factor · cofactor.
    Residuals follow l + v = f(x): v = adjusted - observed, in the observation units of each
    image's sensor (:attr:`residuals_px` in pixels).
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
    Q_theta: np.ndarray            # or a BandedCofactor beyond DENSE_LIMIT (Factor.cofactor): index it, .diagonal()
    residuals: np.ndarray          # (m, 2) image residuals in ``block``'s observation order, observation units
    notes: list[str]
    seconds: float
    linearisation: Linearisation = field(repr=False)   # the last (its points' part: ``points.gathered``)
    points: PointSide = field(repr=False)              # the points' side, with the last reduction's inverses
    point_cofactor_blocks: np.ndarray | None = field(repr=False, default=None)   # Q_points once computed
    reduced_matrix: np.ndarray | None = field(repr=False, default=None)   # S of the last linearisation (dense, small)
    datum_null: np.ndarray | None = field(repr=False, default=None)       # a free network's datum directions
    robust: RobustWeighting | None = field(repr=False, default=None)      # the robust weights, where robust

    @property
    def Q_points(self) -> np.ndarray:
        """Cofactor blocks of the object points, (n_points, 3, 3), computed on first use: the rounds of a tested
        workflow get them from the observation tests, whose pass over the points shares their products."""
        if self.point_cofactor_blocks is None:
            with blas_threads(self.problem.n_images):
                self.point_cofactor_blocks = self.points.point_cofactors(self.Q_theta)
        return self.point_cofactor_blocks

    def some_point_cofactors(self, points: np.ndarray) -> np.ndarray:
        """The cofactor blocks (len(points), 3, 3) of the points ``points`` (indices among ``block``'s) alone."""
        if self.point_cofactor_blocks is not None:
            return self.point_cofactor_blocks[np.asarray(points, np.int64)]
        return self.points.some_point_cofactors(self.Q_theta, np.asarray(points, np.int64))

    def point_linearisation(self) -> tuple[Linearisation, list]:
        """The last linearisation with its points' part (its chunks) and the point inverses of its undamped reduced
        system, in this process: where the points are on a Dask cluster's workers, brought here."""
        lin, v_inv = self.points.gathered(self.linearisation)
        assert v_inv is not None                # (the result's reduction is undamped and kept by its side)
        return lin, v_inv

    @property
    def redundancy(self) -> int:
        return self.n_observations - self.n_unknowns

    @property
    def sigma0_px(self) -> float:
        """A-posteriori sigma of an image coordinate of unit weight, pixels."""
        return self.image_sigma_px * float(np.sqrt(self.variance_factor))

    @property
    def residuals_px(self) -> np.ndarray:
        """Image residuals (m, 2) in pixels along the photo axes (x right, y up), ``block``'s order."""
        problem = self.problem
        out = np.empty_like(self.residuals)
        v = self.residuals[problem.obs_order]               # sorted order
        for slot in problem.sensors:
            col_row = slot.bound.pixel_residuals(slot.observations, v[slot.observations])
            out[problem.obs_order[slot.observations]] = np.column_stack([col_row[:, 0], -col_row[:, 1]])
        return out

    def image_sigma(self) -> np.ndarray:
        """A-posteriori standard deviations of the image parameters, (n_images, width) in code units
        (a frame image's X0, Y0, Z0 in m, omega, phi, kappa in rad); NaN where held."""
        n_e = self.problem.n_e
        s = np.sqrt(self.variance_factor * self.Q_theta.diagonal()[:n_e]).reshape(self.problem.n_images, -1)
        return np.where(self.problem.image_free, s, np.nan)

    def camera_sigma(self) -> list[np.ndarray]:
        """A-posteriori standard deviations of each camera's parameters (NaN where fixed)."""
        out = []
        diag = self.Q_theta.diagonal()
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
        img_lookup = {i: k for k, i in enumerate(self.block.images.image_id)}
        pt_lookup = {p: k for k, p in enumerate(self.block.points.point_id)}
        img = np.array([img_lookup.get(i, -1) for i in image_ids], dtype=np.int64)
        pt = np.array([pt_lookup.get(p, -1) for p in point_ids], dtype=np.int64)
        out = np.full((len(img), 2), np.nan)
        ok = (img >= 0) & (pt >= 0)
        problem = self.problem
        image_slot = np.zeros(problem.n_images, np.int64)
        for s, slot in enumerate(problem.sensors):
            image_slot[slot.images] = s
        for s, slot in enumerate(problem.sensors):
            sel = np.flatnonzero(ok & (image_slot[np.maximum(img, 0)] == s))
            if sel.size:
                context = slot.bound.context(self.state, False)
                out[sel] = slot.bound.pixels(context, img[sel], self.state.points[pt[sel]])
        return out

    def image_leverages(self) -> tuple[np.ndarray, np.ndarray]:
        """The leverage h = j Q jᵀ (m, 2) and the whitened residual v = f - l (m, 2) of every image coordinate, in
        ``block``'s observation order (the redundancy number is 1 - h; :mod:`.leverage`). The points' cofactor
        blocks come out of the same pass and are kept (:attr:`Q_points`)."""
        problem = self.problem
        with blas_threads(problem.n_images):
            h, r, Qp = self.points.image_leverages(self.state, self.Q_theta, self.point_cofactor_blocks)
        self.point_cofactor_blocks = Qp
        h_block, v_block = np.empty_like(h), np.empty_like(r)
        h_block[problem.obs_order] = h
        v_block[problem.obs_order] = -r
        return h_block, v_block

    def control_leverages(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The control points (indices among ``block``'s points), the leverage (n, 3) and the whitened residual
        v = f - l (n, 3) of their surveyed coordinates."""
        control = self.problem.control
        r, J = control.rows(self.state.points[control.index])
        h = np.einsum("nij,njk,nik->ni", J, self.Q_points[control.index], J)        # diag(J Q_pp J^T)
        return control.index, h, -r

    def terrain_leverages(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The tie points with a terrain height (indices among ``block``'s points), the leverage (n,) and the
        whitened residual v = f - l (n,) of their terrain observations (empty without them)."""
        terrain = self.problem.terrain
        if terrain is None or not len(terrain):
            return np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
        r, J = terrain.rows(self.state.points[terrain.index])
        h = np.einsum("nij,njk,nik->ni", J, self.Q_points[terrain.index], J)
        return terrain.index, h[:, 0], -r[:, 0]

    def parameter_observations(self):
        """The whitened Jacobian (k, n_theta, sparse) and residuals l - f of the observations of parameters alone
        (priors, GNSS/IMU with their shift and drift), and the group of each row."""
        from .residuals import parameter_observation_groups, parameter_observations
        J, r = parameter_observations(self.problem, self.state)
        return J, r, parameter_observation_groups(self.problem)

    def parameter_leverages(self) -> tuple[np.ndarray, np.ndarray]:
        """The leverage (k,) and the whitened residual v = f - l (k,) of every parameter observation."""
        from .leverage import parameter_leverages
        J, r, _ = self.parameter_observations()
        h = parameter_leverages(J.tocsr(), self.Q_theta) if J.shape[0] else np.zeros(0)
        return h, -r

    def parameters(self):
        """Every parameter by name with its value and a-posteriori sigma (:class:`~.parameters.ParameterTable`)."""
        from .parameters import parameter_table
        sigma = np.sqrt(self.variance_factor * np.maximum(self.Q_theta.diagonal(), 0.0))
        return parameter_table(self.problem, self.state, sigma)

    def covariance(self, names: list[str]) -> np.ndarray:
        """The a-posteriori covariance (k, k) of the estimated parameters ``names`` ("owner: name" as
        :meth:`ParameterTable.labels` gives them), in code units; a name that is held or unknown is a KeyError."""
        table = self.parameters()
        where = {label: k for k, label in enumerate(table.labels())}
        columns = []
        for name in names:
            k = where[name]
            if not table.free[k] or table.index[k] < 0:
                raise KeyError(f"{name} is not estimated")
            columns.append(int(table.index[k]))
        index = np.array(columns, np.int64)
        return self.variance_factor * np.asarray(self.Q_theta[index[:, None], index[None, :]])

    @property
    def termination(self) -> Termination:
        if self.converged:
            return Termination.CONVERGED
        if self.reason.startswith("the adjustment collapsed"):
            return Termination.COLLAPSED
        if self.reason.startswith("diverged"):
            return Termination.DIVERGED
        return Termination.ITERATION_LIMIT

    def take_back_ap_columns(self, readjusted: "AdjustmentResult") -> None:
        """Take back the kept AP columns (:mod:`.ap_columns`) that ``readjusted``, an adjustment started from this
        one (``adjust(..., start=self)``), carried away, where it kept every observation of this one (a control
        point left out of the control, a parameter held): the next re-adjustment from this one carries them again
        instead of evaluating the basis afresh (a WAP basis: 0.4 s and 221 MiB on the paper's block, each time).
        ``readjusted`` evaluates its columns afresh if it is linearised again. Where it kept fewer observations,
        nothing is taken."""
        from .ap_columns import carry_ap_columns
        carry_ap_columns(self.problem, self.block.observations.row[self.problem.obs_order], readjusted.problem,
                         readjusted.block.observations.row[readjusted.problem.obs_order], consume=True)

    def readjust(self, options, without_rows=(), hold=(), progress=None) -> "AdjustmentResult":
        """This adjustment again, from its estimate, without the observations ``without_rows`` (their
        ``Observations.row``) and with the parameters ``hold`` ("owner: name" labels of :meth:`parameters`) held at
        their reference values; ``options``: its :class:`~selfcal.adjust.AdjustOptions`. The AP basis stays; a
        point left with one ray and an image with too few points go (:func:`selfcal.block.prune`)."""
        from ..block import prune
        from ..sensors import sensor_of
        from .engine import adjust
        table = self.parameters()
        free: dict = {}
        for k in np.flatnonzero(table.screenable | (table.kind == "image")):
            key = table.key[k]
            if key not in free:
                free[key] = np.array([table.free[j] for j in range(len(table)) if table.key[j] == key], bool)
        labels = table.labels()
        for name in hold:
            k = labels.index(name)
            if table.key[k] not in free:
                raise KeyError(f"{name} cannot be held (its sensor does not screen it)")
            free[table.key[k]][int(table.position[k])] = False
        obs = self.block.observations
        keep = np.flatnonzero(~np.isin(obs.row, np.asarray(without_rows, np.int64)))
        need = min((sensor_of(c).min_points_per_image for c in self.block.cameras.values()), default=6)
        block = prune(replace(self.block, observations=obs.take(keep)), min_points_per_image=need)
        return adjust(block, options, progress=progress, start=self, free=free,
                      ap_models={cam.camera_id: cam.ap for cam in self.problem.cameras})

    def point_covariance(self) -> np.ndarray:
        """A-posteriori covariance of every object point, (n_points, 3, 3) in m^2."""
        return self.variance_factor * self.Q_points

