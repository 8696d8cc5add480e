"""The pushbroom study of seed 001: models M1-M7 x {3, 4, 5} GCPs x {mono F, N, B; stereo F+N, F+N+B}.

As in the paper, the focal length of each camera is calibrated first (M7 on all images
with every GCP of the block) and then held for every model; the models differ in which
attitude corrections they estimate. The GCPs of a case are chosen among the block's gcp
points, spread over the scene (:data:`GCP_LAYOUTS`); every other gcp and chk point is a
check point. In mono, check points are restituted on the terrain from their image
coordinates in the one image; in stereo they are tie points of the adjustment. Errors are
given across track (X), along track (Y) and up (Z) at the scene centre of the middle image.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..adjust.pushbroom import (M6_SIGMA, SENSOR_MODELS, PushbroomBlock, PushbroomResult, SensorModel,
                                adjust_pushbroom, sensor_model, track_frame)
from ..stats.pushbroom import ScreenedPushbroom, adjust_pushbroom_with_snooping, screen_pushbroom
from ..stats.screening import ScreeningOptions
from ..stats.snooping import SnoopingOptions
from ..errors import AdjustmentError, UsageError
from ..sensors.pushbroom import PARAMETER_NAMES, LineImage, image_to_ground, intersect

__all__ = ["GCP_LAYOUTS", "PushbroomCase", "choose_gcps", "calibrate_focal", "run_case", "run_study", "with_focal",
           "image_sets", "intersections", "ATTITUDE_FREE_SIGMA"]

#: where the GCPs of a case are, as (row, col) fractions of the middle image: spread over the scene
GCP_LAYOUTS = {
    3: ((0.1, 0.1), (0.1, 0.9), (0.9, 0.5)),
    4: ((0.1, 0.1), (0.1, 0.9), (0.9, 0.1), (0.9, 0.9)),
    5: ((0.1, 0.1), (0.1, 0.9), (0.9, 0.1), (0.9, 0.9), (0.5, 0.5)),
}
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
    gcps: np.ndarray
    checks: np.ndarray
    check_errors_m: np.ndarray | None = None     # (n, 3) across, along, up
    failure: str = ""
    observations: np.ndarray | None = None       # indices into the block's observations that were adjusted
    rejected: list | None = None                 # (index into the block's observations, |w|) of data snooping
    screening: ScreenedPushbroom | None = None   # the parameters dropped by screening, when it ran
    line_aps: dict | None = None                 # camera id -> LineWaveletAP estimated in the case


def image_sets(data: PushbroomBlock) -> dict[str, tuple[int, ...]]:
    """Mono for every image, stereo for the first two and for all (F+N, F+N+B for a triplet)."""
    ids = [img.image_id for img in data.images]
    sets = {i: (k,) for k, i in enumerate(ids)}
    if len(ids) >= 2:
        sets["+".join(ids[:2])] = (0, 1)
    if len(ids) >= 3:
        sets["+".join(ids)] = tuple(range(len(ids)))
    return sets


def choose_gcps(data: PushbroomBlock, n: int) -> np.ndarray:
    """``n`` of the block's gcp points, those nearest to the layout of :data:`GCP_LAYOUTS` in the
    middle image (all of them when ``n`` is None or the block has no more)."""
    candidates = np.flatnonzero(data.role == "gcp")
    if n is None or n >= candidates.size:
        return candidates
    if n not in GCP_LAYOUTS:
        raise UsageError(f"--gcps {n}: choose 3, 4 or 5 of the block's {candidates.size} gcp")
    middle = len(data.images) // 2
    image = data.images[middle]
    mine = (data.obs_image == middle) & np.isin(data.obs_point, candidates)
    rows, cols, points = data.obs_row[mine] / image.rows, data.obs_col[mine] / image.camera.columns, data.obs_point[mine]
    chosen: list[int] = []
    for r, c in GCP_LAYOUTS[n]:
        for k in np.argsort((rows - r) ** 2 + (cols - c) ** 2):
            if points[k] not in chosen:
                chosen.append(int(points[k]))
                break
    return np.array(chosen)


def intersections(data: PushbroomBlock, images: list[LineImage] | None = None) -> np.ndarray:
    """Every point seen in two images or more intersected from all its images (NaN for the others):
    the start values of the tie and check points, the same for every case of a study."""
    images = data.images if images is None else images
    out = np.full((len(data.point_ids), 3), np.nan)
    for p in range(len(data.point_ids)):
        sel = data.obs_point == p
        if np.unique(data.obs_image[sel]).size >= 2:
            out[p], _ = intersect(images, data.obs_image[sel], data.obs_row[sel], data.obs_col[sel])
    return out


def _start_points(data: PushbroomBlock, gcps: np.ndarray, intersected: np.ndarray) -> np.ndarray:
    """GCPs at their surveyed coordinates, every other point intersected from all its images."""
    start = data.reference_ecef.copy()
    others = np.setdiff1d(np.flatnonzero(~np.isnan(intersected[:, 0])), gcps)
    start[others] = intersected[others]
    return start


def run_case(data: PushbroomBlock, model: SensorModel, gcps: np.ndarray, image_set: tuple[int, ...], dem,
             label: str = "", images: list[LineImage] | None = None,
             snooping: SnoopingOptions | None = None, screening: ScreeningOptions | None = None,
             intersected: np.ndarray | None = None, line_aps: dict | None = None,
             line_ap_sigma_px: float | None = None) -> PushbroomCase:
    """One adjustment with ``gcps`` as control, on the images ``image_set``; check points are the other
    points with reference coordinates, restituted on ``dem`` (mono) or intersected (stereo). With
    ``snooping``, Baarda's data snooping rejects image points one at a time; with ``screening``, the
    calibration parameters are then screened on the image points kept (the result is the adjustment
    with the parameters that stay). ``intersected``: :func:`intersections` of ``images``, when the
    caller has them. ``line_aps``: camera id -> :class:`~selfcal.ap.line.LineWaveletAP` (1-D wavelet
    APs of the detector lines)."""
    images = data.images if images is None else images
    mono = len(image_set) == 1
    known = np.flatnonzero(~np.isnan(data.reference_ecef).any(axis=1))
    checks = np.setdiff1d(known, gcps)
    take = np.isin(data.obs_image, image_set)
    if mono:
        take &= np.isin(data.obs_point, gcps)
    else:
        seen = np.unique(data.obs_point[take], return_counts=True)
        checks = np.intersect1d(checks, seen[0][seen[1] >= 2])
    take = np.flatnonzero(take)
    intersected = intersections(data, images) if intersected is None else intersected
    start = _start_points(data, gcps, intersected)
    fail = dict(model=model.name, n_gcp=len(gcps), images=label, rmse_m=None, n_check=checks.size, gcps=gcps,
                checks=checks, line_aps=line_aps)
    try:
        snooped = adjust_pushbroom_with_snooping(
            images, data.obs_image[take], data.obs_point[take], data.obs_row[take], data.obs_col[take], start, gcps,
            data.reference_ecef[gcps], data.reference_cov[gcps], model, data.image_sigma_px, snooping, line_aps,
            line_ap_sigma_px)
    except AdjustmentError as exc:
        return PushbroomCase(sigma0=np.nan, result=None, failure=str(exc), **fail)
    result = snooped.result
    fail |= {"observations": take[snooped.kept], "rejected": [(int(take[k]), w) for k, w in snooped.rejected]}
    if screening is not None and not snooped.failure and result.converged:
        kept = fail["observations"]

        def adjust(models, ap_masks):
            return adjust_pushbroom(images, data.obs_image[kept], data.obs_point[kept], data.obs_row[kept],
                                    data.obs_col[kept], start, gcps, data.reference_ecef[gcps],
                                    data.reference_cov[gcps], models, data.image_sigma_px, line_aps=line_aps,
                                    line_ap_masks=ap_masks, line_ap_sigma_px=line_ap_sigma_px)

        try:
            screened = screen_pushbroom(adjust, [img.image_id for img in images], [img.parameters for img in images],
                                        [model] * len(images), screening, line_aps)
        except AdjustmentError as exc:
            return PushbroomCase(sigma0=result.sigma0, result=result, failure=f"screening: {exc}", **fail)
        result = screened.result
        fail["screening"] = screened
    if snooped.failure:
        return PushbroomCase(sigma0=result.sigma0, result=result, failure=snooped.failure, **fail)
    if not result.converged:
        return PushbroomCase(sigma0=result.sigma0, result=result,
                             failure=f"no convergence in {result.iterations} iterations", **fail)
    _, R = track_frame(images[len(images) // 2])
    if mono:
        i = image_set[0]
        sel = np.flatnonzero((data.obs_image == i) & np.isin(data.obs_point, checks))
        restituted = image_to_ground(result.images[i], data.obs_row[sel], data.obs_col[sel], dem)
        checks = data.obs_point[sel]
        errors = (restituted - data.reference_ecef[checks]) @ R.T
    else:
        errors = (result.points_ecef[checks] - data.reference_ecef[checks]) @ R.T
    rmse = np.sqrt(np.mean(errors ** 2, axis=0)) if len(errors) else None
    return PushbroomCase(model.name, len(gcps), label, rmse, len(errors), result.sigma0, result, gcps, checks,
                         errors, "", fail["observations"], fail["rejected"], fail.get("screening"), line_aps)


def calibrate_focal(data: PushbroomBlock, dem, gcps: np.ndarray | None = None
                    ) -> tuple[dict[str, float], dict[str, float]]:
    """Step 1 of seed 001: each camera's focal length (mm) and its sigma, from M7 on all images."""
    gcps = np.flatnonzero(data.role == "gcp") if gcps is None else gcps
    case = run_case(data, sensor_model("M7"), gcps, tuple(range(len(data.images))), dem, "all")
    if case.result is None or not case.result.converged:
        raise AdjustmentError(f"focal-length calibration (M7 on all images) failed: {case.failure}")
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


def run_study(data: PushbroomBlock, dem, models=tuple(SENSOR_MODELS), gcp_counts=(3, 4, 5), sets=None,
              prior_sigma: dict | None = None, calibrate: bool = True, progress=None,
              snooping: SnoopingOptions | None = None) -> tuple[list[PushbroomCase], dict, dict]:
    """The whole matrix. Returns the cases and the calibrated focal lengths with their sigma
    (empty when ``calibrate`` is False: the block's focal lengths are used)."""
    focal, focal_sigma = calibrate_focal(data, dem) if calibrate else ({}, {})
    images = with_focal(data.images, focal) if calibrate else data.images
    sets = image_sets(data) if sets is None else sets
    intersected = intersections(data, images)
    cases = []
    for label, image_set in sets.items():
        for name in models:
            model = sensor_model(name, prior_sigma if name == "M6" else None)
            for n in gcp_counts:
                case = run_case(data, model, choose_gcps(data, n), image_set, dem, label, images, snooping,
                                intersected=intersected)
                cases.append(case)
                if progress is not None:
                    progress(case)
    return cases, focal, focal_sigma
