"""The adjustment problem: unknowns, observation groups and their weights.

Unknowns fall in two kinds. *Object points* (3 each) are eliminated by the
Schur complement. All other unknowns form the reduced vector theta, laid out as

    theta = [ e | d | x ]

* ``e`` — the parameters of every image, a block of ``image_width`` per image (a frame
  image's exterior orientation X0, Y0, Z0, omega, phi, kappa; a pushbroom image's attitude
  corrections); entries that a problem holds (a sensor model that does not estimate them,
  or screening) keep their value: their columns are zero and their diagonal one, so that
  every image block has the same width;
* ``d`` — camera parameters shared by many images: the sensor's core parameters (a frame
  camera's principal distance c and principal point x0, y0) and the coefficients of its
  additional parameters (only the free ones; fixed ones keep their value and have no column);
* ``x`` — further parameters that only parameter observations touch
  (trajectory shift and drift, lever arm, ...).

Observation groups, each with its own a-priori standard deviation:

* image observations, two per (image, point) pair, in the observation units of the image's
  sensor (:mod:`selfcal.sensors.base`): photo coordinates in mm for frame cameras;
* ground control coordinates (weighted, not fixed), with a 3x3 weight matrix each;
* parameter observations: priors on image and camera parameters (interior orientation,
  seed 001's parameter weights), GNSS positions and IMU attitudes of the images.

Everything is whitened (divided by its sigma), so the normal matrix is J^T J
and sigma0^2 = v^T P v / (n - u) is unitless.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..ap import APModel
from ..block import Block
from ..errors import UsageError
from . import ordering
from .options import AdjustOptions
from .ordering import CHUNK_OBSERVATIONS
from .parameters import CameraParameters
from .residuals import ResidualSettings, build_residuals

if TYPE_CHECKING:
    from ..sensors.base import BoundSensor, Sensor
    from .ap_columns import APColumnCache
    from .structure import BlockStructure

__all__ = ["CameraParameters", "Problem", "State", "SensorSlot", "build_problem"]


#: widest camera (free parameters) kept in compact form, see Problem.compact_cameras
COMPACT_CAMERA_WIDTH = 32


@dataclass
class State:
    """Current values of all unknowns."""

    image: np.ndarray               # (n_images, image_width): each image's parameters
    cameras: list[np.ndarray]       # per camera [core..., a...]
    points: np.ndarray              # (n_points, 3)
    extra: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def copy(self) -> "State":
        return State(self.image.copy(), [c.copy() for c in self.cameras], self.points.copy(), self.extra.copy())


@dataclass
class SensorSlot:
    """A sensor model and its binding to the images of a problem that use it."""

    sensor: Sensor
    bound: BoundSensor
    images: np.ndarray              # problem image indices
    observations: np.ndarray        # positions (sorted order) of its image observations


def _filled(shape: tuple[int, ...], dtype: type = float) -> Any:
    """A field that build_problem fills: empty (``shape`` with no rows) until then."""
    return field(default_factory=lambda: np.zeros(shape, dtype))


def _ap_column_cache() -> APColumnCache:
    from .ap_columns import APColumnCache       # (ap_columns imports this module)
    return APColumnCache()


@dataclass
class Problem:
    """Arrays the engine works on; observations are sorted by point, the points in the problem's own order
    (``point_order``: by the first image that observes them), which the assembly chunks cut into ranges.

    Points keep the block's numbering everywhere (``obs_point``, ``control_index``, a state's points, the
    results): only ``point_start`` and ``chunks`` count positions in ``point_order``. A chunk of points in
    block order (as read: often by id or by track) touches nearly every image of a large block; in the
    order of their first images its points share few images, and their blocks stay in the caches.
    """

    n_images: int
    n_points: int
    cameras: list[CameraParameters]
    image_camera: np.ndarray        # (n_images,) camera index of each image
    # image observations, sorted by point
    obs_image: np.ndarray
    obs_point: np.ndarray
    obs_order: np.ndarray           # position of each sorted observation in the block's observations
    point_order: np.ndarray         # (n_points,) the block's point at each position of the problem's order
    point_start: np.ndarray         # (n_points + 1,) first observation of the point at each position
    chunks: list[tuple[int, int]]   # position ranges [p0, p1) in point_order of the assembly chunks
    # layout of theta
    d_offset: list[int]             # start of each camera's free parameters in theta
    camera_ids: list[str] = field(default_factory=list)
    image_ids: np.ndarray = _filled((0,), object)
    # the sensors of the images (filled by build_problem after the layout above)
    sensors: list[SensorSlot] = field(default_factory=list)
    obs_sensor: np.ndarray = _filled((0,), np.int64)    # (n_obs,) index into sensors
    obs_pixel: np.ndarray = _filled((0, 2))     # (n_obs, 2) the measured (col, row), px
    # (n_obs, 2) where the AP correction is evaluated (the adjusted (col, row) of an earlier adjustment), px;
    # None: at obs_pixel (Observations.ap_at_px)
    obs_ap_at: np.ndarray | None = None
    obs_value: np.ndarray = _filled((0, 2))     # (n_obs, 2) observation vector, the sensor's observation units
    # (n_obs, 2) the standard deviation its rows are whitened by: a-priori / sqrt(weight)
    obs_sigma: np.ndarray = _filled((0, 2))
    obs_sigma_apriori: np.ndarray = _filled((0, 2))     # (n_obs, 2) the a-priori standard deviation (observation units)
    obs_weight: np.ndarray = _filled((0,))  # (n_obs,) weight factor of each observation (1; a robust weight below it)
    point_role: np.ndarray | None = None    # (n_points,) the block's role of each point: gcp, chk, tie
    image_width: int = 6
    image_names: list = field(default_factory=list)     # per image: the names of its parameters
    image_units: list = field(default_factory=list)
    image_free: np.ndarray = _filled((0, 6), bool)      # (n_images, width) bool
    # (n_images, width) a-priori values, observed where the sigma is finite
    image_prior_value: np.ndarray = _filled((0, 6))
    image_prior_sigma: np.ndarray = _filled((0, 6))     # (n_images, width) NaN: no prior
    image_screenable: np.ndarray = _filled((0, 6), bool)    # (n_images, width) bool
    # every other kind of observation (:mod:`selfcal.adjust.residuals`): control coordinates, priors, GNSS/IMU
    residuals: list = field(default_factory=list)
    # the AP columns kept for the problem (:mod:`selfcal.adjust.ap_columns`)
    ap_cache: APColumnCache = field(default_factory=_ap_column_cache, repr=False)
    _structure: BlockStructure | None = field(default=None, repr=False)
    #: the sparse reduced matrix's pattern between iterations (schur.assemble); let go once the result's is made
    sparse_pattern: Any = field(default=None, repr=False)
    _layout: tuple | None = field(default=None, repr=False)

    def settle_sigma(self) -> None:
        """Take ``obs_sigma`` as the a-priori standard deviations (after the sensors refined them at the start
        values), every weight factor 1."""
        self.obs_sigma_apriori = self.obs_sigma.copy()
        self.obs_weight = np.ones(len(self.obs_sigma))

    @property
    def point_residuals(self) -> list:
        """The residual blocks of observations of points alone (:class:`~.residuals.base.PointResiduals`)."""
        from .residuals import PointResiduals
        return [b for b in self.residuals if isinstance(b, PointResiduals)]

    @property
    def parameter_residuals(self) -> list:
        """The residual blocks of observations of theta alone (:class:`~.residuals.base.ParameterResiduals`)."""
        from .residuals import ParameterResiduals
        return [b for b in self.residuals if isinstance(b, ParameterResiduals)]

    @property
    def trajectory(self) -> list:
        """The parameter blocks with parameters of their own (GNSS/IMU shift, drift, mounting), in the order of
        theta's x part."""
        return [b for b in self.parameter_residuals if b.owns_parameters]

    @property
    def control(self):
        """The control coordinates' block (:class:`~.residuals.control.ControlCoordinates`)."""
        from .residuals.control import ControlCoordinates
        return next(b for b in self.residuals if isinstance(b, ControlCoordinates))

    @property
    def terrain(self):
        """The terrain heights' block (:class:`~.residuals.terrain.TerrainHeights`), None without terrain
        observations."""
        from .residuals.terrain import TerrainHeights
        return next((b for b in self.residuals if isinstance(b, TerrainHeights)), None)

    @property
    def control_index(self) -> np.ndarray:
        """The control points (the block's ``gcp``): their indices among the points."""
        return self.control.index

    @property
    def control_xyz(self) -> np.ndarray:
        """Their surveyed coordinates (n_gcp, 3), object frame."""
        return self.control.xyz

    @property
    def control_weight(self) -> np.ndarray:
        """W (n_gcp, 3, 3) with W^T W the inverse covariance of their surveyed coordinates."""
        return self.control.W

    def d_varying(self) -> np.ndarray:
        """Columns of the camera part whose Jacobian changes between iterations.

        The whitened AP columns are the basis at the measured coordinates: their
        Gram matrix is the same in every iteration and is computed once.
        """
        cols = []
        for cam, start in zip(self.cameras, self.d_offset):
            pos = start - self.n_e + np.cumsum(cam.free) - 1
            cols += [int(pos[i]) for i in range(min(cam.n_core, cam.size)) if cam.free[i]]
        return np.array(cols, dtype=np.int64)

    def _camera_layout(self) -> tuple[int, np.ndarray]:
        """(n_d, camera_columns), computed once per layout (read-only). ``d_offset`` is replaced whenever a
        camera's free parameters change (:func:`selfcal.adjust.apply_free`) and only appended to while the
        problem is built. BAL's 49 cameras asked for them some 1000 times per tested adjustment."""
        if self._layout is None or self._layout[0] is not self.d_offset or self._layout[3] != len(self.d_offset):
            widths = [int(c.free.sum()) for c in self.cameras]
            columns = np.full((len(self.cameras), max(widths, default=0)), -1, dtype=np.int64)
            for k, (start, n) in enumerate(zip(self.d_offset, widths)):
                columns[k, :n] = start - self.n_e + np.arange(n)
            columns.flags.writeable = False
            self._layout = (self.d_offset, sum(widths), columns, len(self.d_offset))
        return self._layout[1], self._layout[2]

    def camera_columns(self) -> np.ndarray:
        """Columns of the camera part (0 .. n_d) of each camera's free parameters, one row per
        camera, padded with -1 to the widest camera: (n_cameras, width)."""
        return self._camera_layout()[1]

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

    def point_positions(self) -> np.ndarray:
        """The position in ``point_order`` of each of the block's points (the inverse permutation)."""
        position = np.empty_like(self.point_order)
        position[self.point_order] = np.arange(len(self.point_order))
        return position

    def structure(self) -> BlockStructure:
        """Sparsity structure of the normal equations (built on first use, then cached)."""
        if self._structure is None:
            from .structure import build_structure
            self._structure = build_structure(self)
        return self._structure

    @property
    def image_sensor(self) -> np.ndarray:
        """Sensor model name of each image."""
        return np.array([self.cameras[k].sensor for k in self.image_camera], dtype=object)

    @property
    def all_images_free(self) -> bool:
        return bool(self.image_free.all())

    @property
    def n_e(self) -> int:
        return self.image_width * self.n_images

    @property
    def n_d(self) -> int:
        return self._camera_layout()[0]

    @property
    def n_theta(self) -> int:
        return self.n_e + self.n_d + self.n_extra

    @property
    def n_image_observations(self) -> int:
        return len(self.obs_image)

    def n_observations(self) -> int:
        """Number of scalar observations (image coordinates, control coordinates, parameter observations)."""
        n = 2 * len(self.obs_image)
        n += sum(b.width * len(b) for b in self.point_residuals)
        return n + sum(b.n_rows(self) for b in self.parameter_residuals)

    def n_unknowns(self) -> int:
        return int(self.image_free.sum()) + self.n_d + self.n_extra + 3 * self.n_points

    def theta_names(self, image_ids=None) -> list[str]:
        image_ids = self.image_ids if image_ids is None else image_ids
        names = [f"image {i}: {p}" + ("" if f else " (held)")
                 for i, ps, fs in zip(image_ids, self.image_names, self.image_free) for p, f in zip(ps, fs)]
        for cam in self.cameras:
            names += [f"camera {cam.camera_id}: {n}" for n, f in zip(cam.names, cam.free) if f]
        return names + list(self.extra_names)

    def image_theta(self) -> np.ndarray:
        """theta indices (n_images, width) of the image parameters."""
        return np.arange(self.n_e).reshape(self.n_images, self.image_width)

    def pack(self, state: State) -> np.ndarray:
        """theta of a state (the free entries only)."""
        parts = [state.image.ravel()]
        parts += [c_values[c.free] for c, c_values in zip(self.cameras, state.cameras)]
        parts.append(state.extra[self.extra_free])
        return np.concatenate(parts)

    def apply(self, state: State, d_theta: np.ndarray, d_points: np.ndarray) -> State:
        """A new state moved by the corrections."""
        new = state.copy()
        new.image += d_theta[: self.n_e].reshape(-1, self.image_width)
        for cam, values, start in zip(self.cameras, new.cameras, self.d_offset):
            k = int(cam.free.sum())
            values[cam.free] += d_theta[start:start + k]
        if self.n_extra:
            new.extra[self.extra_free] += d_theta[self.n_theta - self.n_extra:]
        new.points += d_points
        return new


def build_problem(block: Block, options: AdjustOptions = AdjustOptions(), ap_models: dict | None = None,
                  point_key: np.ndarray | None = None, chunk_observations: int = CHUNK_OBSERVATIONS) -> Problem:
    """Arrange a (pruned) block for the engine.

    Parameters
    ----------
    block : Block
        Object points in the object frame of its sensors (ECEF for satellite sensors).
    options : AdjustOptions
        The AP model of every camera (``options.ap``), the trajectory's shift/drift and mounting
        (``options.trajectory``), what the sensors estimate (``options.sensor``, handed to them).
    ap_models : dict camera_id -> APModel, optional
        Prebuilt AP models (instead of building them from ``options.ap``).
    point_key : ndarray, optional
        Orders the points (``Problem.point_order``; :func:`inherited_point_key`); by default their first images, and
        in them their rows (:func:`selfcal.adjust.ordering.point_order`).
    chunk_observations : int
        About how many image observations a chunk of points holds (the unit of the passes over the points).
    """
    from ..ap import ap_settings as settings_of
    from ..sensors import sensor_of
    ap_settings = settings_of(options.ap.model, options.ap.grid)
    obs = block.observations
    used = set(block.images.camera_id.tolist())
    camera_ids = [c for c in block.cameras if c in used]         # a camera without images has no unknowns
    lookup = {c: k for k, c in enumerate(camera_ids)}
    image_camera = np.array([lookup[c] for c in block.images.camera_id], dtype=np.int64)
    point_order = ordering.point_order(obs.image_index, obs.point_index, len(block.points), point_key,
                                       row_px=obs.pixel[:, 1])
    position = np.empty_like(point_order)
    position[point_order] = np.arange(len(point_order))             # (Problem.point_positions)
    order = np.lexsort((obs.image_index, position[obs.point_index]))
    point_start = np.searchsorted(position[obs.point_index[order]], np.arange(len(block.points) + 1))
    sensors = [sensor_of(block.cameras[c]).configured(options.sensor) for c in camera_ids]
    object_frames = {s.object_frame for s in sensors}
    if len(object_frames) > 1:
        raise UsageError("a block mixes sensors with different object frames: "
                         + ", ".join(sorted({s.name for s in sensors})))
    object_frame = object_frames.pop() if object_frames else "block"
    problem = Problem(
        n_images=len(block.images),
        n_points=len(block.points),
        cameras=[],
        image_camera=image_camera,
        obs_image=obs.image_index[order],
        obs_point=obs.point_index[order],
        obs_order=order,
        point_order=point_order,
        point_start=point_start,
        chunks=ordering.point_chunks(point_start, chunk_observations),
        d_offset=[],
        camera_ids=camera_ids,
        image_ids=np.asarray(block.images.image_id),
        point_role=np.asarray(block.points.role, dtype=object),
    )

    # the sensors, bound to their images and observations
    kinds = list(dict.fromkeys(s.name for s in sensors))
    sensor_index = np.array([kinds.index(s.name) for s in sensors])[image_camera]
    problem.obs_sensor = sensor_index[problem.obs_image]
    problem.obs_pixel = obs.pixel[order]
    problem.obs_ap_at = None if obs.ap_at_px is None else obs.ap_at_px[order]
    problem.obs_value = np.zeros((len(order), 2))
    problem.obs_sigma = np.ones((len(order), 2))
    widths = set()
    problem.image_names = [None] * problem.n_images
    problem.image_units = [None] * problem.n_images
    image_setup = {}
    for s_index, name in enumerate(kinds):
        sensor = next(s for s in sensors if s.name == name)
        images = np.flatnonzero(sensor_index == s_index)
        o = np.flatnonzero(problem.obs_sensor == s_index)
        bound = sensor.bind(problem, block, o, obs.pixel[order[o]], obs.sigma_px[order[o]], options.sensor)
        problem.obs_value[o], problem.obs_sigma[o] = bound.observations()
        problem.sensors.append(SensorSlot(sensor, bound, images, o))
        widths.add(len(sensor.image_parameters))
        for i in images:
            problem.image_names[i] = list(sensor.image_names)
            problem.image_units[i] = [p.unit for p in sensor.image_parameters]
        image_setup[s_index] = (images, *sensor.image_setup(block, images, options.sensor))
    if len(widths) > 1:
        raise UsageError("a block mixes sensors whose images have different parameters: " + ", ".join(kinds))
    width = widths.pop() if widths else 6
    problem.image_width = width
    problem.image_free = np.ones((problem.n_images, width), bool)
    problem.image_prior_value = np.zeros((problem.n_images, width))
    problem.image_prior_sigma = np.full((problem.n_images, width), np.nan)
    problem.image_screenable = np.zeros((problem.n_images, width), bool)
    for s_index, (images, free, sigma) in image_setup.items():
        slot = problem.sensors[s_index]
        undetermined = slot.bound.undetermined_image_parameters(images)
        problem.image_free[images] = free if undetermined is None else free & ~undetermined
        problem.image_prior_sigma[images] = sigma
        problem.image_prior_value[images] = slot.sensor.initial_images(slot.bound, block, images)
        problem.image_screenable[images] = [p.screened for p in slot.sensor.image_parameters]

    # the cameras: core parameters of their sensor, then the additional parameters
    cam_of_obs = image_camera[problem.obs_image]
    start = problem.n_e
    ap_cameras, ap_sigma_px = options.ap.cameras, options.ap.sigma_px
    for k, (cid, sensor) in enumerate(zip(camera_ids, sensors)):
        cfg = block.cameras[cid]
        value, free, sigma = sensor.camera_setup(cfg, options.sensor)
        spec = options.ap.model if ap_cameras is None or cid in ap_cameras else "none"
        initial = getattr(cfg, "initial_ap", None)
        held = initial is not None and initial.sigma_px == 0
        if initial is not None and held:
            spec = initial.spec          # a held calibration keeps its own AP model (block.toml sigma_px = 0)
        ap, ap_start = sensor.create_ap(spec, cfg, problem.obs_value[cam_of_obs == k], ap_settings,
                                        model=(ap_models or {}).get(cid))
        n_ap = ap.n_params
        units = tuple(p.unit for p in sensor.camera_parameters) + ("px",) * n_ap
        ap_sigma = np.full(n_ap, np.nan if ap_sigma_px is None else float(ap_sigma_px))
        if initial is not None and initial.sigma_px is not None:
            ap_sigma[:] = initial.sigma_px          # 0 with free False: held at the given values
        camera = CameraParameters(cid, ap, getattr(cfg, "pixel_size_mm", 1.0),
                                  np.concatenate([free, np.full(n_ap, not held)]),
                                  np.concatenate([value, ap_start]), np.concatenate([sigma, ap_sigma]),
                                  list(sensor.camera_names) + list(ap.parameter_names), sensor.name,
                                  len(sensor.camera_parameters), tuple(p.screened for p in sensor.camera_parameters),
                                  units, _core_reference(sensor))
        problem.cameras.append(camera)
        problem.d_offset.append(start)
        start += int(camera.free.sum())

    problem.residuals = build_residuals(block, problem, ResidualSettings(object_frame, options.trajectory))
    problem.settle_sigma()
    return problem


def _core_reference(sensor: Sensor) -> tuple:
    """The references of a sensor's core parameters that are not their start values (NaN for those that are);
    empty where none has one."""
    given = tuple(np.nan if p.reference is None else float(p.reference) for p in sensor.camera_parameters)
    return given if np.isfinite(given).any() else ()
