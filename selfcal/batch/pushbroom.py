"""The pushbroom study of seed 001: models M1-M7 x {3, 4, 5} GCPs x {mono F, N, B; stereo F+N, F+N+B}.

As in the paper, the focal length of each camera is calibrated first (M7 on the stereo
triplet with the largest GCP set) and then held for every model; the models differ in
which attitude corrections they estimate. Check points are every point that is not a
GCP: in mono they are restituted on the terrain from their image coordinates in the one
image, in stereo they are tie points of the adjustment. Errors are given across track
(X), along track (Y) and up (Z) at the scene centre of the nadir image.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..adjust.pushbroom import (M6_SIGMA, SENSOR_MODELS, PushbroomResult, SensorModel, adjust_pushbroom, sensor_model,
                                track_frame)
from ..errors import AdjustmentError
from ..sensors.pushbroom import PARAMETER_NAMES, LineImage, image_to_ground, intersect

__all__ = ["GCP_LAYOUTS", "IMAGE_SETS", "PushbroomCase", "choose_gcps", "calibrate_focal", "run_case", "run_study",
           "ATTITUDE_FREE_SIGMA"]

#: where the GCPs are, as (row, col) fractions of the nadir image: spread over the scene
GCP_LAYOUTS = {
    3: ((0.1, 0.1), (0.1, 0.9), (0.9, 0.5)),
    4: ((0.1, 0.1), (0.1, 0.9), (0.9, 0.1), (0.9, 0.9)),
    5: ((0.1, 0.1), (0.1, 0.9), (0.9, 0.1), (0.9, 0.9), (0.5, 0.5)),
}
#: image sets of the study (indices into the simulation's F, N, B)
IMAGE_SETS = {"F": (0,), "N": (1,), "B": (2,), "F+N": (0, 1), "F+N+B": (0, 1, 2)}
#: M6 without the given attitude (seed 001, Table 5): the constant terms are free to take the whole
#: attitude (loose weights), the linear terms keep M6's weights
ATTITUDE_FREE_SIGMA = {**M6_SIGMA, "d_roll0": 1e-2, "d_pitch0": 1e-2, "d_yaw0": 1e-2}


@dataclass
class PushbroomCase:
    model: str
    n_gcp: int
    images: str
    rmse_m: np.ndarray | None        # (3,) across, along, up; None when the adjustment failed
    n_check: int
    sigma0: float
    result: PushbroomResult | None
    failure: str = ""


def choose_gcps(obs_image: np.ndarray, obs_point: np.ndarray, obs_row: np.ndarray, obs_col: np.ndarray,
                nadir: LineImage, n: int) -> np.ndarray:
    """The points nearest to the layout of ``n`` GCPs (:data:`GCP_LAYOUTS`) in the nadir image."""
    mine = obs_image == 1
    rows, cols, points = obs_row[mine] / nadir.rows, obs_col[mine] / nadir.camera.columns, obs_point[mine]
    chosen: list[int] = []
    for r, c in GCP_LAYOUTS[n]:
        for k in np.argsort((rows - r) ** 2 + (cols - c) ** 2):
            if points[k] not in chosen:
                chosen.append(int(points[k]))
                break
    return np.array(chosen)


def _observations(sim, image_set, points=None):
    keep = np.isin(sim.obs_image, image_set)
    if points is not None:
        keep &= np.isin(sim.obs_point, points)
    return sim.obs_image[keep], sim.obs_point[keep], sim.obs_row[keep], sim.obs_col[keep]


def _start_points(images, sim, gcps, control_xyz):
    """GCPs at their surveyed coordinates, the other points intersected from the images."""
    start = np.zeros((len(sim.point_ids), 3))
    for p in range(len(sim.point_ids)):
        sel = sim.obs_point == p
        start[p], _ = intersect(images, sim.obs_image[sel], sim.obs_row[sel], sim.obs_col[sel])
    start[gcps] = control_xyz
    return start


def run_case(sim, images: list[LineImage], model: SensorModel, gcps: np.ndarray, image_set: tuple[int, ...],
             control_xyz: np.ndarray, control_sigma_m: float, label: str = "") -> PushbroomCase:
    """One adjustment of the study and its check-point errors against the simulation's truth."""
    truth = sim.truth.points_ecef
    checks = np.setdiff1d(np.arange(len(sim.point_ids)), gcps)
    mono = len(image_set) == 1
    cov = np.broadcast_to(np.eye(3) * control_sigma_m ** 2, (len(gcps), 3, 3))
    obs = _observations(sim, image_set, gcps if mono else None)
    start = _start_points(images, sim, gcps, control_xyz)
    try:
        result = adjust_pushbroom(images, *obs, start, gcps, control_xyz, cov, model, sim.image_sigma_px)
    except AdjustmentError as exc:
        return PushbroomCase(model.name, len(gcps), label, None, checks.size, np.nan, None, str(exc))
    if not result.converged:
        return PushbroomCase(model.name, len(gcps), label, None, checks.size, result.sigma0, result,
                             f"no convergence in {result.iterations} iterations")
    _, R = track_frame(images[1])
    if mono:
        i = image_set[0]
        sel = (sim.obs_image == i) & np.isin(sim.obs_point, checks)
        restituted = image_to_ground(result.images[i], sim.obs_row[sel], sim.obs_col[sel], sim.dem)
        errors = (restituted - truth[sim.obs_point[sel]]) @ R.T
    else:
        errors = (result.points_ecef[checks] - truth[checks]) @ R.T
    rmse = np.sqrt(np.mean(errors ** 2, axis=0))
    return PushbroomCase(model.name, len(gcps), label, rmse, len(errors), result.sigma0, result)


def calibrate_focal(sim, images: list[LineImage], gcps: np.ndarray, control_xyz: np.ndarray,
                    control_sigma_m: float) -> tuple[dict[str, float], dict[str, float]]:
    """Step 1 of seed 001: each camera's focal length (mm) and its sigma from M7 on the triplet."""
    case = run_case(sim, images, sensor_model("M7"), gcps, (0, 1, 2), control_xyz, control_sigma_m, "F+N+B")
    if case.result is None:
        raise AdjustmentError(f"focal-length calibration failed: {case.failure}")
    values, sigmas = {}, {}
    for name, value, sigma in zip(case.result.parameter_names, case.result.parameter_values,
                                  case.result.parameter_sigma):
        image_id, parameter = name.split(".", 1)
        if parameter == "focal":
            values[image_id], sigmas[image_id] = float(value), float(sigma)
    return values, sigmas


def with_focal(images: list[LineImage], focal_mm: dict[str, float]) -> list[LineImage]:
    out = []
    for image in images:
        parameters = image.parameters.copy()
        parameters[PARAMETER_NAMES.index("focal")] = focal_mm[image.image_id]
        out.append(image.with_parameters(parameters))
    return out


def run_study(sim, models=tuple(SENSOR_MODELS), gcp_counts=(3, 4, 5), image_sets=tuple(IMAGE_SETS),
              control_sigma_m: float = 0.1, seed: int = 0, given_attitude: bool = True,
              prior_sigma: dict | None = None) -> tuple[list[PushbroomCase], dict, dict]:
    """The whole matrix. GCP coordinates are the truth plus noise of ``control_sigma_m``.
    Returns the cases and the calibrated focal lengths with their sigma."""
    rng = np.random.default_rng(seed)
    control_all = sim.truth.points_ecef + rng.normal(0.0, control_sigma_m, sim.truth.points_ecef.shape)
    images = sim.images(given_attitude=given_attitude)
    largest = max(gcp_counts)
    gcps = choose_gcps(sim.obs_image, sim.obs_point, sim.obs_row, sim.obs_col, images[1], largest)
    focal, focal_sigma = calibrate_focal(sim, images, gcps, control_all[gcps], control_sigma_m)
    images = with_focal(images, focal)
    cases = []
    for label in image_sets:
        for name in models:
            model = sensor_model(name, prior_sigma if name == "M6" else None)
            for n in gcp_counts:
                gcps = choose_gcps(sim.obs_image, sim.obs_point, sim.obs_row, sim.obs_col, images[1], n)
                cases.append(run_case(sim, images, model, gcps, IMAGE_SETS[label], control_all[gcps],
                                      control_sigma_m, label))
    return cases, focal, focal_sigma
