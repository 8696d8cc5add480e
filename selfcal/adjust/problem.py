"""The adjustment problem: unknowns, observation groups and their weights.

Unknowns fall in two kinds. *Object points* (3 each) are eliminated by the
Schur complement. All other unknowns form the reduced vector theta, laid out as

    theta = [ e | d | x ]

* ``e`` — exterior orientation, 6 per image (X0, Y0, Z0, omega, phi, kappa);
* ``d`` — camera parameters shared by many images: principal distance c,
  principal point x0, y0 and the AP coefficients of each camera (only the free
  ones; fixed ones keep their value and have no column);
* ``x`` — further parameters that only parameter observations touch
  (trajectory shift and drift, lever arm, ...).

Observation groups, each with its own a-priori standard deviation:

* image coordinates (x, y) of every (image, point) pair, sigma in pixels;
* ground control coordinates (weighted, not fixed), sigma in metres;
* parameter observations: priors on interior orientation, GNSS positions and
  IMU attitudes of the images.

Everything is whitened (divided by its sigma), so the normal matrix is J^T J
and sigma0^2 = v^T P v / (n - u) is unitless.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..ap import APModel, ImageFrame, create_ap
from ..block import Block
from ..sensors.frame import EOP_NAMES, IOP_NAMES, photo_from_pixel

__all__ = ["CameraParameters", "Problem", "State", "build_problem", "CHUNK_OBSERVATIONS"]

#: observations per chunk of the normal-equation assembly (bounds memory)
CHUNK_OBSERVATIONS = 16384


@dataclass
class CameraParameters:
    """One camera's parameter vector [c, x0, y0, a_1 .. a_n] and its settings."""

    camera_id: str
    ap: APModel
    pixel_size_mm: float
    free: np.ndarray          # bool, which entries are unknowns
    prior_value: np.ndarray   # a-priori values (used where prior_sigma is finite)
    prior_sigma: np.ndarray   # NaN: no prior observation
    names: list[str]

    @property
    def size(self) -> int:
        return len(self.free)


@dataclass
class State:
    """Current values of all unknowns."""

    eop: np.ndarray                 # (n_images, 6)
    cameras: list[np.ndarray]       # per camera [c, x0, y0, a...]
    points: np.ndarray              # (n_points, 3)
    extra: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def copy(self) -> "State":
        return State(self.eop.copy(), [c.copy() for c in self.cameras], self.points.copy(), self.extra.copy())


@dataclass
class Problem:
    """Arrays the engine works on; observations are sorted by point."""

    n_images: int
    n_points: int
    cameras: list[CameraParameters]
    image_camera: np.ndarray        # (n_images,) camera index of each image
    # image observations, sorted by point
    obs_image: np.ndarray
    obs_point: np.ndarray
    obs_xy_mm: np.ndarray           # measured photo coordinates
    obs_sigma_mm: np.ndarray
    obs_order: np.ndarray           # position of each sorted observation in the block's observations
    point_start: np.ndarray         # (n_points + 1,) first observation of each point
    chunks: list[tuple[int, int]]   # point ranges [p0, p1) of the assembly chunks
    # weighted point observations (gcp)
    control_index: np.ndarray
    control_xyz: np.ndarray
    control_sigma: np.ndarray
    # trajectory observations of the images
    gnss_index: np.ndarray
    gnss_xyz: np.ndarray
    gnss_sigma: np.ndarray          # (3,) metres
    imu_index: np.ndarray
    imu_opk: np.ndarray
    imu_sigma: np.ndarray           # (3,) radians
    # layout of theta
    d_offset: list[int]             # start of each camera's free parameters in theta
    n_extra: int = 0
    extra_names: list[str] = field(default_factory=list)
    _structure: object = field(default=None, repr=False)

    def structure(self):
        """Sparsity structure of the normal equations (built on first use, then cached)."""
        if self._structure is None:
            from .structure import build_structure
            self._structure = build_structure(self)
        return self._structure

    @property
    def n_e(self) -> int:
        return 6 * self.n_images

    @property
    def n_d(self) -> int:
        return int(sum(int(c.free.sum()) for c in self.cameras))

    @property
    def n_theta(self) -> int:
        return self.n_e + self.n_d + self.n_extra

    @property
    def n_image_observations(self) -> int:
        return len(self.obs_image)

    def n_observations(self) -> int:
        """Number of scalar observations (image coordinates, control coordinates, parameter observations)."""
        n = 2 * len(self.obs_image) + 3 * len(self.control_index)
        n += 3 * len(self.gnss_index) + 3 * len(self.imu_index)
        n += int(sum(np.sum(c.free & np.isfinite(c.prior_sigma)) for c in self.cameras))
        return n

    def n_unknowns(self) -> int:
        return self.n_theta + 3 * self.n_points

    def theta_names(self, image_ids) -> list[str]:
        names = [f"image {i}: {p}" for i in image_ids for p in EOP_NAMES]
        for cam in self.cameras:
            names += [f"camera {cam.camera_id}: {n}" for n, f in zip(cam.names, cam.free) if f]
        return names + list(self.extra_names)

    def pack(self, state: State) -> np.ndarray:
        """theta of a state (the free entries only)."""
        parts = [state.eop.ravel()]
        parts += [c_values[c.free] for c, c_values in zip(self.cameras, state.cameras)]
        parts.append(state.extra)
        return np.concatenate(parts)

    def apply(self, state: State, d_theta: np.ndarray, d_points: np.ndarray) -> State:
        """A new state moved by the corrections."""
        new = state.copy()
        new.eop += d_theta[: self.n_e].reshape(-1, 6)
        for cam, values, start in zip(self.cameras, new.cameras, self.d_offset):
            k = int(cam.free.sum())
            values[cam.free] += d_theta[start:start + k]
        if self.n_extra:
            new.extra += d_theta[self.n_theta - self.n_extra:]
        new.points += d_points
        return new


def _chunks(point_start: np.ndarray, target: int) -> list[tuple[int, int]]:
    """Split points into ranges holding about ``target`` observations each."""
    n_points = len(point_start) - 1
    bounds = [0]
    cuts = np.searchsorted(point_start, np.arange(target, point_start[-1], target))
    for cut in cuts:
        cut = int(min(max(cut, bounds[-1] + 1), n_points))
        if cut > bounds[-1] and cut < n_points:
            bounds.append(cut)
    bounds.append(n_points)
    return [(a, b) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]


def build_problem(block: Block, ap_spec: str = "none", ap_settings: dict | None = None,
                  chunk_observations: int = CHUNK_OBSERVATIONS, ap_models: dict | None = None) -> Problem:
    """Arrange a (pruned) block for the engine.

    Parameters
    ----------
    block : Block
    ap_spec : str
        AP model name (``none``, ``brown``, ``wavelet:db4``, ...), one model per camera.
    ap_settings : dict, optional
        Passed to the AP factory (e.g. ``grid=(9, 6)``).
    ap_models : dict camera_id -> APModel, optional
        Prebuilt AP models (instead of building them from ``ap_spec``).
    """
    ap_settings = ap_settings or {}
    obs = block.observations
    camera_ids = list(block.cameras)
    image_camera = block.camera_index()
    cam_of_obs = image_camera[obs.image_index]

    # measured photo coordinates and their sigma in mm
    widths = np.array([block.cameras[c].width_px for c in camera_ids], float)
    heights = np.array([block.cameras[c].height_px for c in camera_ids], float)
    pix = np.array([block.cameras[c].pixel_size_mm for c in camera_ids], float)
    xy = photo_from_pixel(obs.pixel, widths[cam_of_obs], heights[cam_of_obs], pix[cam_of_obs])
    sigma_mm = obs.sigma_px * pix[cam_of_obs]

    cameras = []
    for k, cid in enumerate(camera_ids):
        cam = block.cameras[cid]
        frame = ImageFrame(cam.width_mm, cam.height_mm, cam.pixel_size_mm)
        if ap_models and cid in ap_models:
            ap = ap_models[cid]
        else:
            ap = create_ap(ap_spec, frame, xy[cam_of_obs == k], **ap_settings)
        n = 3 + ap.n_params
        free = np.ones(n, bool)
        prior_value = np.zeros(n)
        prior_value[:3] = (cam.focal_mm, cam.x0_mm, cam.y0_mm)
        prior_sigma = np.full(n, np.nan)
        for i, sigma in enumerate((cam.sigma_focal_mm, cam.sigma_x0_mm, cam.sigma_y0_mm)):
            if sigma is not None:
                if sigma == 0:
                    free[i] = False
                else:
                    prior_sigma[i] = sigma
        cameras.append(CameraParameters(cid, ap, cam.pixel_size_mm, free, prior_value, prior_sigma,
                                        list(IOP_NAMES) + list(ap.parameter_names)))

    order = np.lexsort((obs.image_index, obs.point_index))
    point_start = np.searchsorted(obs.point_index[order], np.arange(len(block.points) + 1))
    d_offset, start = [], 6 * len(block.images)
    for cam in cameras:
        d_offset.append(start)
        start += int(cam.free.sum())

    pts = block.points
    control = np.flatnonzero(pts.role == "gcp")
    images = block.images
    if block.gnss_sigma_m is not None:
        gnss_index = np.flatnonzero(np.isfinite(images.position_m).all(axis=1))
        gnss_sigma = np.array(block.gnss_sigma_m, float)
    else:
        gnss_index, gnss_sigma = np.zeros(0, np.int64), np.ones(3)
    if block.imu_sigma_deg is not None:
        imu_index = np.flatnonzero(np.isfinite(images.attitude_rad).all(axis=1))
        imu_sigma = np.radians(np.array(block.imu_sigma_deg, float))
    else:
        imu_index, imu_sigma = np.zeros(0, np.int64), np.ones(3)

    return Problem(
        n_images=len(images),
        n_points=len(pts),
        cameras=cameras,
        image_camera=image_camera,
        obs_image=obs.image_index[order],
        obs_point=obs.point_index[order],
        obs_xy_mm=xy[order],
        obs_sigma_mm=sigma_mm[order],
        obs_order=order,
        point_start=point_start,
        chunks=_chunks(point_start, chunk_observations),
        control_index=control,
        control_xyz=pts.xyz_m[control],
        control_sigma=pts.sigma_m[control],
        gnss_index=gnss_index,
        gnss_xyz=images.position_m[gnss_index],
        gnss_sigma=gnss_sigma,
        imu_index=imu_index,
        imu_opk=images.attitude_rad[imu_index],
        imu_sigma=imu_sigma,
        d_offset=d_offset,
    )
