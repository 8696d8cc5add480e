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

from ..ap import APModel, ImageFrame, create_ap, fit_displacement, frame_nodes_mm
from ..ap.none import NoAP
from ..sensors.bal import CAMERA_NAMES as BAL_CAMERA_NAMES
from ..block import Block
from ..errors import BlockError, UsageError
from ..sensors.frame import EOP_NAMES, IOP_NAMES, photo_from_pixel

__all__ = ["CameraParameters", "Problem", "State", "TrajectoryTerms", "build_problem", "trajectory_terms",
           "CHUNK_OBSERVATIONS"]

#: observations per chunk of the normal-equation assembly (bounds memory)
CHUNK_OBSERVATIONS = 16384

#: widest camera (free parameters) kept in compact form, see Problem.compact_cameras
COMPACT_CAMERA_WIDTH = 32


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
    sensor: str = "frame"     # projection model of the camera's images: "frame" or "bal"

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
    # trajectory observations of the images (GNSS positions, IMU attitudes) with their shift/drift
    trajectory: list["TrajectoryTerms"]
    # layout of theta
    d_offset: list[int]             # start of each camera's free parameters in theta
    _structure: object = field(default=None, repr=False)
    _ap_gram: object = field(default=None, repr=False)
    _ap_columns: dict = field(default_factory=dict, repr=False)

    def d_varying(self) -> np.ndarray:
        """Columns of the camera part whose Jacobian changes between iterations.

        The whitened AP columns are the basis at the measured coordinates: their
        Gram matrix is the same in every iteration and is computed once.
        """
        cols = []
        for cam, start in zip(self.cameras, self.d_offset):
            pos = start - self.n_e + np.cumsum(cam.free) - 1
            limit = 3 if cam.sensor == "frame" else cam.size
            cols += [int(pos[i]) for i in range(min(limit, cam.size)) if cam.free[i]]
        return np.array(cols, dtype=np.int64)

    def camera_columns(self) -> np.ndarray:
        """Columns of the camera part (0 .. n_d) of each camera's free parameters, one row per
        camera, padded with -1 to the widest camera: (n_cameras, width)."""
        widths = [int(c.free.sum()) for c in self.cameras]
        out = np.full((len(self.cameras), max(widths, default=0)), -1, dtype=np.int64)
        for k, (start, n) in enumerate(zip(self.d_offset, widths)):
            out[k, :n] = start - self.n_e + np.arange(n)
        return out

    @property
    def compact_cameras(self) -> bool:
        """Whether the camera part is kept per camera (compact rows, pair sums) rather than as
        dense columns.

        Every observation touches the parameters of one camera only. With many small
        cameras (per-image intrinsics, as in BAL) the dense point-camera coupling is
        mostly zeros and its products grow with the square of all camera parameters; the
        compact form sums small blocks over the pairs of observations of each point. One
        camera, or wide cameras (hundreds of APs), keep the dense form, whose AP Gram
        matrix is computed once per problem.
        """
        widths = [int(c.free.sum()) for c in self.cameras]
        return len(widths) > 1 and 0 < max(widths) <= COMPACT_CAMERA_WIDTH and 4 * max(widths) <= sum(widths)

    @property
    def extra_free(self) -> np.ndarray:
        """Which shift/drift parameters (all sensors, in order) are estimated."""
        if not self.trajectory:
            return np.zeros(0, bool)
        return np.concatenate([t.free for t in self.trajectory])

    @property
    def n_extra(self) -> int:
        return int(self.extra_free.sum())

    @property
    def extra_names(self) -> list[str]:
        return [n for t in self.trajectory for n, f in zip(t.names, t.free) if f]

    @property
    def extra_groups(self) -> dict[str, list[int]]:
        """theta indices of the free shift/drift parameters of each sensor (GNSS, IMU)."""
        groups: dict[str, list[int]] = {}
        start = self.n_e + self.n_d
        for t in self.trajectory:
            k = int(t.free.sum())
            groups.setdefault(t.sensor, []).extend(range(start, start + k))
            start += k
        return groups

    def structure(self):
        """Sparsity structure of the normal equations (built on first use, then cached)."""
        if self._structure is None:
            from .structure import build_structure
            self._structure = build_structure(self)
        return self._structure

    @property
    def image_sensor(self) -> np.ndarray:
        """Projection model of each image ("frame", "bal")."""
        return np.array([self.cameras[k].sensor for k in self.image_camera], dtype=object)

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
        n += sum(3 * len(t.index) for t in self.trajectory)
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
        parts.append(state.extra[self.extra_free])
        return np.concatenate(parts)

    def apply(self, state: State, d_theta: np.ndarray, d_points: np.ndarray) -> State:
        """A new state moved by the corrections."""
        new = state.copy()
        new.eop += d_theta[: self.n_e].reshape(-1, 6)
        for cam, values, start in zip(self.cameras, new.cameras, self.d_offset):
            k = int(cam.free.sum())
            values[cam.free] += d_theta[start:start + k]
        if self.n_extra:
            new.extra[self.extra_free] += d_theta[self.n_theta - self.n_extra:]
        new.points += d_points
        return new


@dataclass
class TrajectoryTerms:
    """Trajectory observations of one sensor with strip-wise shift and drift, Eq. (12) of seed 000:

        P_observed = P0 + D0 + D1 dt + D2 dt^2

    with P0 the image's exterior orientation (position for GNSS, attitude for
    IMU) and dt the time since the strip's middle (half-way between its first and last
    exposure), so that D0 is the strip's mean offset and D0, D1 are nearly uncorrelated
    (counted from the first exposure they were correlated at -0.4 to -0.9 on the simulated
    block, and the screening tested each against a partner that moved with it). ``order``
    -1 means plain observations (no shift/drift); 0 a shift D0; 1 shift and drift; 2 adds D2.

    The mounting of the sensor enters P0: the GNSS antenna sits at the lever arm
    ``a`` (camera frame, metres), P0 = X0 + M^T a; the IMU body frame is turned by
    the boresight angles ``b`` from the camera, P0 = opk(B(b)^T M) (M the camera's
    object-to-image rotation). ``mounting`` holds a or b (radians) as given; with
    ``estimate_mounting`` they are three more unknowns, starting from it.

    Parameters are laid out per strip as [D0 (3), D1 (3), D2 (3)], then the mounting (3) if estimated.
    """

    sensor: str                 # "GNSS" or "IMU"
    index: np.ndarray           # images with an observation
    observed: np.ndarray        # (k, 3)
    sigma: np.ndarray           # (3,) metres or radians
    offset: int                 # 0: X0 Y0 Z0, 3: omega phi kappa
    order: int
    strip_of: np.ndarray        # (k,) strip number of each observation
    dt: np.ndarray              # (k,) seconds since the strip's middle (half-way between first and last exposure)
    strips: list[str]
    free: np.ndarray            # bool over the parameters (screening holds some at zero)
    names: list[str]
    mounting: np.ndarray = field(default_factory=lambda: np.zeros(3))
    estimate_mounting: bool = False

    @property
    def n_params(self) -> int:
        return len(self.free)

    @property
    def n_strip_params(self) -> int:
        return len(self.strips) * (self.order + 1) * 3 if self.order >= 0 else 0

    @property
    def wrap(self) -> bool:
        return self.offset == 3

    @property
    def mounted(self) -> bool:
        """Whether the mounting enters the model (estimated, or given and not zero)."""
        return self.estimate_mounting or bool(np.any(self.mounting != 0))

    def initial(self) -> np.ndarray:
        """Initial values of the parameters: zero shift/drift, the given mounting."""
        return np.concatenate([np.zeros(self.n_strip_params), self.mounting if self.estimate_mounting else []])

    def mounting_of(self, values: np.ndarray) -> np.ndarray:
        """The lever arm or boresight angles in effect, from this sensor's parameter values."""
        if self.estimate_mounting:
            return values[self.n_strip_params:self.n_strip_params + 3]
        return self.mounting

    def design(self) -> np.ndarray:
        """(k, order + 1) powers of dt."""
        return self.dt[:, None] ** np.arange(self.order + 1)[None, :] if self.order >= 0 else np.zeros((len(self.dt), 0))


def trajectory_terms(sensor: str, images, index: np.ndarray, observed: np.ndarray, sigma: np.ndarray,
                     offset: int, order: int, mounting=None, estimate_mounting: bool = False) -> TrajectoryTerms:
    """Set up one sensor's trajectory observations with strip-wise shift/drift of ``order``.

    ``mounting``: the lever arm (GNSS, metres) or boresight angles (IMU, radians); with
    ``estimate_mounting`` they are unknowns. They cannot be told apart from strip-wise
    shifts (the attitude is nearly constant along a strip), so estimating them needs ``order`` -1.
    """
    from ..errors import AdjustmentError
    what = "lever arm" if offset == 0 else "boresight angles"
    if estimate_mounting and order >= 0:
        raise UsageError(f"the {sensor} {what} cannot be separated from strip-wise {sensor} shifts (the attitude "
                         f"hardly changes along a strip): estimate them with --{sensor.lower()}-drift none")
    strip_ids = images.strip_id[index]
    strips = list(dict.fromkeys(strip_ids.tolist()))
    strip_of = np.array([strips.index(s) for s in strip_ids], dtype=np.int64)
    times = images.time_s[index]
    if order >= 1 and np.isnan(times).any():
        bad = ", ".join(images.image_id[index[np.isnan(times)]][:5])
        raise AdjustmentError(f"{sensor} drift of order {order} needs time_s of every image; missing for {bad}")
    t0 = np.array([0.5 * (np.nanmin(times[strip_of == s]) + np.nanmax(times[strip_of == s])) if order >= 1 else 0.0
                   for s in range(len(strips))])
    dt = np.nan_to_num(times - t0[strip_of]) if order >= 1 else np.zeros(len(index))
    axes = ("X", "Y", "Z") if offset == 0 else ("omega", "phi", "kappa")
    names = [f"{sensor} {strip} D{k} {a}" for strip in strips for k in range(order + 1) for a in axes]
    if estimate_mounting:
        names += [f"GNSS lever arm {a}" for a in "xyz"] if offset == 0 else \
            [f"IMU boresight {a}" for a in ("omega", "phi", "kappa")]
    return TrajectoryTerms(sensor, index, observed, sigma, offset, order, strip_of, dt, strips,
                           np.ones(len(names), bool), names,
                           np.zeros(3) if mounting is None else np.asarray(mounting, float), estimate_mounting)


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


def initial_coefficients(ap: APModel, initial, frame: ImageFrame, observed_xy_mm: np.ndarray,
                         camera_id: str) -> np.ndarray:
    """Initial AP coefficients from block.toml `[cameras.ID.initial_ap]`: the values themselves when the
    model is the same, else ``ap``'s least-squares fit of their distortion field on a 61-node grid (the parts
    the orientation absorbs fitted alongside and left to it)."""
    where = f"cameras.{camera_id}.initial_ap"
    try:
        source = create_ap(initial.spec, frame, observed_xy_mm)
    except ValueError as exc:
        raise BlockError("block.toml", str(exc), None, f"{where}.model") from None
    given = dict(zip(initial.names, initial.values_px))
    unknown = sorted(set(given) - set(source.parameter_names))
    if unknown:
        raise BlockError("block.toml", f"{initial.spec} has no coefficient {unknown[0]!r} (its coefficients: "
                                       f"{', '.join(source.parameter_names)})", None, f"{where}.{unknown[0]}")
    values = np.array([given.get(name, 0.0) for name in source.parameter_names])
    if source.spec == ap.spec and source.parameter_names == ap.parameter_names:
        return values
    x, y = frame_nodes_mm(frame)
    dx, dy = source.displacement_px(x, y, values)
    return fit_displacement(ap, x, y, dx, dy, absorbed=True)[0]


def build_problem(block: Block, ap_spec: str = "none", ap_settings: dict | None = None,
                  chunk_observations: int = CHUNK_OBSERVATIONS, ap_models: dict | None = None,
                  gnss_drift: int = 1, imu_drift: int = 1, lever_arm: bool = False,
                  boresight: bool = False) -> Problem:
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
    gnss_drift, imu_drift : int
        Order of the strip-wise shift/drift of the trajectory observations
        (-1 none, 0 shift, 1 shift + linear drift, 2 adds a quadratic term).
    lever_arm, boresight : bool
        Estimate the GNSS lever arm / the IMU boresight angles (block.toml gives their
        initial values, else zero); both need the shift/drift order -1.
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
        if cam.model == "bal":
            # BAL's own radial model; additional parameters do not apply
            cameras.append(CameraParameters(cid, NoAP(frame), 1.0, np.ones(3, bool),
                                            np.array([cam.focal_px, cam.k1, cam.k2]), np.full(3, np.nan),
                                            list(BAL_CAMERA_NAMES), sensor="bal"))
            continue
        if ap_models and cid in ap_models:
            ap = ap_models[cid]
        else:
            ap = create_ap(ap_spec, frame, xy[cam_of_obs == k], **ap_settings)
        n = 3 + ap.n_params
        free = np.ones(n, bool)
        prior_value = np.zeros(n)
        prior_value[:3] = (cam.focal_mm, cam.x0_mm, cam.y0_mm)
        if cam.initial_ap is not None:
            prior_value[3:] = initial_coefficients(ap, cam.initial_ap, frame, xy[cam_of_obs == k], cid)
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
    trajectory = []
    if lever_arm and block.gnss_sigma_m is None:
        raise UsageError("--lever-arm needs GNSS observations ([gnss] in block.toml)")
    if boresight and block.imu_sigma_deg is None:
        raise UsageError("--boresight needs IMU observations ([imu] in block.toml)")
    if block.gnss_sigma_m is not None:
        index = np.flatnonzero(np.isfinite(images.position_m).all(axis=1))
        trajectory.append(trajectory_terms("GNSS", images, index, images.position_m[index],
                                           np.array(block.gnss_sigma_m, float), 0, gnss_drift,
                                           block.gnss_lever_arm_m, lever_arm))
    if block.imu_sigma_deg is not None:
        index = np.flatnonzero(np.isfinite(images.attitude_rad).all(axis=1))
        trajectory.append(trajectory_terms("IMU", images, index, images.attitude_rad[index],
                                           np.radians(np.array(block.imu_sigma_deg, float)), 3, imu_drift,
                                           None if block.imu_boresight_deg is None else
                                           np.radians(np.array(block.imu_boresight_deg, float)), boresight))

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
        trajectory=trajectory,
        d_offset=d_offset,
    )
