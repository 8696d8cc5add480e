"""The uncertainty of a calibrated camera's projection, defined as mrcal defines it (``mrcal.projection_uncertainty``,
mrcal 2.2: "uncertainty.html" of its documentation), for a like-for-like comparison with mrcal.

A point p fixed in the camera's frame (OpenCV's axes: x right, y down, z forward; metres) is projected by the
estimated interior orientation. The camera frame itself is only known through the images' orientations: mrcal
writes p in the frame of each of the N images (boards) it was calibrated from, X_i = T_i^-1(p) with T_i the
estimated camera-from-object transform of image i, and asks where the perturbed estimate puts it back:
p' = mean_i T_i'(X_i), q' = project(p', intrinsics'). To first order

    dq = J_core d(core) + sum_i (1/N) J_image,i d(image_i)        (J_image,i = dq/dp dT_i(X_i)/d(image_i))

and Cov(q) = J Sigma_theta J^T with Sigma_theta the covariance of the camera's core parameters, its additional
parameters and all its images' orientations together (their block of the inverse normal matrix: the object
points, here the board's corners, eliminated). :func:`projection_covariance` gives it from an adjustment, with the
a-posteriori variance factor or a stated one (mrcal's ``observed_pixel_uncertainty``: pass
``variance_factor = 1`` for the a-priori sigma of the observations).

Unlike distortion_sigma.csv (the σ of the APs' correction alone: :mod:`.field_sigma`), this σ includes the
interior orientation's core (c, x0, y0; fx, fy, cx, cy) and the images' orientations; it depends on the distance
of p (the translations of the images enter through it).
"""
from __future__ import annotations

import numpy as np

from ..geometry.rotation import matrix_from_opk
from ..sensors.frame import EOP_NAMES

__all__ = ["projection_covariance", "camera_points"]


def camera_points(normalised: np.ndarray, distance_m: float) -> np.ndarray:
    """Points (m, 3) of the camera frame (OpenCV's axes) at ``distance_m`` from the centre along the rays of
    normalised coordinates (m, 2) (x / z, y / z)."""
    n = np.atleast_2d(np.asarray(normalised, float))
    v = np.column_stack([n, np.ones(len(n))])
    return distance_m * v / np.linalg.norm(v, axis=1, keepdims=True)


def projection_covariance(result, camera_id: str, points_m: np.ndarray, variance_factor: float | None = None
                          ) -> np.ndarray:
    """Covariance (m, 2, 2), px² along (col, row), of the pixels of camera-frame points ``points_m`` (m, 3; OpenCV's
    axes) through camera ``camera_id`` of the adjustment ``result`` (module docstring). Sensors whose images are
    oriented by (X0, Y0, Z0, omega, phi, kappa): frame and OpenCV cameras. Needs the dense cofactor matrix (a
    block small enough to have it)."""
    problem, state = result.problem, result.state
    if not isinstance(result.Q_theta, np.ndarray):
        raise ValueError("the projection's uncertainty needs the dense cofactor matrix of the adjustment")
    k = problem.camera_ids.index(camera_id)
    images = np.flatnonzero(problem.image_camera == k)
    slot = next(s for s in problem.sensors if np.isin(images, s.images).all())
    if slot.sensor.image_names != EOP_NAMES:
        raise ValueError(f"{slot.sensor.name} images are not oriented by {', '.join(EOP_NAMES)}")
    p = np.atleast_2d(np.asarray(points_m, float))
    m = len(p)
    u = p * [1.0, -1.0, -1.0]                                  # photogrammetric camera axes (y up, looking along -z)
    context = slot.bound.context(state, True)
    o_camera = slot.observations[problem.image_camera[problem.obs_image[slot.observations]] == k]
    o_rep = np.full(m, o_camera[0])

    def pixels(values: np.ndarray) -> np.ndarray:
        """(m, 2, c) in observation units -> px along (col, row)."""
        return np.stack([slot.bound.pixel_residuals(o_rep, values[:, :, j]) for j in range(values.shape[2])], 2)

    n_theta = result.Q_theta.shape[0]
    J = np.zeros((m, 2, n_theta))
    theta = problem.image_theta()
    M = matrix_from_opk(state.image[images, 3:])
    cam = problem.cameras[k]
    j_core = predicted = None
    for i, Mi in zip(images, M):
        X = u @ Mi + state.image[i, :3]                         # M^T u + X0: the point in the object frame
        f, j_image, _, j_core = slot.bound.predict(context, o_rep, np.full(m, i), np.full(m, k), X, True)
        predicted = f
        columns = theta[i]
        used = columns >= 0
        J[:, :, columns[used]] += pixels(j_image[:, :, used]) / len(images)
    assert j_core is not None and predicted is not None
    position = problem.d_offset[k] + np.cumsum(cam.free) - 1
    core_free = np.flatnonzero(cam.free[:cam.n_core])
    J[:, :, position[core_free]] = pixels(j_core[:, :, core_free])
    ap_free = np.flatnonzero(cam.free[cam.n_core:])
    if ap_free.size:
        # the APs' correction at the predicted position (photo mm of a frame camera): its basis in observation units
        bx, by = cam.ap.basis(predicted[:, 0], predicted[:, 1])
        columns = np.stack([bx[:, ap_free], by[:, ap_free]], 1) * cam.pixel_size_mm
        J[:, :, position[cam.n_core + ap_free]] = pixels(columns)
    vf = result.variance_factor if variance_factor is None else float(variance_factor)
    return vf * np.einsum("mai,ij,mbj->mab", J, result.Q_theta, J)
