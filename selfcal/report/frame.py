"""The positions, attitudes and precision the results folder writes, in the block's CRS.

A block in a projected CRS is adjusted in its local tangent plane (:func:`selfcal.workflows.frames.
tangent_plane_block`); what the files give is turned back into the CRS here, once, from the adjustment in the
plane (:class:`ResultView`). For any other block the view holds the adjustment's own numbers.

What "in the CRS" means:

* a position is the CRS's coordinates (easting, northing, height) of the adjusted point;
* a difference (a check point's error d = adjusted - reference, a GCP's residual, a GNSS shift or drift) is the
  difference of CRS coordinates, so in the grid's metres (k times the ground's: 4e-4 more at the edge of a UTM
  zone, 4e-4 less on its central meridian), as a block adjusted in the projection gave it;
* a sigma is that of the CRS coordinate: the covariance C in the plane turned by the Jacobian J of the CRS's
  coordinates at the point, J C J^T. J is k times the rotation by the meridian convergence gamma about the
  vertical (and the tilt of the local vertical against the plane's up, 1.6e-4 rad per km from the origin), so
  sigma_X is the standard deviation along grid east, not true east: with sigma_E != sigma_N in the plane, the
  grid's sigmas mix them by gamma (cos^2 gamma sigma_E^2 + sin^2 gamma sigma_N^2), and the grid's axes carry a
  correlation the plane's did not have;
* an attitude (omega, phi, kappa; the IMU's shifts and drifts) is against the CRS's axes at the camera (grid
  east, grid north, the ellipsoid normal: the rotation part of J), its sigma turned by the derivatives of those
  angles with respect to the plane's.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.tangent import TangentPlane
from ..stats.checks import CheckPoints

__all__ = ["ResultView", "trajectory_in_crs", "FRAME_IMAGE_PARAMETERS"]

#: the image parameters whose values are a pose (a frame camera's): the first three a position, the others angles
FRAME_IMAGE_PARAMETERS = ("X0", "Y0", "Z0", "omega", "phi", "kappa")


@dataclass
class ResultView:
    """An adjustment's object points and image parameters as the results folder gives them (module docstring)."""

    crs: str
    plane: TangentPlane | None
    points: np.ndarray              # (n, 3) adjusted object points
    point_covariance: np.ndarray    # (n, 3, 3) m^2, a-posteriori
    reference: np.ndarray           # (n, 3) the block's coordinates of each point (control, check, tie start)
    image: np.ndarray               # (n_images, width) image parameters, code units
    image_sigma: np.ndarray         # (n_images, width) a-posteriori sigma, NaN where held
    given_positions: np.ndarray     # (n_images, 3) the images' positions as the block gives them

    @classmethod
    def of(cls, result, plane: TangentPlane | None = None, crs: str | None = None) -> "ResultView":
        """The view of ``result``: in the CRS of ``plane`` where it was adjusted in one, else its own."""
        block = result.block
        view = cls(crs or block.crs, plane, result.state.points, result.point_covariance(), block.points.xyz_m,
                   result.state.image, result.image_sigma(), block.images.position_m)
        if plane is None:
            return view
        view.crs = plane.crs
        J = plane.jacobian(view.points)
        view.points, view.point_covariance = plane.to_crs(view.points), TangentPlane.covariances(J, view.point_covariance)
        view.reference = plane.to_crs(view.reference)
        view.given_positions = plane.to_crs(view.given_positions)
        if _is_pose(result):
            view.image, view.image_sigma = _poses_in_crs(result, plane)
        return view

    def poses(self, values: np.ndarray) -> np.ndarray:
        """Frame image parameters (n, 6) of the plane in the CRS (start values, for parameters.csv)."""
        if self.plane is None:
            return values
        return _pose_values(self.plane, values)[0]

    def checks(self, checks: CheckPoints) -> CheckPoints:
        """Check points of the adjustment in the CRS: reference and estimate in its coordinates, the errors
        along them."""
        if self.plane is None or not len(checks):
            return checks
        return CheckPoints(checks.point_id, checks.role, self.plane.to_crs(checks.reference),
                           self.plane.to_crs(checks.estimate), checks.method, np.eye(3))

    def check_sigmas(self, checks: CheckPoints, point_ids: np.ndarray) -> np.ndarray | None:
        """The a-posteriori sigmas (n, 3) of intersected check points along the CRS's coordinates (``point_ids``:
        the adjustment's points, in the order of :attr:`points`); None for restituted ones."""
        if checks.method != "intersection" or not len(checks):
            return None
        row = {pid: k for k, pid in enumerate(point_ids)}
        covariance = self.point_covariance[[row[pid] for pid in checks.point_id]]
        return np.sqrt(np.einsum("ij,njk,ik->ni", checks.axes, covariance, checks.axes))


def _is_pose(result) -> bool:
    sensors = result.problem.sensors
    return bool(sensors) and all(tuple(p.name for p in slot.sensor.image_parameters) == FRAME_IMAGE_PARAMETERS
                                 for slot in sensors)


def _pose_values(plane: TangentPlane, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Poses (n, 6) of the plane in the CRS, and the Jacobian (n, 6, 6) of the CRS's values by the plane's."""
    position, angles = values[:, :3], values[:, 3:]
    J = plane.jacobian(position)
    R = plane.axes(position, J)
    out = np.column_stack([plane.to_crs(position), plane.attitudes_to_crs(angles, R)])
    T = np.zeros((len(values), 6, 6))
    T[:, :3, :3] = J
    T[:, 3:, 3:] = TangentPlane.attitude_jacobian(angles, np.swapaxes(R, -1, -2))
    return out, T


def _poses_in_crs(result, plane: TangentPlane) -> tuple[np.ndarray, np.ndarray]:
    """The images' adjusted poses in the CRS and their sigmas (T C T^T per image, C from the cofactors)."""
    problem = result.problem
    values, T = _pose_values(plane, result.state.image)
    index = problem.image_theta()
    C = result.variance_factor * np.asarray(result.Q_theta[index[:, :, None], index[:, None, :]], float)
    free = problem.image_free
    C = np.where(free[:, :, None] & free[:, None, :], C, 0.0)      # held: no variance, no coupling
    sigma = np.sqrt(np.einsum("nii->ni", TangentPlane.covariances(T, C)))
    return values, np.where(free, sigma, np.nan)


def trajectory_in_crs(result, plane: TangentPlane | None) -> tuple[np.ndarray, np.ndarray]:
    """The trajectory terms' values (code units, the order of ``state.extra``) and a-posteriori sigmas (NaN where
    held). With ``plane``, each strip's shift and drift vectors are turned into the CRS's axes at the strip's
    middle observation: GNSS terms by the Jacobian of the CRS's coordinates there, IMU terms by the derivatives
    of the angles against the CRS's axes with respect to the plane's, at the observed angles (the convergence
    changes by 3e-5 rad per km across a block); the mounting terms are in the camera's and the IMU's axes and
    stay."""
    problem, state = result.problem, result.state
    values = np.array(state.extra, float)
    column = np.full(len(values), -1, np.int64)
    free_col, full = problem.n_e + problem.n_d, 0
    for t in problem.trajectory:
        active = np.flatnonzero(t.free)
        column[full + active] = free_col + np.arange(active.size)
        free_col += active.size
        full += t.n_params
    held = column < 0
    sigma = np.full(len(values), np.nan)
    if (~held).any():
        sigma[~held] = np.sqrt(result.variance_factor * np.asarray(result.Q_theta[column[~held], column[~held]]))
    if plane is None:
        return values, sigma
    full = 0
    for t in problem.trajectory:
        width = t.order + 1 if t.order >= 0 else 0
        for s in range(len(t.strips) if width else 0):
            rows = np.flatnonzero(t.strip_of == s)
            middle = rows[len(rows) // 2]
            if t.offset == 0:
                T = plane.jacobian(t.observed[middle][None])[0]
            else:
                R = plane.axes(state.image[t.index[middle], :3][None])
                T = TangentPlane.attitude_jacobian(t.observed[middle][None], np.swapaxes(R, -1, -2))[0]
            for k in range(width):
                idx = full + (s * width + k) * 3 + np.arange(3)
                cols, free = column[idx], column[idx] >= 0
                C = np.zeros((3, 3))
                C[np.ix_(free, free)] = result.variance_factor * np.asarray(
                    result.Q_theta[cols[free][:, None], cols[free][None, :]], float)
                values[idx] = T @ values[idx]
                sigma[idx] = np.where(free, np.sqrt(np.diag(T @ C @ T.T)), np.nan)
        full += t.n_params
    return values, sigma
