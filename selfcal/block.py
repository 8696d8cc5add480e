"""A photogrammetric block as plain data: cameras, images, points, observations.

Nothing here computes geometry. The arrays follow DESIGN.md §2-3: angles are
radians, lengths metres (object space) or millimetres (image space), image
measurements are pixels with (0, 0) at the upper-left corner of the upper-left
pixel. Missing values are NaN.

The one piece of behaviour is :func:`prune`, which removes what a real block
always contains and an adjustment cannot use (tie points seen once, control
points seen nowhere, images with too few points) and records what it removed.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "ROLES",
    "InitialAP",
    "FrameCamera",
    "BalCamera",
    "OpenCVCamera",
    "PushbroomCamera",
    "Ephemeris",
    "AttitudeSamples",
    "Images",
    "Points",
    "Observations",
    "Dropped",
    "TerrainObservations",
    "Block",
    "prune",
    "leave_out",
    "MIN_POINTS_PER_IMAGE",
]

ROLES = ("gcp", "chk", "tie")

#: An image needs this many observed points to be oriented; with fewer it is
#: dropped. Six points (twelve coordinates for six unknowns) leave redundancy
#: for the image's own orientation, as a minimal space resection with checks.
MIN_POINTS_PER_IMAGE = 6


@dataclass(frozen=True)
class InitialAP:
    """Initial values of a camera's additional parameters (`[cameras.ID.initial_ap]`): an AP model
    and its coefficients in pixels, named as ap.csv of a results folder names them (e.g. a
    calibration imported from COLMAP as ``brown``). An adjustment with another AP model starts
    from that model's least-squares fit of the same distortion field."""

    spec: str
    names: tuple[str, ...]
    values_px: tuple[float, ...]
    #: a-priori sigma of every coefficient about its value (key ``sigma_px``): None (default) = start values
    #: only; 0 = held at them (an imported calibration used as fixed: the camera keeps this AP model whatever
    #: the adjustment's --ap)
    sigma_px: float | None = None


@dataclass(frozen=True)
class FrameCamera:
    """Interior orientation of a frame camera (DESIGN.md §3, `[cameras.ID]`).

    ``sigma_*`` are a-priori standard deviations of the interior orientation:
    None means the parameter is estimated freely, 0 that it is held fixed.
    """

    camera_id: str
    width_px: int
    height_px: int
    pixel_size_mm: float
    focal_mm: float
    x0_mm: float = 0.0
    y0_mm: float = 0.0
    sigma_focal_mm: float | None = None
    sigma_x0_mm: float | None = None
    sigma_y0_mm: float | None = None
    initial_ap: InitialAP | None = None
    #: ``"rolling"``: the sensor is read line by line during ``readout_ms`` (its a-priori value, weighted by
    #: ``sigma_readout_ms``: None free, 0 held), the lines running ``readout_direction`` ("down": row 0 first, "up",
    #: "right": column 0 first, "left"); ``readout_rotation``: the attitude turns too (selfcal.sensors.rolling).
    #: None or ``"global"``: a global shutter
    shutter: str | None = None
    readout_ms: float | None = None
    sigma_readout_ms: float | None = None
    readout_direction: str | None = None
    readout_rotation: bool | None = None

    model = "frame"

    @property
    def rolling_shutter(self) -> bool:
        return self.shutter == "rolling"

    @property
    def sensor(self) -> str:
        """The registered sensor of its images: the frame camera, or the frame camera with a rolling shutter."""
        return "frame-rolling" if self.rolling_shutter else "frame"

    @property
    def width_mm(self) -> float:
        return self.width_px * self.pixel_size_mm

    @property
    def height_mm(self) -> float:
        return self.height_px * self.pixel_size_mm


class PixelUnits:
    """A camera whose photo coordinates are pixels: pixel size 1 "mm" (BAL, OpenCV), its frame in those units."""

    pixel_size_mm = 1.0
    width_px: int
    height_px: int

    @property
    def width_mm(self) -> float:
        return float(self.width_px)

    @property
    def height_mm(self) -> float:
        return float(self.height_px)


@dataclass(frozen=True)
class BalCamera(PixelUnits):
    """A camera of Bundle Adjustment in the Large (``model = "bal"``): f, k1, k2 of
    ``pixel = f (1 + k1 |p|^2 + k2 |p|^4) p`` (see :mod:`selfcal.sensors.bal`).

    BAL has no physical units: the pixel size is 1 "mm", so photo coordinates
    are BAL's centred pixel coordinates (y up).
    """

    camera_id: str
    width_px: int
    height_px: int
    focal_px: float
    k1: float = 0.0
    k2: float = 0.0

    model = "bal"

    @property
    def focal_mm(self) -> float:
        return self.focal_px


@dataclass(frozen=True)
class OpenCVCamera(PixelUnits):
    """OpenCV's camera (``model = "opencv"``, :mod:`selfcal.sensors.opencv`): focal lengths and principal point in
    pixels (OpenCV's: cx, cy from the centre of the first pixel) and the distortion coefficients of
    cv::projectPoints, ``distortion`` naming how many are estimated (``opencv4``, ``plumb_bob``, ``rational``,
    ``thin_prism``). Its photo coordinates are pixels (pixel size 1)."""

    camera_id: str
    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    distortion: str = "rational"
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    k4: float = 0.0
    k5: float = 0.0
    k6: float = 0.0
    s1: float = 0.0
    s2: float = 0.0
    s3: float = 0.0
    s4: float = 0.0

    model = "opencv"

    @property
    def coefficients(self) -> tuple[float, ...]:
        """(k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4), OpenCV's order."""
        return (self.k1, self.k2, self.p1, self.p2, self.k3, self.k4, self.k5, self.k6, self.s1, self.s2, self.s3,
                self.s4)

    @property
    def focal_mm(self) -> float:
        return self.fx_px


@dataclass(frozen=True)
class PushbroomCamera:
    """A linear CCD camera (``model = "pushbroom"``, DESIGN.md §3): ``columns`` detectors merged into
    one virtual array, ``rows`` lines per image; line of sight of column col: (0, (col - center_col) p, f)
    in the telescope frame, turned forward by ``view_pitch_deg``. ``t0_s`` is a clock offset added to
    every image's time_s. Positions, velocities and quaternions are in ``frame`` (ECI = GCRS,
    ECEF = ITRS) and times count from ``epoch_utc``."""

    camera_id: str
    columns: int
    rows: int
    center_col: float
    pixel_size_mm: float
    focal_mm: float
    line_period_s: float
    epoch_utc: str
    frame: str = "ECI"
    view_pitch_deg: float = 0.0
    t0_s: float = 0.0
    #: chips of the virtual array: first column of every chip after the first, and each chip's known
    #: (along, across) displacement in pixels (seed 001, Fig. 1); empty: one ideal line
    chip_starts: tuple[int, ...] | None = None
    chip_offsets_px: tuple[tuple[float, float], ...] | None = None

    model = "pushbroom"

    @property
    def width_px(self) -> int:
        return self.columns

    @property
    def height_px(self) -> int:
        return self.rows


@dataclass(frozen=True)
class Ephemeris:
    """Perspective-centre positions (m) and velocities (m/s) of pushbroom cameras (ephemeris.csv)."""

    camera_id: np.ndarray
    time_s: np.ndarray
    position_m: np.ndarray       # (n, 3)
    velocity_m_s: np.ndarray     # (n, 3)


@dataclass(frozen=True)
class AttitudeSamples:
    """Attitude quaternions of pushbroom cameras (attitude.csv): q1..q3 vector, q4 scalar, body -> frame."""

    camera_id: np.ndarray
    time_s: np.ndarray
    quaternion: np.ndarray       # (n, 4)


@dataclass(frozen=True)
class Images:
    """Images and their approximate or observed exterior orientation.

    Attributes
    ----------
    image_id, camera_id, strip_id : ndarray of str, shape (n,)
    time_s : ndarray, shape (n,)
        Exposure time (NaN when not given).
    position_m : ndarray, shape (n, 3)
        Perspective centre X0, Y0, Z0 (NaN when not given).
    attitude_rad : ndarray, shape (n, 3)
        omega, phi, kappa of M = R3(kappa) R2(phi) R1(omega) (NaN when not given).
    line : ndarray of int, shape (n,)
        Line of images.csv each image came from (for messages).
    gnss_sigma_m : ndarray, shape (n, 3), optional
        A-priori sigma of each image's GNSS observation of X0, Y0, Z0 (images.csv ``sigma_gnss_X_m``...);
        NaN (or None for all) where block.toml's ``[gnss] sigma_m`` applies.
    imu_sigma_rad : ndarray, shape (n, 3), optional
        A-priori sigma of each image's IMU observation of omega, phi, kappa (``sigma_imu_omega_deg``...);
        NaN (or None for all) where ``[imu] sigma_deg`` applies.
    """

    image_id: np.ndarray
    camera_id: np.ndarray
    strip_id: np.ndarray
    time_s: np.ndarray
    position_m: np.ndarray
    attitude_rad: np.ndarray
    line: np.ndarray
    gnss_sigma_m: np.ndarray | None = None
    imu_sigma_rad: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.image_id)

    def take(self, index: np.ndarray) -> "Images":
        fields: list[Any] = [None if getattr(self, f) is None else getattr(self, f)[index]
                             for f in self.__dataclass_fields__]
        return Images(*fields)

    def trajectory_sigma(self, sensor: str, default: ArrayLike) -> np.ndarray:
        """(n, 3) a-priori sigma of each image's ``"GNSS"`` (m) or ``"IMU"`` (rad) observation: the image's own
        where given, else ``default`` (block.toml's, in the same units)."""
        own = self.gnss_sigma_m if sensor == "GNSS" else self.imu_sigma_rad
        default = np.broadcast_to(np.asarray(default, float), (len(self), 3))
        return default.copy() if own is None else np.where(np.isnan(own), default, own)


@dataclass(frozen=True)
class Points:
    """Object points: ground control (gcp), check points (chk) and tie points.

    ``xyz_m`` holds the reference coordinates of gcp/chk and the approximate
    coordinates of tie points where given (NaN otherwise); ``sigma_m`` the
    a-priori standard deviations sigma_X, sigma_Y, sigma_Z (NaN when not given).
    ``sigma_axes`` (n, 3, 3), where given, says along what ``sigma_m`` is given when
    that is not the block's own axes: row i of a point's matrix is the gradient of
    the coordinate that ``sigma_m[:, i]`` belongs to with respect to ``xyz_m`` (a block
    in the tangent plane of its CRS: the CRS's easting, northing and height,
    :func:`selfcal.workflows.frames.tangent_plane_block`).
    """

    point_id: np.ndarray
    role: np.ndarray
    xyz_m: np.ndarray
    sigma_m: np.ndarray
    line: np.ndarray
    sigma_axes: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.point_id)

    def take(self, index: np.ndarray) -> "Points":
        fields: list[Any] = [None if getattr(self, f) is None else getattr(self, f)[index]
                             for f in self.__dataclass_fields__]
        return Points(*fields)


@dataclass(frozen=True)
class Observations:
    """Image measurements: one row per (image, point) pair.

    ``pixel`` holds (col, row) in pixels, ``sigma_px`` the a-priori standard
    deviation of each coordinate. ``row`` identifies each observation by its
    position in the block as read (0-based), so that subsets (after pruning or
    data snooping) map back to it. ``ap_at_px`` (col, row), where not None, is where the
    additional parameters' correction of each observation is evaluated instead of ``pixel``: the
    adjusted image coordinates of an earlier adjustment (:mod:`selfcal.adjust.engine` sets it; a block
    as read has None). It belongs to these pixels: a block whose ``pixel`` is replaced must drop it.
    """

    image_index: np.ndarray
    point_index: np.ndarray
    pixel: np.ndarray
    sigma_px: np.ndarray
    line: np.ndarray
    row: np.ndarray = None  # type: ignore[assignment]  # None: 0 .. n - 1, set by __post_init__
    ap_at_px: np.ndarray | None = None

    def __post_init__(self):
        if self.row is None:
            object.__setattr__(self, "row", np.arange(len(self.image_index)))

    def __len__(self) -> int:
        return len(self.image_index)

    def take(self, index: np.ndarray) -> "Observations":
        fields: list[Any] = [None if getattr(self, f) is None else getattr(self, f)[index]
                             for f in self.__dataclass_fields__]
        return Observations(*fields)


@dataclass(frozen=True)
class Dropped:
    """What :func:`prune` removed, with one message per item."""

    tie_points_one_image: int = 0
    control_points_unobserved: int = 0
    check_points_one_image: int = 0
    images_too_few_points: int = 0
    #: image observations outside their image's frame (beyond half a pixel), left out when read
    observations_outside_frame: int = 0
    #: a free network's observations of a point behind its camera at the start values, left out
    observations_behind_camera: int = 0
    #: a free network's points that their rays do not determine (``selfcal.adjust.datum``), left out
    points_undetermined: int = 0
    messages: tuple[str, ...] = ()

    def as_dict(self) -> dict:
        return {
            "tie_points_one_image": self.tie_points_one_image,
            "control_points_unobserved": self.control_points_unobserved,
            "check_points_one_image": self.check_points_one_image,
            "images_too_few_points": self.images_too_few_points,
            "observations_outside_frame": self.observations_outside_frame,
            "observations_behind_camera": self.observations_behind_camera,
            "points_undetermined": self.points_undetermined,
        }


@dataclass(frozen=True)
class TerrainObservations:
    """Terrain heights as observations of tie points (issue 42; DESIGN-NOTES "Terrain as observations").

    ``dem``: a :class:`~selfcal.geometry.terrain.GridDem` of ellipsoidal heights (EPSG:4326) or a ground point
    cloud's :class:`~selfcal.geometry.cloud.CloudSurface` (anything with their ``__call__``, ``gradient`` and
    ``covers``); ``sigma_m``: the
    a-priori standard deviation of a DEM height at a point; ``point_ids``: the tie points observed (None: every tie
    point whose coordinates in the block are known and lie on the DEM; the tested workflow names them from the
    start values); ``rejected``: those whose terrain height data snooping rejected (kept out of the adjustment);
    ``source``: where the DEM came from (a path, for the reports)."""

    dem: Any
    sigma_m: float
    point_ids: tuple[str, ...] | None = None
    rejected: tuple[str, ...] = ()
    source: str = ""
    #: the tie points left without a terrain row because they lie off the DEM (named with ``point_ids``)
    off_dem: tuple[str, ...] = ()

    def observed_ids(self) -> tuple[str, ...] | None:
        """The tie points with a terrain row: ``point_ids`` without ``rejected`` (None: not yet named)."""
        if self.point_ids is None:
            return None
        gone = set(self.rejected)
        return tuple(p for p in self.point_ids if p not in gone)


@dataclass(frozen=True)
class Block:
    """Everything an adjustment needs, as read from a block folder."""

    name: str
    crs: str
    #: camera id -> its camera: the ``camera_type`` of its sensor (selfcal.sensors): FrameCamera, BalCamera,
    #: PushbroomCamera here, UsgscsmCamera, RpcCamera, DimapCamera ... of the satellite sensors; no common base
    cameras: dict[str, Any]
    images: Images
    points: Points
    observations: Observations
    image_sigma_px: float
    gnss_sigma_m: tuple[float, float, float] | None = None
    imu_sigma_deg: tuple[float, float, float] | None = None
    #: GNSS antenna offset from the perspective centre in the camera frame (x, y, z; metres): the GNSS
    #: observes X0 + M^T a; None = 0 (TrajectoryOptions.lever_arm estimates it, starting from this value)
    gnss_lever_arm_m: tuple[float, float, float] | None = None
    #: boresight angles (omega, phi, kappa; degrees) of the camera in the IMU body frame: the IMU observes
    #: the angles of B(b)^T M; None = 0 (TrajectoryOptions.boresight estimates them, starting from these values)
    imu_boresight_deg: tuple[float, float, float] | None = None
    dropped: Dropped = field(default_factory=Dropped)
    datum: str = "control"          # "control": fixed by control/trajectory; "free": a relative (free) network
    #: pushbroom telemetry (ephemeris.csv, attitude.csv) and terrain (``[terrain]``: a DEM file or a height)
    ephemeris: Ephemeris | None = None
    attitude: AttitudeSamples | None = None
    dem_path: str | None = None
    terrain_height_m: float | None = None
    #: image id -> the image's own sensor description, read from its ``sensor_file`` (DESIGN.md §3a): a
    #: usgscsm/DIMAP/DG line image, an RPC, ...; its sensor uses it instead of fitting telemetry
    image_models: dict | None = None
    #: image id -> the path of its sensor_file (for writing the block again)
    image_files: dict | None = None
    #: the block folder it was read from (None: built in memory); an output never goes there
    folder: str | None = None
    #: terrain heights as observations of the tie points (``selfcal adjust --terrain-observations``); None: none
    terrain_observations: TerrainObservations | None = None

    @property
    def has_trajectory(self) -> bool:
        return self.gnss_sigma_m is not None or self.imu_sigma_deg is not None

    def camera_index(self) -> np.ndarray:
        """Index into ``list(cameras)`` of each image's camera."""
        names = list(self.cameras)
        lookup = {name: i for i, name in enumerate(names)}
        return np.array([lookup[c] for c in self.images.camera_id], dtype=np.int64)


def prune(block: Block, min_points_per_image: int = MIN_POINTS_PER_IMAGE, copy: bool = True) -> Block:
    """Remove what cannot take part in the adjustment, and say what went.

    The returned block's arrays are its own, unless ``copy`` is false and nothing went: then they are ``block``'s
    (a reader's block, which nothing else holds).

    Repeats until stable, because dropping an image can leave tie points with a
    single ray, and dropping those can leave an image with too few points:

    * a tie point seen in one image (no intersection, no redundancy);
    * a check point seen in fewer than two images (it cannot be determined);
    * a control point (gcp) seen in no image;
    * an image with fewer than ``min_points_per_image`` observed points.
    """
    images, points, obs = block.images, block.points, block.observations
    counts = dict(tie=0, chk=0, gcp=0, img=0)
    messages: list[str] = list(block.dropped.messages)
    keep_img = np.ones(len(images), bool)
    keep_pt = np.ones(len(points), bool)
    keep_obs = np.ones(len(obs), bool)
    while True:
        changed = False
        rays = np.bincount(obs.point_index[keep_obs], minlength=len(points))
        for role, minimum, key in (("tie", 2, "tie"), ("chk", 2, "chk"), ("gcp", 1, "gcp")):
            bad = keep_pt & (points.role == role) & (rays < minimum)
            for i in np.flatnonzero(bad):
                messages.append(
                    f"dropped {role} point '{points.point_id[i]}': seen in {rays[i]} image(s), "
                    f"needs {minimum}"
                )
            counts[key] += int(bad.sum())
            if bad.any():
                keep_pt &= ~bad
                changed = True
        keep_obs &= keep_pt[obs.point_index]
        n_pts = np.bincount(obs.image_index[keep_obs], minlength=len(images))
        bad = keep_img & (n_pts < min_points_per_image)
        for i in np.flatnonzero(bad):
            messages.append(
                f"dropped image '{images.image_id[i]}': {n_pts[i]} observed point(s), "
                f"needs {min_points_per_image} to be oriented"
            )
        counts["img"] += int(bad.sum())
        if bad.any():
            keep_img &= ~bad
            keep_obs &= keep_img[obs.image_index]
            changed = True
        if not changed:
            break

    dropped = Dropped(
        tie_points_one_image=block.dropped.tie_points_one_image + counts["tie"],
        control_points_unobserved=block.dropped.control_points_unobserved + counts["gcp"],
        check_points_one_image=block.dropped.check_points_one_image + counts["chk"],
        images_too_few_points=block.dropped.images_too_few_points + counts["img"],
        observations_outside_frame=block.dropped.observations_outside_frame,
        observations_behind_camera=block.dropped.observations_behind_camera,
        points_undetermined=block.dropped.points_undetermined,
        messages=tuple(messages),
    )
    if not copy and keep_obs.all() and keep_pt.all() and keep_img.all():
        return replace(block, dropped=dropped)
    img_new = np.cumsum(keep_img) - 1
    pt_new = np.cumsum(keep_pt) - 1
    kept_obs = obs.take(np.flatnonzero(keep_obs))
    kept_obs = replace(
        kept_obs,
        image_index=img_new[kept_obs.image_index],
        point_index=pt_new[kept_obs.point_index],
    )
    return replace(
        block,
        images=images.take(np.flatnonzero(keep_img)),
        points=points.take(np.flatnonzero(keep_pt)),
        observations=kept_obs,
        dropped=dropped,
    )


def leave_out(block: Block, observations: np.ndarray | None = None, points: np.ndarray | None = None,
              dropped: Dropped | None = None) -> Block:
    """``block`` without the observations flagged in ``observations`` (bool over its observations) and the points
    flagged in ``points`` (bool over its points; their observations go with them); ``dropped`` replaces its
    record of what went. Observation rows (``Observations.row``) are kept; run :func:`prune` afterwards for
    what the removal leaves with too few rays."""
    keep_pt = np.ones(len(block.points), bool) if points is None else ~np.asarray(points, bool)
    keep_obs = np.ones(len(block.observations), bool) if observations is None else ~np.asarray(observations, bool)
    keep_obs &= keep_pt[block.observations.point_index]
    pt_new = np.cumsum(keep_pt) - 1
    kept = block.observations.take(np.flatnonzero(keep_obs))
    kept = replace(kept, point_index=pt_new[kept.point_index])
    return replace(block, points=block.points.take(np.flatnonzero(keep_pt)), observations=kept,
                   dropped=block.dropped if dropped is None else dropped)
