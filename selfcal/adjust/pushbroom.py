"""In-flight self-calibration of pushbroom images: the models M1-M7 of seed 001.

Unknowns: the free calibration parameters of each image (:data:`selfcal.sensors.pushbroom.
PARAMETER_NAMES`) and the ECEF coordinates of every observed ground point. Observations:

* image points (row, col), each giving the time of its line; the collinearity condition of
  :func:`~selfcal.sensors.pushbroom.photo_coordinates` in image units
  (:func:`~selfcal.sensors.pushbroom.image_residuals`: the along-track misfit over the image
  motion per line, the across-track misfit over the detector spacing), weighted by the image sigma;
* ground control: the surveyed coordinates of GCPs, with their covariance;
* parameter weights (M6): a prior observation of a parameter at its start value, with
  an a-priori sigma that bounds how far it may move.

A pushbroom block has few unknowns (tens of parameters and a few hundred point
coordinates), so the normal equations are dense; Gauss-Newton stops when every
correction is below 1e-4 of its standard deviation.

Mono adjustment uses the GCPs of one image; the check points are then restituted on the
terrain (:func:`~selfcal.sensors.pushbroom.image_to_ground`). Stereo adjustment uses every
point of two or three images, the check points as tie points.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import AdjustmentError, BlockError, UsageError
from ..geometry.earth import geodetic_from_ecef, local_up
from ..sensors.pushbroom import (PARAMETER_NAMES, LineCamera, LineImage, fit_trajectory, image_residuals,
                                image_scales, line_of_sight)

__all__ = ["SENSOR_MODELS", "M6_SIGMA", "SensorModel", "sensor_model", "PushbroomResult", "adjust_pushbroom",
           "track_frame", "PushbroomBlock", "pushbroom_block", "FIT_ORDERS", "TELEMETRY_MARGIN_S"]

_P = {name: k for k, name in enumerate(PARAMETER_NAMES)}

#: the parameter sets of seed 001 (Table 1); M6 is M5 with parameter weights
SENSOR_MODELS = {
    "M1": ("d_roll0", "d_pitch0"),
    "M2": ("d_roll0", "d_pitch0", "d_yaw0"),
    "M3": ("d_roll0", "d_pitch0", "focal"),
    "M4": ("d_roll0", "d_pitch0", "d_yaw0", "focal"),
    "M5": ("d_roll0", "d_roll1", "d_pitch0", "d_pitch1", "d_yaw0", "d_yaw1"),
    "M6": ("d_roll0", "d_roll1", "d_pitch0", "d_pitch1", "d_yaw0", "d_yaw1"),
    "M7": ("d_roll0", "d_roll1", "d_pitch0", "d_pitch1", "d_yaw0", "d_yaw1", "focal"),
}

#: a-priori sigma of M6's parameters (rad, rad/s): the uncertainty of the attitude data. Roll and
#: pitch are weighted more than yaw (seed 001: yaw steering takes the bulk of the yaw motion)
M6_SIGMA = {"d_roll0": 1.0e-4, "d_pitch0": 1.0e-4, "d_yaw0": 5.0e-4,
            "d_roll1": 1.0e-5, "d_pitch1": 1.0e-5, "d_yaw1": 5.0e-5}


@dataclass(frozen=True)
class SensorModel:
    """Which calibration parameters are estimated, and with which a-priori sigma (inf: free)."""

    name: str
    free: tuple[str, ...]
    prior_sigma: dict

    def mask(self) -> np.ndarray:
        return np.array([n in self.free for n in PARAMETER_NAMES])

    def sigmas(self) -> np.ndarray:
        return np.array([self.prior_sigma.get(n, np.inf) for n in PARAMETER_NAMES])


def sensor_model(spec: str, prior_sigma: dict | None = None) -> SensorModel:
    """``M1`` ... ``M7``, or an explicit comma-separated list of parameter names (free unless
    ``prior_sigma`` weights them)."""
    if spec.upper() in SENSOR_MODELS:
        name = spec.upper()
        sigmas = dict(M6_SIGMA) if name == "M6" else {}
        sigmas.update(prior_sigma or {})
        return SensorModel(name, SENSOR_MODELS[name], sigmas)
    names = tuple(n.strip() for n in spec.split(",") if n.strip())
    unknown = [n for n in names if n not in _P]
    if unknown or not names:
        raise UsageError(f"unknown sensor model {spec!r}: use M1..M7 or parameter names from "
                         f"{', '.join(PARAMETER_NAMES)}")
    return SensorModel("custom", names, dict(prior_sigma or {}))


@dataclass
class PushbroomResult:
    images: list[LineImage]
    points_ecef: np.ndarray          # (n_points, 3) adjusted (unobserved points keep their start values)
    point_cov: np.ndarray            # (n_points, 3, 3) a-posteriori covariance, m² (NaN for unobserved)
    parameter_names: list[str]       # "IMAGE.name" of each estimated parameter
    parameter_values: np.ndarray
    parameter_sigma: np.ndarray      # a-posteriori
    correlation: np.ndarray          # of the estimated parameters
    residuals_px: np.ndarray         # (n_obs, 2) row, col residuals v = f - l
    redundancy_numbers: np.ndarray   # (n_obs, 2) r = 1 - h of each image coordinate
    w_test: np.ndarray               # (n_obs, 2) Baarda's w = v / (sigma sqrt(r)), with the a-priori sigma
    sigma0: float                    # a-posteriori sigma of unit weight
    redundancy: int
    iterations: int
    converged: bool
    line_ap_coefficients: dict = field(default_factory=dict)   # camera id -> coefficients (px) of its line APs


def _control_whitening(cov: np.ndarray) -> np.ndarray:
    """W (n, 3, 3) with W^T W = cov^-1, per point."""
    return np.linalg.inv(np.linalg.cholesky(cov))


def adjust_pushbroom(images: list[LineImage], obs_image: np.ndarray, obs_point: np.ndarray, obs_row: np.ndarray,
                     obs_col: np.ndarray, points_ecef: np.ndarray, control_index: np.ndarray,
                     control_ecef: np.ndarray, control_cov: np.ndarray, model: SensorModel | list[SensorModel],
                     image_sigma_px: float = 0.3, max_iterations: int = 20, tolerance: float = 1e-4,
                     line_aps: dict | None = None, line_ap_masks: dict | None = None,
                     line_ap_sigma_px: float | None = None) -> PushbroomResult:
    """Adjust ``images`` (start values in their parameters) to image points and ground control.

    ``points_ecef`` are start values of all points (the GCPs' surveyed coordinates, the
    other points' intersections); ``control_index`` names the GCPs among them, with
    ``control_ecef`` and covariance ``control_cov`` (n, 3, 3, m²). ``model``: one
    :class:`SensorModel` for every image, or one per image. ``line_aps``: camera id ->
    :class:`~selfcal.ap.line.LineWaveletAP`, the additional parameters of that camera's detector line
    (shared by its images, estimated from zero, named ``CAMERA.along_c1k+0`` ...); ``line_ap_masks``:
    camera id -> bool (ap.size,), the coefficients estimated (the others stay zero; default all);
    ``line_ap_sigma_px``: an a-priori sigma of every line-AP coefficient (a prior observation of zero), or
    None for free coefficients.
    """
    models = model if isinstance(model, list) else [model] * len(images)
    obs_image, obs_point = np.asarray(obs_image), np.asarray(obs_point)
    obs_row, obs_col = np.asarray(obs_row, float), np.asarray(obs_col, float)
    points = np.array(points_ecef, float)
    n_obs = len(obs_row)
    observed = np.unique(obs_point)
    point_slot = np.full(len(points), -1)
    point_slot[observed] = np.arange(observed.size)
    # layout: the free parameters of each image, then 3 per observed point
    seen = np.isin(np.arange(len(images)), obs_image)
    masks = [m.mask() & seen[i] for i, m in enumerate(models)]      # images without observations stay as they are
    offsets = np.cumsum([0] + [int(m.sum()) for m in masks])
    names = [f"{img.image_id}.{PARAMETER_NAMES[j]}" for img, m in zip(images, masks) for j in np.flatnonzero(m)]
    priors = []                  # (column, prior value, sigma) of each weighted parameter
    for i, (img, m, mod) in enumerate(zip(images, masks, models)):
        sigma = mod.sigmas()
        priors += [(offsets[i] + k, img.parameters[j], sigma[j]) for k, j in enumerate(np.flatnonzero(m))
                   if np.isfinite(sigma[j])]
    # line APs: one coefficient set per camera with observations, after the image parameters
    ap_start, ap_values, ap_masks = {}, {}, {}
    n_par = int(offsets[-1])
    for cid, ap in (line_aps or {}).items():
        if any(img.camera.camera_id == cid and seen[i] for i, img in enumerate(images)):
            mask = np.ones(ap.size, bool) if not line_ap_masks or cid not in line_ap_masks else \
                np.asarray(line_ap_masks[cid], bool)
            ap_start[cid], ap_masks[cid] = n_par, mask
            ap_values[cid] = np.zeros(ap.size)
            names += [f"{cid}.{n}" for n, free in zip(ap.names, mask) if free]
            if line_ap_sigma_px is not None:
                priors += [(n_par + k, 0.0, float(line_ap_sigma_px)) for k in range(int(mask.sum()))]
            n_par += int(mask.sum())
    n_unk = n_par + 3 * observed.size
    control_index = np.asarray(control_index, int)
    ctl_in = point_slot[control_index] >= 0
    W_ctl = _control_whitening(np.asarray(control_cov, float)[ctl_in])
    ctl_slots = point_slot[control_index[ctl_in]]
    ctl_xyz = np.asarray(control_ecef, float)[ctl_in]
    n_rows = 2 * n_obs + len(priors) + 3 * ctl_slots.size
    redundancy = n_rows - n_unk
    if redundancy <= 0:
        raise AdjustmentError(f"no redundancy: {n_rows} observations for {n_unk} unknowns")
    images = list(images)

    scales, bases = {}, {}

    def evaluate(images, points, jacobians):
        res = np.zeros((n_obs, 2))
        J = np.zeros((2 * n_obs, n_unk)) if jacobians else None
        for i, img in enumerate(images):
            sel = np.flatnonzero(obs_image == i)
            if not sel.size:
                continue
            if i not in scales:              # the image scales of the start values serve every iteration
                scales[i] = image_scales(img, points[obs_point[sel]], obs_row[sel], obs_col[sel])
            cid = img.camera.camera_id
            offset_mm = None
            if cid in ap_start:
                ap = line_aps[cid]
                if i not in bases:
                    bases[i] = ap.basis(obs_col[sel])
                m = bases[i].shape[1]
                v = ap_values[cid]
                offset_mm = np.stack([bases[i] @ v[:m], bases[i] @ v[m:]], -1) * img.camera.pixel_size_mm
            out = image_residuals(img, points[obs_point[sel]], obs_row[sel], obs_col[sel], jacobians, scales[i],
                                  offset_mm)
            res[sel] = out[0] if jacobians else out
            if jacobians and cid in ap_start:
                m, p = bases[i].shape[1], img.camera.pixel_size_mm
                along, across = ap_masks[cid][:m], ap_masks[cid][m:]
                start, n_along = ap_start[cid], int(along.sum())
                J[2 * sel[:, None], start + np.arange(n_along)[None, :]] = p * bases[i][:, along] / scales[i][:, :1]
                J[2 * sel[:, None] + 1, start + n_along + np.arange(int(across.sum()))[None, :]] = \
                    -p * bases[i][:, across] / scales[i][:, 1:]
            if jacobians:
                _, d_par, d_pt = out
                rows = (2 * sel[:, None] + np.arange(2)[None, :])
                cols_par = offsets[i] + np.arange(int(masks[i].sum()))
                J[rows[:, :, None], cols_par[None, None, :]] = d_par[:, :, masks[i]]
                cols_pt = n_par + 3 * point_slot[obs_point[sel]][:, None] + np.arange(3)[None, :]
                J[rows[:, :, None], cols_pt[:, None, :]] = d_pt
        return res, J

    def whitened(images, points, jacobians=True):
        res, J = evaluate(images, points, jacobians)
        r = [res.ravel() / image_sigma_px]
        A = [J / image_sigma_px] if jacobians else []
        if priors:
            cols = np.array([c for c, _, _ in priors])
            values = np.concatenate([img.parameters[m] for img, m in zip(images, masks)] +
                                    [ap_values[cid][ap_masks[cid]] for cid in ap_start])
            p0 = np.array([v for _, v, _ in priors])
            sig = np.array([s for _, _, s in priors])
            r.append((p0 - values[cols]) / sig)
            if jacobians:
                Jp = np.zeros((len(priors), n_unk))
                Jp[np.arange(len(priors)), cols] = 1.0 / sig
                A.append(Jp)
        if ctl_slots.size:
            diff = ctl_xyz - points[observed[ctl_slots]]
            r.append(np.einsum("nij,nj->ni", W_ctl, diff).ravel())
            if jacobians:
                Jc = np.zeros((3 * ctl_slots.size, n_unk))
                for k, (slot, W) in enumerate(zip(ctl_slots, W_ctl)):
                    Jc[3 * k:3 * k + 3, n_par + 3 * slot:n_par + 3 * slot + 3] = W
                A.append(Jc)
        return np.concatenate(r), (np.vstack(A) if jacobians else None), res

    converged = False
    iterations = 0
    for iterations in range(1, max_iterations + 1):
        r, A, _ = whitened(images, points)
        N = A.T @ A
        g = A.T @ r
        scale = 1.0 / np.sqrt(np.maximum(np.diag(N), 1e-300))
        Ns = N * np.outer(scale, scale)
        try:
            L = np.linalg.cholesky(Ns)
        except np.linalg.LinAlgError:
            raise AdjustmentError("pushbroom adjustment: the normal equations are singular "
                                  "(too few control points for the sensor model?)") from None
        dx = scale * np.linalg.solve(L.T, np.linalg.solve(L, g * scale))
        sigma_cond = scale                                   # conditional sigma (unit weight) of each unknown
        images = [img.with_parameters(_apply(img.parameters, m, dx[offsets[i]:offsets[i + 1]]))
                  for i, (img, m) in enumerate(zip(images, masks))]
        points[observed] += dx[n_par:].reshape(-1, 3)
        for cid, start in ap_start.items():
            ap_values[cid][ap_masks[cid]] += dx[start:start + int(ap_masks[cid].sum())]
        if np.max(np.abs(dx) / sigma_cond) < tolerance:
            converged = True
            break

    r, A, res = whitened(images, points)
    N = A.T @ A
    Q = np.linalg.inv(N)
    leverage = np.einsum("ij,ij->i", A[:2 * n_obs] @ Q, A[:2 * n_obs]).reshape(n_obs, 2)
    redundancy_numbers = np.clip(1.0 - leverage, 1e-12, None)
    w_test = (-res / image_sigma_px) / np.sqrt(redundancy_numbers)
    sigma0 = float(np.sqrt(r @ r / redundancy)) if redundancy > 0 else float("nan")
    s0 = sigma0 if redundancy > 0 else 1.0
    values = np.concatenate([img.parameters[m] for img, m in zip(images, masks)] +
                            [ap_values[cid][ap_masks[cid]] for cid in ap_start])
    sd = np.sqrt(np.diag(Q))
    Q_par = Q[:n_par, :n_par]
    corr = Q_par / np.outer(sd[:n_par], sd[:n_par]) if n_par else np.zeros((0, 0))
    cov = np.full((len(points), 3, 3), np.nan)
    for slot, p in enumerate(observed):
        cov[p] = s0 ** 2 * Q[n_par + 3 * slot:n_par + 3 * slot + 3, n_par + 3 * slot:n_par + 3 * slot + 3]
    return PushbroomResult(images, points, cov, names, values, s0 * sd[:n_par], corr, -res, redundancy_numbers,
                           w_test, sigma0, redundancy, iterations, converged, ap_values)


def _apply(parameters: np.ndarray, mask: np.ndarray, step: np.ndarray) -> np.ndarray:
    out = parameters.copy()
    out[mask] += step
    return out


def track_frame(image: LineImage) -> tuple[np.ndarray, np.ndarray]:
    """The scene centre (ECEF, on the ellipsoid) and R (3, 3) whose rows are the across-track (X),
    along-track (Y) and up (Z) unit vectors there: check-point errors are reported in it."""
    row = image.rows / 2
    col = image.camera.center_col
    S, d = line_of_sight(image, [row - 1000, row + 1000], [col, col])
    b = np.einsum("ni,ni->n", S, d)
    c = np.einsum("ni,ni->n", S, S) - 6371000.0 ** 2
    ground = S + (-b - np.sqrt(b * b - c))[:, None] * d
    lat, lon, _ = geodetic_from_ecef(ground.mean(axis=0))
    up = local_up(lat, lon)
    along = ground[1] - ground[0]
    along -= (along @ up) * up
    along /= np.linalg.norm(along)
    across = np.cross(along, up)
    return ground.mean(axis=0), np.stack([across, along, up])


#: polynomial orders of the ephemeris position, velocity and attitude fits (Eq. 5)
FIT_ORDERS = (7, 7, 3)
#: telemetry used beyond each end of an image
TELEMETRY_MARGIN_S = 10.0


@dataclass
class PushbroomBlock:
    """A pushbroom block ready for adjustment: images with fitted telemetry (start values of the
    calibration parameters), points in ECEF with their reference coordinates and covariance,
    image points (row, col)."""

    images: list[LineImage]
    point_ids: np.ndarray
    role: np.ndarray                 # gcp | chk | tie
    reference_ecef: np.ndarray       # (n, 3), NaN for tie points
    reference_cov: np.ndarray        # (n, 3, 3) m², from sigma_xy / sigma_z in the local horizon
    obs_image: np.ndarray
    obs_point: np.ndarray
    obs_row: np.ndarray
    obs_col: np.ndarray
    image_sigma_px: float

    def subset(self, image_index) -> tuple[np.ndarray, ...]:
        """The observations of some images: (obs_image, obs_point, obs_row, obs_col)."""
        keep = np.isin(self.obs_image, image_index)
        return self.obs_image[keep], self.obs_point[keep], self.obs_row[keep], self.obs_col[keep]


def _horizon_covariance(ecef: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Covariances (n, 3, 3) in ECEF of sigmas (east, north, up) in the local horizon."""
    lat, lon, _ = geodetic_from_ecef(ecef)
    up = local_up(lat, lon)
    east = np.stack([-np.sin(lon), np.cos(lon), np.zeros_like(lon)], -1)
    north = np.cross(up, east)
    R = np.stack([east, north, up], -1)                       # columns: east, north, up
    return np.einsum("nij,nj,nkj->nik", R, sigma ** 2, R)


def pushbroom_block(block, given_attitude: bool = True, orders=FIT_ORDERS,
                    margin_s: float = TELEMETRY_MARGIN_S) -> PushbroomBlock:
    """Fit each image's telemetry (its camera's ephemeris and attitude over the scene, +/-
    ``margin_s``) and bring the points to ECEF (``block.crs`` through pyproj)."""
    from pyproj import Transformer

    images = []
    for k in range(len(block.images)):
        cam = block.cameras[block.images.camera_id[k]]
        t_first = float(block.images.time_s[k]) + cam.t0_s
        t_last = t_first + cam.rows * cam.line_period_s
        e, a = block.ephemeris, block.attitude
        pick_e = (e.camera_id == cam.camera_id) & (e.time_s >= t_first - margin_s) & (e.time_s <= t_last + margin_s)
        pick_a = (a.camera_id == cam.camera_id) & (a.time_s >= t_first - margin_s) & (a.time_s <= t_last + margin_s)
        for name, pick, order in (("ephemeris.csv", pick_e, max(orders[:2])), ("attitude.csv", pick_a, orders[2])):
            if pick.sum() <= order + 1:
                raise BlockError(name, f"image '{block.images.image_id[k]}' ({t_first:.3f} - {t_last:.3f} s) has "
                                       f"{int(pick.sum())} samples within {margin_s:g} s; the fit of order {order} "
                                       f"needs more")
        camera = LineCamera(cam.camera_id, cam.columns, cam.center_col, cam.pixel_size_mm, cam.focal_mm,
                            cam.line_period_s, cam.view_pitch_deg, cam.chip_starts or (), cam.chip_offsets_px or ())
        t_ref = t_first + 0.5 * cam.rows * cam.line_period_s
        trajectory = fit_trajectory(cam.frame, cam.epoch_utc, e.time_s[pick_e], e.position_m[pick_e],
                                    e.velocity_m_s[pick_e], a.time_s[pick_a], a.quaternion[pick_a], orders,
                                    t_ref=t_ref, given_attitude=given_attitude)
        images.append(LineImage.nominal(str(block.images.image_id[k]), camera, trajectory, t_first, cam.rows))
    xyz = block.points.xyz_m
    if block.crs not in ("EPSG:4978", "ECEF"):
        transformer = Transformer.from_crs(block.crs, "EPSG:4978", always_xy=True)
        xyz = np.column_stack(transformer.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2]))
    sigma = np.nan_to_num(block.points.sigma_m, nan=1.0)
    known = ~np.isnan(xyz).any(axis=1)
    cov = np.full((len(xyz), 3, 3), np.nan)
    cov[known] = _horizon_covariance(xyz[known], sigma[known])
    ob = block.observations
    return PushbroomBlock(images, block.points.point_id, block.points.role, xyz, cov, ob.image_index.copy(),
                          ob.point_index.copy(), ob.pixel[:, 1].copy(), ob.pixel[:, 0].copy(), block.image_sigma_px)
