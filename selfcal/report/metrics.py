"""What an adjustment achieved, as plain tables and a summary dictionary: one schema for every sensor.

These are the contents of the results folder (DESIGN.md §4). The functions
compute; :mod:`selfcal.io.results` writes. The common keys and columns are the
same whatever the sensor (``schema_version`` in summary.json); a sensor adds
files of its own (``distortion_grid.csv`` for frame APs, ``detector_line.csv``
for line APs, ``check_points.csv`` across / along / up for seed 001's cases).
Conventions:

* RMSD(XY) at check points = sqrt(mean(dX^2 + dY^2)), RMSD(Z) = sqrt(mean(dZ^2)),
  with d = adjusted - reference;
* RMS(sigma_XY) of tie points = sqrt(mean(sigma_X^2 + sigma_Y^2)), a-posteriori;
* GSD = mean over images of pixel_size · (Z0 - mean height of the image's points) / c;
* image residuals v = adjusted - observed, in pixels along the photo axes (x right, y up).
"""
from __future__ import annotations

import numpy as np

from .. import __version__
from ..block import Block, FrameCamera
from ..ap import frame_nodes_mm, takes_grid
from ..sensors.frame import pixel_from_photo
from ..stats.accuracy import ce90, le90
from ..stats.asprs import accuracy_statement
from ..stats.quality import quality_checks, worst_status
from ..stats.checks import CheckPoints, check_point_sigmas_m, intersected
from ..stats.correlation import max_abs_correlation_by_group
from .exchange import check_points_geojson, object_points_ply
from .frame import ResultView
from .sigma_map import distortion_sigma_summary, distortion_sigma_table

__all__ = ["SCHEMA_VERSION", "ground_sample_distance", "model_choice_table", "summary", "camera_json", "image_table",
           "point_table", "residual_table", "screening_json", "correlation_table", "distortion_grid_table",
           "trajectory_table", "parameter_table", "detector_line_table", "check_point_table", "control_loo_table",
           "distortion_sigma_table", "result_files"]

#: a CSV file of the results folder as data: header, columns (equal-length sequences), format of each column
#: (:func:`selfcal.io.table.write_table`)
CsvTable = tuple[list[str], list, list[str]]

#: version of the results schema (DESIGN.md §4); 2: one schema for every sensor (parameters.csv, sensors)
SCHEMA_VERSION = 2
#: detector_line.csv samples the estimated line APs every this many columns
DETECTOR_LINE_STEP = 16


def ground_sample_distance(block: Block, result) -> float | None:
    """Mean ground sample distance of the block in metres (None where the sensors do not say)."""
    values = [slot.bound.ground_sample_distance(result.state) for slot in result.problem.sensors]
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


def _rms(values: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(values))) if values.size else None


def datum(block, problem, n_gcp: int) -> tuple[str, str]:
    """What fixes the block in its object frame: ``control`` (control points), ``trajectory`` (GNSS/IMU
    observations of the images), ``free`` (a free network, precision in the minimum-trace datum) or ``a-priori``
    (no control: the images' given geometry, weighted by the a-priori sigmas of their parameters, e.g. an RPC
    block of tie points and ``sigma_bias_px``); and a sentence that says it with the numbers."""
    if block.datum == "free":
        return "free", "free network: no control; precision in the minimum-trace datum (relative)"
    telemetry = " and GNSS/IMU observations" if block.has_trajectory else ""
    if n_gcp:
        return "control", f"{n_gcp} control points{telemetry}"
    if block.has_trajectory:
        return "trajectory", "GNSS/IMU observations of the images (no control point)"
    names = sorted({name for slot in problem.sensors for name, k in
                    ((p.name, k) for k, p in enumerate(slot.sensor.image_parameters))
                    if np.any(np.isfinite(problem.image_prior_sigma[slot.images, k])
                              & problem.image_free[slot.images, k])})
    names += sorted({name for c in problem.cameras for name, free, sigma in
                     zip(c.names[:c.n_core], c.free[:c.n_core], c.prior_sigma[:c.n_core])
                     if free and np.isfinite(sigma)})
    weighted = f"weighted by the a-priori sigmas of {', '.join(names)}" if names else "held"
    return "a-priori", f"no control point: the images' given geometry, {weighted}"


def summary(tested, extra: dict | None = None, checks=None, view: ResultView | None = None) -> dict:
    """summary.json of DESIGN.md §4 for a (tested) adjustment. ``checks``: the check points
    (:mod:`selfcal.stats.checks`), by default those intersected in the adjustment. Errors and
    precision are along the object frame's axes, or east, north, up for ECEF; ``view``: the
    adjustment in the block's CRS (:class:`~selfcal.report.frame.ResultView`; a block adjusted in its
    tangent plane), where errors and precision are along the CRS's coordinates."""
    from ..stats.checks import intersected, local_axes
    result = tested.result
    block = result.block
    pts = block.points
    view = ResultView.of(result) if view is None else view
    checks = view.checks(intersected(result) if checks is None else checks)
    d_chk = checks.errors_m
    gcp = pts.role == "gcp"
    tie = pts.role == "tie"
    axes = np.eye(3) if view.plane is not None else \
        local_axes(pts.xyz_m[gcp] if gcp.any() else view.points, _object_frame(result), block.crs)
    d_gcp = (view.points[gcp] - view.reference[gcp]) @ axes.T
    cov = np.einsum("ij,njk,lk->nil", axes, view.point_covariance, axes)
    var = np.einsum("nii->ni", cov)
    gsd = ground_sample_distance(block, result)
    rmsd_xy = _rms(np.sum(d_chk[:, :2] ** 2, axis=1))
    rmsd_z = _rms(d_chk[:, 2] ** 2)
    extrapolated = distortion_extrapolation(result)
    sig_xy = _rms(var[tie, 0] + var[tie, 1])
    sig_z = _rms(var[tie, 2])
    v = result.residuals_px

    def gsd_of(x):
        return None if x is None or not gsd else x / gsd

    out = {
        "schema_version": SCHEMA_VERSION,
        "selfcal_version": __version__,
        "crs": view.crs,
        "sensors": sorted({cam.sensor for cam in result.problem.cameras}),
        "block": block.name,
        "ap_model": result.problem.cameras[0].ap.spec if result.problem.cameras else "none",
        "converged": bool(result.converged),
        "convergence": result.reason,
        "iterations": int(result.iterations),
        "sigma0_px": result.sigma0_px,
        "variance_factor": result.variance_factor,
        "redundancy": int(result.redundancy),
        "n_observations": int(result.n_observations),
        "n_unknowns": int(result.n_unknowns),
        "gsd_m": gsd,
        "rmsd_chk_xy_m": rmsd_xy,
        "rmsd_chk_z_m": rmsd_z,
        "rmsd_chk_xy_gsd": gsd_of(rmsd_xy),
        "rmsd_chk_z_gsd": gsd_of(rmsd_z),
        "ce90_chk_m": ce90(d_chk[:, :2]),
        "le90_chk_m": le90(d_chk[:, 2]),
        "accuracy": accuracy_statement(d_chk, survey_sigmas_m(checks, block)).as_dict(),
        "check_method": checks.method,
        "rms_gcp_residual_xy_m": _rms(np.sum(d_gcp[:, :2] ** 2, axis=1)),
        "rms_gcp_residual_z_m": _rms(d_gcp[:, 2] ** 2),
        "rms_sigma_tie_xy_m": sig_xy,
        "rms_sigma_tie_z_m": sig_z,
        "rms_sigma_tie_xy_gsd": gsd_of(sig_xy),
        "rms_sigma_tie_z_gsd": gsd_of(sig_z),
        "rms_image_residual_px": float(np.sqrt(np.mean(np.sum(v * v, axis=1)))),
        "n_images": int(len(block.images)),
        "n_tie_points": int(tie.sum()),
        "n_image_observations": int(len(block.observations)),
        "n_gcp_used": int(gcp.sum()),
        "datum": datum(block, result.problem, int(gcp.sum()))[0],
        "datum_detail": datum(block, result.problem, int(gcp.sum()))[1],
        "n_chk_used": int(len(checks)),
        "n_obs_rejected": int(len(tested.rejected_rows)),
        "robust": None if tested.cleaning is None else tested.cleaning.as_dict(),
        "control_demoted": [{"point_id": p, "w": w} for p, w in tested.control_demoted],
        "n_ap_initial": int(tested.n_ap_initial),
        "n_ap_significant": int(tested.n_ap_significant),
        "failure": tested.failure or None,
        "mean_redundancy_image": float(np.mean(tested.tests.image_redundancy)),
        "snooping": {"critical": tested.tests.critical, "delta0": tested.tests.delta0,
                     "rounds": [vars(r) for r in tested.rounds]},
        "max_abs_corr": max_abs_correlation_by_group(result.problem, result.Q_theta),
        "variance_components": None if tested.variance_components is None else {
            "converged": tested.variance_converged,
            "groups": [c.as_dict() for c in tested.variance_components]},
        "dropped": block.dropped.as_dict(),
        "distortion_extrapolation": [e.as_dict() for e in extrapolated],
        "warnings": list(block.dropped.messages) + [e.warning for e in extrapolated if e.warning],
        "notes": list(result.notes),
        "seconds": result.seconds,
        "diagnosis": diagnosis(tested, checks, view),
        "distortion_sigma": distortion_sigma_summary(result),
    }
    out["quality_check"] = quality_check(tested, d_gcp, pts.sigma_m[gcp], pts.point_id[gcp])
    if block.terrain_observations is not None:
        out["terrain_observations"] = terrain_summary(tested)
    if extra:
        out.update(extra)
    return out


def survey_sigmas_m(checks: CheckPoints, block: Block) -> np.ndarray:
    """The check points' own survey sigmas (n, 3), m, from the block's points (NaN where a point has none or is
    not in ``block``): along the axes their errors are given in (a block's X, Y, Z; east, north, up for ECEF, as
    the control weights read them)."""
    row = {pid: k for k, pid in enumerate(block.points.point_id)}
    out = np.full((len(checks), 3), np.nan)
    for i, pid in enumerate(checks.point_id):
        if pid in row:
            out[i] = block.points.sigma_m[row[pid]]
    return out


def quality_check(tested, d_gcp: np.ndarray, sigma_gcp: np.ndarray, gcp_ids: np.ndarray) -> dict:
    """summary.json ``quality_check`` (:mod:`selfcal.stats.quality`): the figures of the checks gathered from the
    adjustment, ``d_gcp`` the control residuals (n, 3) along the axes of their sigmas ``sigma_gcp``."""
    result = tested.result
    block = result.block
    obs = block.observations
    per_image = np.bincount(obs.image_index, minlength=len(block.images))
    per_point = np.bincount(obs.point_index, minlength=len(block.points))
    n_rejected = int(len(tested.rejected_rows))
    table = result.parameters()
    focal = np.flatnonzero((table.kind == "core") & (table.name == "c") & (table.start != 0))
    focal_change = None
    if focal.size:
        change = np.abs(table.value[focal] - table.start[focal]) / np.abs(table.start[focal])
        k = int(np.nanargmax(change))
        focal_change = (float(change[k]), f"camera {table.owner[focal[k]]}")
    weighted = np.isfinite(sigma_gcp) & (sigma_gcp > 0)
    gcp_ratio = None
    if weighted.any():
        ratio = np.where(weighted, np.abs(d_gcp) / np.where(weighted, sigma_gcp, 1.0), -1.0)
        i, a = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
        gcp_ratio = (float(ratio[i, a]), f"point {gcp_ids[i]}, axis {'XYZ'[a]}")
    checks = quality_checks(
        n_images=int(len(block.images) + block.dropped.images_too_few_points),
        n_images_oriented=int(np.count_nonzero(per_image)), points_per_image=per_image[per_image > 0],
        rays_per_point=per_point[block.points.role == "tie"], focal_change=focal_change,
        sigma0_ratio=float(np.sqrt(result.variance_factor)) if np.isfinite(result.variance_factor) else None,
        n_rejected=n_rejected, n_observations=int(len(obs)) + n_rejected, gcp_ratio=gcp_ratio,
        camera_correlation=_camera_correlation(result, table))
    return {"status": worst_status(checks), "checks": {c.key: c.as_dict() for c in checks}}


def _camera_correlation(result, table) -> tuple[float, str] | None:
    """The largest |rho| of an estimated camera parameter (core, AP) with any other estimated unknown, and the
    two names; None where no camera parameter is estimated."""
    free = table.free & (table.index >= 0)
    camera = np.flatnonzero(free & np.isin(table.kind, ("core", "ap")))
    if camera.size == 0:
        return None
    others = np.flatnonzero(free)
    rows, cols = table.index[camera].astype(np.int64), table.index[others].astype(np.int64)
    Q = result.Q_theta
    d = np.sqrt(np.maximum(Q.diagonal(), 0.0))
    block = np.asarray(Q[np.ix_(rows, cols)], float)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.abs(block / d[rows][:, None] / d[cols][None, :])
    rho[rows[:, None] == cols[None, :]] = 0.0
    rho = np.nan_to_num(rho, nan=0.0, posinf=0.0)
    i, j = np.unravel_index(int(np.argmax(rho)), rho.shape)
    labels = table.labels()
    return float(min(rho[i, j], 1.0)), f"{labels[camera[i]]} with {labels[others[j]]}"


def _object_frame(result) -> str:
    return result.problem.sensors[0].sensor.object_frame if result.problem.sensors else "block"


def _sensor(result, camera_index: int):
    """The sensor of a camera of the adjustment (through the images that use it)."""
    problem = result.problem
    return next(slot.sensor for slot in problem.sensors
                if np.any(problem.image_camera[slot.images] == camera_index))


def distortion_extrapolation(result) -> list:
    """The extrapolation of each frame camera's correction beyond its observations
    (:mod:`selfcal.stats.extrapolation`)."""
    from ..stats.extrapolation import extrapolation
    problem = result.problem
    cam_of = problem.image_camera[problem.obs_image]
    out = []
    for k, (cam, values) in enumerate(zip(problem.cameras, result.state.cameras)):
        if getattr(cam.ap, "frame", None) is None or getattr(cam.ap, "domain", "frame") != "frame":
            continue
        out.append(extrapolation(cam.camera_id, cam.ap, values[cam.n_core:] * cam.free[cam.n_core:],
                                 problem.obs_value[cam_of == k]))
    return out


def image_spreads(result) -> dict:
    """(camera index, core parameter index) -> :class:`selfcal.stats.image_spread.ImageSpread` of every estimated
    core parameter whose sensor marks it ``spread_by_image`` (a rolling shutter's readout)."""
    from ..stats.image_spread import image_spread
    out = {}
    for k, cam in enumerate(result.problem.cameras):
        for i, parameter in enumerate(_sensor(result, k).camera_parameters):
            if parameter.spread_by_image and cam.free[i]:
                spread = image_spread(result, k, i)
                if spread is not None:
                    out[k, i] = spread
    return out


def camera_json(block: Block, result, spreads: dict | None = None) -> dict:
    """camera.json: each camera's sensor parameters and AP coefficients with sigma (files' units), and the
    extrapolation of a frame camera's correction beyond its observations (``extrapolation``). A parameter the
    images may see each with its own error (``spreads``, default :func:`image_spreads`) has the sigma with their
    spread, and ``sigma_adjustment`` (the adjustment's alone), ``spread_between_images`` (beyond their noise),
    ``images_chi2`` and ``images_dof`` (the test of their agreement)."""
    sigmas = result.camera_sigma()
    spreads = image_spreads(result) if spreads is None else spreads
    extrapolated = {e.camera_id: e.as_dict() for e in distortion_extrapolation(result)}
    cameras = {}
    for k, (cam, values, sigma) in enumerate(zip(result.problem.cameras, result.state.cameras, sigmas)):
        cfg = block.cameras[cam.camera_id]
        sensor = _sensor(result, k)
        # (a sensor variant that a camera's keys choose, a rolling shutter's, writes the camera's model and keys)
        entry = {"model": cam.sensor if sensor.selectable else cfg.model}
        for key in ("width_px", "height_px", "pixel_size_mm", "columns", "rows"):
            if hasattr(cfg, key):
                entry[key] = getattr(cfg, key)
        for key in ("shutter", "readout_direction"):
            if getattr(cfg, key, None) is not None:
                entry[key] = getattr(cfg, key)
        for i, parameter in enumerate(sensor.camera_parameters):
            unit, factor = parameter.display
            entry[parameter.file_key] = {"value": float(values[i]) * factor,
                                         "sigma": None if np.isnan(sigma[i]) else float(sigma[i]) * factor,
                                         "estimated": bool(cam.free[i]), "unit": unit}
            if (k, i) in spreads:
                spread = spreads[k, i]
                entry[parameter.file_key] |= {
                    "sigma": spread.sigma_total * factor, "sigma_adjustment": spread.sigma_adjustment * factor,
                    "spread_between_images": spread.spread * factor, "images_chi2": spread.chi2,
                    "images_dof": spread.dof}
        nc = cam.n_core
        coefficients = [
            {"name": name, "value_px": float(values[nc + j]),
             "sigma_px": None if np.isnan(sigma[nc + j]) else float(sigma[nc + j]),
             "active": bool(cam.free[nc + j])}
            for j, name in enumerate(cam.ap.parameter_names)
        ]
        for j, c in enumerate(coefficients):
            if not cam.free[nc + j] and cam.prior_sigma[nc + j] == 0:
                c["held"] = True                    # held at its given value (an imported calibration, --fixed)
        entry["covariance"] = _camera_covariance(result, k, cam, spreads)
        ap = {**cam.ap.to_dict(), "coefficient_unit": "px", "n_active": int(cam.free[nc:].sum())}
        if hasattr(cam.ap, "active_ranges"):
            # the translation ranges that remain after screening (Table 3 of seed 000)
            ap["active_ranges"] = cam.ap.active_ranges(cam.free[nc:])
        entry["ap"] = {**ap, "coefficients": coefficients}
        if cam.camera_id in extrapolated:
            entry["extrapolation"] = extrapolated[cam.camera_id]
        cameras[cam.camera_id] = entry
    return {"cameras": cameras}


def _camera_covariance(result, k: int, cam, spreads: dict) -> dict:
    """The full covariance of a camera's estimated parameters (files' units: c, x0, y0 in mm, APs in px), for
    the exports that carry it through a fit into another tool's parameters (correlation.csv is rounded); the
    images' spread of a parameter (:func:`image_spreads`) on its diagonal."""
    start = result.problem.d_offset[k]
    free = np.flatnonzero(cam.free)
    core = _sensor(result, k).camera_parameters
    factor = np.array([core[i].display[1] if i < cam.n_core else 1.0 for i in free])
    block = result.variance_factor * result.Q_theta[start:start + len(free), start:start + len(free)]
    for (camera, i), spread in spreads.items():
        if camera == k:
            j = int(np.flatnonzero(free == i)[0])
            block[j, j] = spread.sigma_total ** 2
    return {"parameters": [cam.names[i] for i in free],
            "matrix": (block * factor[:, None] * factor[None, :]).tolist()}


def _image_parameters(result):
    """The image parameters of the problem's first sensor (those of images.csv), by their column in the image block:
    a line scanner's jitter coefficients are left to jitter_terms.csv."""
    parameters = result.problem.sensors[0].sensor.image_parameters if result.problem.sensors else ()
    return [(k, p) for k, p in enumerate(parameters) if p.group != "jitter"]


def image_table(block: Block, result, view: ResultView | None = None) -> CsvTable:
    """images.csv: each image's parameters (a frame image's exterior orientation) and their sigma, in the
    files' units (angles in degrees, wrapped to (-180, 180]); ``view``: in the block's CRS."""
    im = block.images
    parameters = _image_parameters(result)
    view = ResultView.of(result) if view is None else view
    values = view.image.copy()
    sigma = view.image_sigma
    header = ["image_id", "camera_id", "strip_id"] + [p.file_key for _, p in parameters] + \
        [p.sigma_key for _, p in parameters] + ["n_points"]
    cols = [im.image_id, im.camera_id, im.strip_id]
    for k, p in parameters:
        v = values[:, k]
        if p.unit == "rad":
            v = (v + np.pi) % (2 * np.pi) - np.pi
        cols.append(v * p.display[1])
    cols += [sigma[:, k] * p.display[1] for k, p in parameters]
    cols.append(np.bincount(block.observations.image_index, minlength=len(im)))
    fmts = ["", "", ""] + [".4f" if p.unit == "m" else ".6f" if p.unit == "rad" else ".9g" for _, p in parameters] * 2 + ["d"]
    return header, cols, fmts


def parameter_table(result, view: ResultView | None = None, spreads: dict | None = None) -> CsvTable:
    """parameters.csv: every image and camera parameter with its start value and a-posteriori sigma, in the
    files' units: ``owner`` (image or camera id), ``parameter``, ``group`` (EOP, IOP, AP), ``value``, ``sigma``
    (empty where held; with the images' spread where ``spreads``, as camera.json), ``start``, ``unit``, ``active``
    (0: held, by the sensor model or screening); ``view``: the image parameters in the block's CRS."""
    from ..sensors.base import display_unit
    table = result.parameters()
    from ..stats.image_spread import theta_index
    for (k, i), spread in (spreads or {}).items():
        table.sigma[table.index == theta_index(result.problem, k, i)] = spread.sigma_total
    if view is not None and view.plane is not None:
        _image_rows_in_crs(table, result, view)
    rows = np.flatnonzero(table.kind != "trajectory")          # (the trajectory terms: trajectory.csv)
    shown = [display_unit(u) for u in table.unit[rows]]
    factor = np.array([f for _, f in shown])
    cols: dict[str, list] = {"owner": list(table.owner[rows]), "parameter": list(table.name[rows]),
                             "group": list(table.group[rows]), "value": list(table.value[rows] * factor),
                             "sigma": list(table.sigma[rows] * factor), "start": list(table.start[rows] * factor),
                             "unit": [u for u, _ in shown], "active": list(table.free[rows].astype(int))}
    header = list(cols)
    columns = [np.array(cols[h], dtype=object) if h in ("owner", "parameter", "group", "unit")
               else np.array(cols[h], dtype=int if h == "active" else float) for h in header]
    return header, columns, ["", "", "", ".9g", ".3g", ".9g", "", "d"]


def _image_rows_in_crs(table, result, view: ResultView) -> None:
    """The image parameters' values, sigmas and start values of ``table`` replaced by the CRS's (in place)."""
    ids = {i: k for k, i in enumerate(result.problem.image_ids)}
    rows = np.flatnonzero(table.kind == "image")
    image = np.array([ids[o] for o in table.owner[rows]], np.int64)
    position = table.position[rows].astype(np.int64)
    start = np.full(view.image.shape, np.nan)
    start[image, position] = table.start[rows]
    start = view.poses(start)
    table.value[rows] = view.image[image, position]
    table.sigma[rows] = view.image_sigma[image, position]
    table.start[rows] = start[image, position]


def detector_line_table(result) -> CsvTable | None:
    """detector_line.csv: the estimated displacement of the detectors (along, across track, px) of every
    camera with line APs, every DETECTOR_LINE_STEP columns."""
    ids, cols, along, across = [], [], [], []
    for cam, values in zip(result.problem.cameras, result.state.cameras):
        if getattr(cam.ap, "family", "") != "wavelet1d" or not cam.ap.n_params:
            continue
        col = np.arange(0.5, cam.ap.columns, DETECTOR_LINE_STEP)
        d = cam.ap.displacement_px(col, values[cam.n_core:] * cam.free[cam.n_core:])
        ids += [cam.camera_id] * len(col)
        cols.append(col)
        along.append(d[:, 0])
        across.append(d[:, 1])
    if not ids:
        return None
    return (["camera_id", "col", "d_along_px", "d_across_px"],
            [np.array(ids, object), np.concatenate(cols), np.concatenate(along), np.concatenate(across)],
            ["", ".1f", ".4f", ".4f"])


def check_point_table(checks: CheckPoints, axes: np.ndarray, centre: np.ndarray) -> CsvTable:
    """check_points.csv: each check point's position (km, along ``axes`` from ``centre``) and its error
    d = estimate - reference along the axes (seed 001: across track, along track, up)."""
    where = (checks.reference - centre) @ axes.T / 1000.0
    e = (checks.estimate - checks.reference) @ axes.T
    return (["point_id", "role", "x_across_km", "y_along_km", "d_across_m", "d_along_m", "d_up_m"],
            [checks.point_id.astype(object), checks.role.astype(object), where[:, 0], where[:, 1], e[:, 0], e[:, 1],
             e[:, 2]], ["", "", ".3f", ".3f", ".4f", ".4f", ".4f"])


def control_loo_table(loo) -> CsvTable:
    """control_loo.csv: each control point's leave-one-out error d = estimate without it - surveyed
    (:class:`selfcal.stats.loo.LeaveOneOut`; along east, north, up for ECEF), its a-priori sigma, w = d / sigma,
    the 3-D T = d^T C^-1 d, P(chi2(3) > T) and whether it fails the test (1) at the adjustment's significance."""
    sigma, w = loo.sigma_m, loo.w
    header = ["point_id", "role", "dX_m", "dY_m", "dZ_m", "sigma_X_m", "sigma_Y_m", "sigma_Z_m", "w_X", "w_Y", "w_Z",
              "T_3d", "p", "fails"]
    cols = [loo.point_id.astype(object), loo.role.astype(object), *loo.d_m.T, *sigma.T, *w.T, loo.t3, loo.p,
            loo.fails.astype(int)]
    return header, cols, ["", ""] + [".4f"] * 3 + [".5f"] * 3 + [".3f"] * 3 + [".3f", ".3g", "d"]


def point_table(block: Block, result, tests=None, view: ResultView | None = None) -> CsvTable:
    """points.csv: adjusted points with sigma; for control and check points d = adjusted - reference.

    For weighted control points, ``w_X, w_Y, w_Z`` are Baarda's w of the control
    coordinates (``tests``, :func:`selfcal.stats.observation_tests`); empty elsewhere.
    ``view``: the points in the block's CRS.
    """
    pts = block.points
    view = ResultView.of(result) if view is None else view
    xyz = view.points
    sd = np.sqrt(np.einsum("nii->ni", view.point_covariance))
    diff = np.where((pts.role != "tie")[:, None], xyz - view.reference, np.nan)
    n_images = np.bincount(block.observations.point_index, minlength=len(pts))
    w = np.full((len(pts), 3), np.nan)
    if tests is not None:
        w[result.problem.control_index] = tests.control_w
    header = ["point_id", "role", "X", "Y", "Z", "sigma_X_m", "sigma_Y_m", "sigma_Z_m", "n_images",
              "dX_m", "dY_m", "dZ_m", "w_X", "w_Y", "w_Z"]
    cols = [pts.point_id, pts.role, *xyz.T, *sd.T, n_images, *diff.T, *w.T]
    fmts = ["", ""] + [".4f"] * 3 + [".5f"] * 3 + ["d"] + [".4f"] * 3 + [".3f"] * 3
    return header, cols, fmts


def terrain_table(tested) -> CsvTable | None:
    """terrain.csv (issue 42): every tie point named for a terrain observation, its DEM height H and adjusted
    ellipsoidal height h at the adjusted latitude and longitude, v = h - H (m), its a-priori sigma and, for a
    used height, the redundancy number and Baarda's w; ``status`` used, rejected (by data snooping: w when it was
    rejected) or off_dem (no row: its start value lay off the DEM). None without terrain observations."""
    from ..geometry.earth import geodetic_from_ecef
    result = tested.result
    block = result.block
    terrain = block.terrain_observations
    if terrain is None:
        return None
    ids = list(terrain.point_ids or ()) + list(terrain.off_dem)
    where = {p: k for k, p in enumerate(block.points.point_id)}
    status = np.array(["used"] * len(terrain.point_ids or ()) + ["off_dem"] * len(terrain.off_dem), object)
    rejected = dict(tested.terrain_rejected)
    status[[k for k, p in enumerate(ids) if p in rejected]] = "rejected"
    n = len(ids)
    lat, lon, h, H, r, w = (np.full(n, np.nan) for _ in range(6))
    known = np.array([p in where for p in ids], bool)
    index = np.array([where.get(p, 0) for p in ids], np.int64)
    if known.any():
        la, lo, hh = geodetic_from_ecef(result.state.points[index[known]])
        lat[known], lon[known], h[known] = np.degrees(la), np.degrees(lo), hh
        H[known] = terrain.dem(lat[known], lon[known])
    if result.problem.terrain is not None and len(result.problem.terrain):
        position = {int(p): k for k, p in enumerate(result.problem.terrain.index)}
        for k in range(n):
            j = position.get(int(index[k]), -1) if known[k] and status[k] == "used" else -1
            if j >= 0:
                r[k], w[k] = tested.tests.terrain_redundancy[j], tested.tests.terrain_w[j]
    for k, p in enumerate(ids):
        if p in rejected:
            w[k] = rejected[p]
    header = ["point_id", "status", "lat_deg", "lon_deg", "h_m", "dem_h_m", "v_m", "sigma_m", "redundancy", "w"]
    cols = [np.array(ids, object), status, lat, lon, h, H, h - H, np.full(n, terrain.sigma_m), r, w]
    fmts = ["", "", ".9f", ".9f", ".4f", ".4f", ".4f", ".4f", ".4f", ".3f"]
    return header, cols, fmts


def terrain_summary(tested) -> dict | None:
    """summary.json ``terrain_observations`` (issue 42): the DEM, the sigma given (``sigma_apriori_m``) and the one
    the final adjustment used (``sigma_m``: rescaled by the variance component where it was estimated), how many
    heights were used, rejected by data snooping and off the DEM; None without them."""
    block = tested.result.block
    terrain = block.terrain_observations
    if terrain is None:
        return None
    tests = tested.tests
    component = next((c for c in tested.variance_components or () if c.group == "terrain"), None)
    apriori = terrain.sigma_m if component is None else component.sigma_apriori[0]
    from ..geometry.cloud import CloudSurface
    return {"dem": terrain.source or None, "surface": "cloud" if isinstance(terrain.dem, CloudSurface) else "dem",
            "sigma_apriori_m": float(apriori), "sigma_m": float(terrain.sigma_m),
            "n_used": int(tests.terrain_w.size), "n_rejected": len(tested.terrain_rejected),
            "n_off_dem": len(terrain.off_dem), "redundancy": float(tests.terrain_redundancy.sum()),
            "rejected": [{"point_id": p, "w": w} for p, w in tested.terrain_rejected]}


def residual_table(block_read: Block, tested) -> CsvTable:
    """residuals.csv: every observation of the block as read, rejected ones included.

    v = adjusted - observed in pixels along the photo axes; w, redundancy numbers,
    minimal detectable blunder (px) and Baarda's external reliability factor per
    coordinate. For a rejected observation, v is computed at the final estimate
    (NaN if its image or point left the adjustment), and w_test and the MDB are
    those of the adjustment that rejected it (none for the robust cleaning's).
    ``robust_weight``, ``robust_u``: its weight at the end of the robust cleaning and
    its residual's size there in robust sigmas (:mod:`selfcal.stats.cleaning`);
    ``rejected_by``: ``robust`` or ``snooping``.
    """
    result, tests = tested.result, tested.tests
    ob = block_read.observations
    n = len(ob)
    used = result.block.observations
    pos = np.full(ob.row.max() + 1 if n else 0, -1)
    pos[used.row] = np.arange(len(used))
    where = pos[ob.row]
    kept = where >= 0
    v = np.full((n, 2), np.nan)
    v[kept] = result.residuals_px[where[kept]]
    lost = ~kept
    if lost.any():
        pred = result.predict_pixels(block_read.images.image_id[ob.image_index[lost]],
                                     block_read.points.point_id[ob.point_index[lost]])
        d = pred - ob.pixel[lost]
        v[lost] = np.column_stack([d[:, 0], -d[:, 1]])
    def per_obs(values):
        out = np.full((n, 2), np.nan)
        out[kept] = values[where[kept]]
        return out
    w = per_obs(tests.image_w)
    red = per_obs(tests.image_redundancy)
    mdb = per_obs(tests.image_mdb_px)
    ext = per_obs(tests.image_external)
    w_test = np.full(n, np.nan)
    pick = np.argmax(np.nan_to_num(np.abs(w[kept])), axis=1)
    w_test[kept] = w[kept][np.arange(int(kept.sum())), pick]
    rejected = np.isin(ob.row, tested.rejected_rows)
    rej_pos = np.searchsorted(tested.rejected_rows, ob.row[rejected])
    w_test[rejected] = tested.rejected_w[rej_pos]
    mdb[rejected] = tested.rejected_mdb_px[rej_pos]
    # the robust cleaning: each observation's weight at its end and its normalised size u (1 and empty without it)
    weight, size = np.ones(n), np.full(n, np.nan)
    by = np.where(rejected, "snooping", "")
    cleaning = tested.cleaning
    if cleaning is not None:
        at = np.full(ob.row.max() + 1 if n else 0, -1)
        at[cleaning.rows] = np.arange(len(cleaning.rows))
        k = at[ob.row] if n else np.zeros(0, np.int64)
        seen = k >= 0
        weight[seen], size[seen] = cleaning.weight[k[seen]], cleaning.u[k[seen]]
        by[np.isin(ob.row, cleaning.rejected_rows)] = "robust"
    header = ["image_id", "point_id", "vx_px", "vy_px", "w_test", "rejected", "col_px", "row_px", "w_x", "w_y",
              "redundancy_x", "redundancy_y", "mdb_x_px", "mdb_y_px", "external_x", "external_y", "robust_weight",
              "robust_u", "rejected_by"]
    cols = [block_read.images.image_id[ob.image_index], block_read.points.point_id[ob.point_index],
            v[:, 0], v[:, 1], w_test, rejected.astype(int), ob.pixel[:, 0], ob.pixel[:, 1], w[:, 0], w[:, 1],
            red[:, 0], red[:, 1], mdb[:, 0], mdb[:, 1], ext[:, 0], ext[:, 1], weight, size, by]
    fmts = ["", "", ".4f", ".4f", ".3f", "d", ".3f", ".3f", ".3f", ".3f", ".4f", ".4f", ".3f", ".3f", ".3f", ".3f",
            ".4g", ".3f", ""]
    return header, cols, fmts


def screening_json(tested, options=None) -> dict:
    """screening.json: which parameter was dropped (AP coefficient, calibration parameter, trajectory term),
    in which round, and why; ``prediction``: the cross-validated prediction error unscreened and screened and, per
    group, what the screening removed and what that cost (+) or gained (-) (:class:`selfcal.stats.screening.
    PredictionGuard`), or why it was not cross-validated."""
    n_kept = int(sum(int(v.sum()) for v in tested.ap_free.values()))
    return {
        "options": None if options is None else vars(options),
        "n_ap_initial": int(tested.n_ap_initial),
        "n_ap_significant": int(tested.n_ap_significant),
        "n_parameters_initial": n_kept + len(tested.screening_log),
        "n_parameters_kept": n_kept,
        "dropped": [{"round": k, "camera_id": d.camera_id, "name": d.name, "t": d.t, "reason": d.reason}
                    for k, d in tested.screening_log],
        "joint_tests": [{"round": k, "n_dropped": j.n_dropped, "f_statistic": j.f_statistic,
                         "f_critical": j.f_critical, "jointly_significant": j.jointly_significant,
                         **({"groups": [{"group": g.group, "n_dropped": g.n_dropped, "f_statistic": g.f_statistic,
                                         "f_critical": g.f_critical, "jointly_significant": g.jointly_significant}
                                        for g in j.groups]} if j.groups else {})}
                        for k, j in tested.screening_rounds],
        "prediction": tested.screening_prediction,
        # the coefficients the interior orientation's guard keeps: one more round without the guard would drop them
        "kept_by_interior_guard": [{"camera_id": d.camera_id, "name": d.name, "t": d.t, "reason_unguarded": d.reason}
                                   for d in tested.guard_kept],
    }


def correlation_table(result) -> CsvTable:
    """correlation.csv: correlation matrix of the calibration parameters: the images' parameters that their
    sensor screens (seed 001's attitude corrections), each camera's core parameters and its active APs."""
    from ..stats.correlation import correlation_matrix
    names, index = [], []
    problem = result.problem
    theta = problem.image_theta()
    for i, k in zip(*np.nonzero(problem.image_screenable & problem.image_free)):
        names.append(f"{problem.image_ids[i]}:{problem.image_names[i][k]}")
        index.append(int(theta[i, k]))
    for cam, start in zip(result.problem.cameras, result.problem.d_offset):
        pos = start + np.cumsum(cam.free) - 1
        for i in range(cam.size):
            if cam.free[i]:
                names.append(f"{cam.camera_id}:{cam.names[i]}")
                index.append(int(pos[i]))
    if not index:
        return ["parameter"], [np.array([], dtype=object)], [""]
    rho = correlation_matrix(result.Q_theta, np.array(index))
    return (["parameter"] + names, [np.array(names, dtype=object)] + [rho[:, j] for j in range(len(names))],
            [""] + [".4f"] * len(names))


def distortion_grid_table(block: Block, result, nodes_x: int = 61) -> CsvTable | None:
    """Estimated Delta in pixels on a regular grid over each camera's frame.

    The grid has ``nodes_x`` nodes across and as many down as keep the cells
    square (41 for a 3:2 frame). ``dcol``, ``drow`` follow the pixel axes.
    """
    framed = [(cam, values) for cam, values in zip(result.problem.cameras, result.state.cameras)
              if getattr(cam.ap, "frame", None) is not None]
    if not framed:
        return None
    multi = len(framed) > 1
    cols_out: dict[str, list] = {k: [] for k in ("camera_id", "col", "row", "dcol", "drow")}
    for cam, values in framed:
        cfg = block.cameras[cam.camera_id]
        x, y = frame_nodes_mm(cam.ap.frame, nodes_x)
        col, row = pixel_from_photo(np.column_stack([x, y]), cfg.width_px, cfg.height_px, cfg.pixel_size_mm).T
        dx, dy = cam.ap.displacement_px(x, y, values[cam.n_core:] * cam.free[cam.n_core:])
        cols_out["camera_id"].append(np.full(col.size, cam.camera_id, dtype=object))
        cols_out["col"].append(col)
        cols_out["row"].append(row)
        cols_out["dcol"].append(dx)
        cols_out["drow"].append(-dy)
    header = (["camera_id"] if multi else []) + ["col", "row", "dcol", "drow"]
    cols = [np.concatenate(cols_out[h]) for h in header]
    fmts = ([""] if multi else []) + [".2f", ".2f", ".5f", ".5f"]
    return header, cols, fmts


def result_files(block_read: Block, tested, summary_extra: dict | None = None, screening_options=None, checks=None,
                 track=None, plane=None) -> dict:
    """Every file of the results folder as data: dicts become JSON, tuples CSV. ``checks``: the check points
    (default: intersected in the adjustment); ``track`` = (centre, axes) adds check_points.csv across /
    along / up (seed 001); ``plane``: the tangent plane the block was adjusted in
    (:class:`~selfcal.geometry.tangent.TangentPlane`): positions, attitudes and their precision are written back
    in its CRS (:mod:`selfcal.report.frame`), the check points compared there."""
    result = tested.result
    view = ResultView.of(result, plane)
    spreads = image_spreads(result)
    files = {
        "summary.json": summary(tested, summary_extra, checks, view),
        "camera.json": camera_json(result.block, result, spreads),
        "images.csv": image_table(result.block, result, view),
        "points.csv": point_table(result.block, result, tested.tests, view),
        "residuals.csv": residual_table(block_read, tested),
        "parameters.csv": parameter_table(result, view, spreads),
        "screening.json": screening_json(tested, screening_options),
        "correlation.csv": correlation_table(result),
    }
    files["points.ply"] = object_points_ply(result, view)
    found = view.checks(intersected(result) if checks is None else checks)
    sigmas = check_point_sigmas_m(found, result) if plane is None else \
        view.check_sigmas(found, result.block.points.point_id)
    optional = {"check_points.geojson": check_points_geojson(
                    found, view.crs, _object_frame(result) == "ECEF", sigmas, target_naif_code(result.block)),
                "distortion_grid.csv": distortion_grid_table(result.block, result),
                "distortion_sigma.csv": distortion_sigma_table(result, getattr(tested, "half_block", None)),
                "detector_line.csv": detector_line_table(result),
                "trajectory.csv": trajectory_table(result, plane) if result.problem.trajectory else None,
                "control_loo.csv": control_loo_table(tested.loo) if getattr(tested, "loo", None) is not None else None,
                "terrain.csv": terrain_table(tested) if getattr(tested, "terrain_rejected", None) is not None else None}
    if track is not None and checks is not None and len(checks):
        optional["check_points.csv"] = check_point_table(checks, track[1], track[0])
    for slot in result.problem.sensors:
        optional |= slot.sensor.result_files(result, slot)
    return files | {k: v for k, v in optional.items() if v is not None}


def target_naif_code(block: Block) -> int | None:
    """The NAIF code of the body the block's images look at, as their ISDs name it (None: none or several)."""
    codes = {getattr(model, "target_naif_code", None) for model in (block.image_models or {}).values()}
    codes.discard(None)
    return codes.pop() if len(codes) == 1 else None


def trajectory_table(result, plane=None) -> CsvTable:
    """trajectory.csv: the strip-wise shift/drift (Eq. 12 of seed 000) and the mounting of each trajectory sensor.

    One row per parameter: ``sensor`` (GNSS, IMU), ``strip_id`` (empty for the mounting),
    ``term`` (D0, D1, D2, lever_arm, boresight), ``axis``, value and a-posteriori sigma in
    ``unit`` (m, m/s, m/s^2 for GNSS; deg, deg/s, deg/s^2 for IMU), and ``active``
    (false: held at zero by screening, sigma empty). ``plane``: the tangent plane the block was adjusted in;
    each strip's terms are turned into the CRS's axes at the strip's middle image
    (:func:`~selfcal.report.frame.trajectory_in_crs`); the mounting is in the camera's and the IMU's axes.
    """
    from .frame import trajectory_in_crs
    problem = result.problem
    values, sigmas = trajectory_in_crs(result, plane)
    cols: dict[str, list] = {k: [] for k in ("sensor", "strip_id", "term", "axis", "value", "sigma", "unit", "active")}
    full = 0
    for t in problem.trajectory:
        gnss = t.offset == 0
        axes = ("X", "Y", "Z") if gnss else ("omega", "phi", "kappa")
        base = "m" if gnss else "deg"
        scale = 1.0 if gnss else float(np.degrees(1.0))
        meta = [(t.strips[s], f"D{k}", axes[a], base + ("" if k == 0 else "/s" if k == 1 else "/s^2"))
                for s in range(len(t.strips)) for k in range(t.order + 1) for a in range(3)]
        if t.estimate_mounting:
            meta += [("", "lever_arm", a, "m") for a in "xyz"] if gnss else \
                [("", "boresight", a, "deg") for a in axes]
        for j, (strip, term, axis, unit) in enumerate(meta):
            active = bool(t.free[j])
            sigma = sigmas[full + j] * scale if active else np.nan
            for key, value in zip(cols, (t.sensor, strip, term, axis, values[full + j] * scale, sigma, unit,
                                         int(active))):
                cols[key].append(value)
        full += t.n_params
    header = list(cols)
    columns = [np.array(cols[h], dtype=object) if h in ("sensor", "strip_id", "term", "axis", "unit")
               else np.array(cols[h], dtype=float if h != "active" else int) for h in header]
    return header, columns, ["", "", "", "", ".6f", ".6f", "", "d"]


def model_choice_table(choice) -> CsvTable:
    """model_choice.csv: every candidate of ``--ap auto`` with its scores (selfcal.workflows.model_choice): the
    image-space BIC of the pre-filter (``field_bic``, with the coefficients it counted), and for the short-listed
    candidates the cross-validated prediction error with its standard error over the folds (``cv_rmse_px``,
    ``cv_se_px``; ``cv_se_diff_px`` of its difference to the best, the rule's), the same rays' fit (``fit_rmse_px``),
    and the linearised adjustment's Omega, sigma0 and BIC."""
    from ..stats.prediction import paired_se_px
    header = ["model", "grid", "n_camera_parameters", "n_observations", "n_unknowns", "omega", "sigma0_px",
              "bic", "delta_bic", "field_bic", "field_coefficients", "cv_rmse_px", "cv_se_px", "cv_se_diff_px",
              "fit_rmse_px", "chosen", "rmsd_chk_xy_m", "rmsd_chk_z_m", "error"]
    best = min((s.bic for s in choice.candidates if s.bic is not None), default=np.nan)   # nan: none converged

    def num(value):
        return np.nan if value is None else value

    def cv(s, name):
        return np.nan if s.prediction is None else getattr(s.prediction, name)
    rows = choice.candidates
    scored = [s.prediction for s in rows if s.prediction is not None]
    best_cv = min(scored, key=lambda p: p.rmse_px) if scored else None
    cols = [np.array([s.model for s in rows], dtype=object),
            np.array([f"{s.grid[0]}x{s.grid[1]}" if takes_grid(s.model) else "" for s in rows],
                     dtype=object),
            np.array([s.n_ap for s in rows]), np.array([s.n_observations for s in rows]),
            np.array([s.n_unknowns for s in rows]), np.array([s.omega for s in rows]),
            np.array([s.sigma0_px for s in rows]), np.array([num(s.bic) for s in rows]),
            np.array([num(s.bic) - best for s in rows]), np.array([num(s.field_bic) for s in rows]),
            np.array([-1 if s.field_k is None else s.field_k for s in rows]),
            np.array([cv(s, "rmse_px") for s in rows]), np.array([cv(s, "se_px") for s in rows]),
            np.array([np.nan if s.prediction is None or best_cv is None else paired_se_px(s.prediction, best_cv)
                      for s in rows]),
            np.array([cv(s, "fit_px") for s in rows]),
            np.array([int(s.model == choice.model and s.grid == choice.grid) for s in rows]),
            np.array([num(s.rmsd_chk_xy_m) for s in rows]), np.array([num(s.rmsd_chk_z_m) for s in rows]),
            np.array([s.error.splitlines()[0].replace(",", ";") if s.error else "" for s in rows], dtype=object)]
    fmts = ["", "", "d", "d", "d", ".3f", ".4f", ".2f", ".2f", ".2f", "d", ".5f", ".5f", ".5f", ".5f", "d", ".4f", ".4f",
            ""]
    return header, cols, fmts


def diagnosis(tested, checks=None, view: ResultView | None = None) -> dict:
    """summary.json ``diagnosis`` (:mod:`selfcal.stats.diagnosis`): the residual-field test of each frame camera,
    the dome test of the check points' heights, and sentences naming what was found, its likely cause and the
    remedy. The dome's centre is the centre of the images' positions (of the check points without them).
    ``view``: the frame ``checks`` are in (the block's CRS; default the adjustment's own)."""
    from ..stats.checks import intersected
    from ..stats.diagnosis import ALPHA, POWER, dome_test, findings, residual_field_tests
    result = tested.result
    block = result.block
    ob = block.observations
    v = result.residuals_px
    red = tested.tests.image_redundancy
    fields = []
    camera_of_image = np.asarray(block.images.camera_id)[ob.image_index]
    for camera_id, cam in block.cameras.items():
        if not isinstance(cam, FrameCamera):
            continue
        at = np.flatnonzero(camera_of_image == camera_id)
        if len(at) == 0:
            continue
        fields += residual_field_tests(camera_id, ob.pixel[at, 0], ob.pixel[at, 1], v[at], ob.sigma_px[at], red[at],
                                       cam.width_px, cam.height_px)
    checks = intersected(result) if checks is None else checks
    dome = None
    if len(checks):
        planar = checks.reference @ checks.axes.T
        positions = block.images.position_m if view is None else view.given_positions
        seen = np.isfinite(positions).all(axis=1)
        centre = (positions[seen] @ checks.axes.T)[:, :2].mean(axis=0) if seen.any() else planar[:, :2].mean(axis=0)
        dome = dome_test(planar[:, :2], checks.errors_m[:, 2], centre)
    return {"alpha": ALPHA, "power": POWER,
            "residual_field": [f.as_dict() for f in fields],
            "dome": None if dome is None else dome.as_dict(),
            "findings": findings(fields, dome)}
