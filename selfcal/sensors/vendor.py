"""Pieces shared by the vendor line cameras (DigitalGlobe/Maxar XML, SPOT 5 DIMAP) and the one entry point
that turns a vendor sensor file into a selfcal :class:`~selfcal.sensors.pushbroom.LineImage`.

The generic pushbroom model (:mod:`selfcal.sensors.pushbroom`) takes its trajectory as callables of time:
position, velocity (Earth-fixed here) and the attitude as roll, pitch, yaw of the body (selfcal's telescope
frame T: x along track, z towards the scene) in the orbit frame of that position and velocity. A vendor model
gives the rotation T -> ECEF instead; :class:`OrbitAttitude` turns one into the other at every call (no fit),
so the lines of sight are the vendor's and seed 001's attitude corrections (Eq. 6) apply unchanged.

A vendor's line times need not be one straight line in the row (DigitalGlobe's TLC list may change the line
rate): :class:`LineTimes` is the row -> time table, and the image runs on a *pseudo time* linear in the row,
tau = tau0 + row * period, which every callable maps to the true time before it evaluates (:class:`OnLineTime`).
With one line rate tau is the true time.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from ..geometry.earth import orbit_frame
from .pushbroom.model import LineImage, TimeFunction, angles_from_body_to_orbit

if TYPE_CHECKING:
    from ..io.dg import DgSensor
    from ..io.dimap import DimapSensor
    from ..io.spot import Spot5Sensor

__all__ = ["LineTimes", "OnLineTime", "OrbitAttitude", "line_image_from_file", "line_image_from_record", "DimapCamera",
           "DgCamera", "VendorLineSensor", "DIMAP_SENSOR", "DG_SENSOR"]


@dataclass(frozen=True)
class LineTimes:
    """Piecewise-linear time of selfcal rows (the table's rows and times, rows increasing); linear
    extrapolation beyond the first and last entry with their intervals' rates."""

    rows: np.ndarray
    times_s: np.ndarray

    def __post_init__(self):
        if len(self.rows) < 2 or np.any(np.diff(self.rows) <= 0):
            raise ValueError("LineTimes needs two or more increasing rows")
        if np.any(np.diff(self.times_s) == 0) or len(set(np.sign(np.diff(self.times_s)))) != 1:
            raise ValueError("the times of the line table must be strictly monotonic")

    @property
    def period_s(self) -> float:
        """|mean seconds per row| over the table: the pseudo time's line period."""
        return float(abs((self.times_s[-1] - self.times_s[0]) / (self.rows[-1] - self.rows[0])))

    @property
    def linear(self) -> bool:
        """One increasing line rate (to 1e-12 s over the table): the pseudo time is the time."""
        fit = self.times_s[0] + (self.rows - self.rows[0]) * self.period_s
        return bool(np.all(np.abs(fit - self.times_s) < 1e-12) and self.times_s[-1] > self.times_s[0])

    def time(self, row: ArrayLike) -> np.ndarray:
        row = np.asarray(row, float)
        k = np.clip(np.searchsorted(self.rows, row, side="right") - 1, 0, len(self.rows) - 2)
        slope = (self.times_s[k + 1] - self.times_s[k]) / (self.rows[k + 1] - self.rows[k])
        return self.times_s[k] + slope * (row - self.rows[k])

    def row(self, time_s: ArrayLike) -> np.ndarray:
        """Inverse of :meth:`time`."""
        order = np.argsort(self.times_s)
        return LineTimes(self.times_s[order], self.rows[order]).time(time_s)


@dataclass(frozen=True)
class OnLineTime:
    """A callable of true time evaluated at the true time of a pseudo time (module docstring)."""

    function: TimeFunction
    line_times: LineTimes
    tau0_s: float

    def __call__(self, tau):
        row = (np.asarray(tau, float) - self.tau0_s) / self.line_times.period_s
        return self.function(self.line_times.time(row))


@dataclass(frozen=True)
class OrbitAttitude:
    """Roll, pitch, yaw (n, 3) of the telescope frame in the orbit frame, evaluated from callables of time:
    ``position`` and ``velocity`` (Earth-fixed), ``rotation`` (n, 3, 3) telescope -> Earth-fixed."""

    position: TimeFunction
    velocity: TimeFunction
    rotation: TimeFunction

    def __call__(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, float))
        R_FO = orbit_frame(np.atleast_2d(self.position(t)), np.atleast_2d(self.velocity(t)))
        return angles_from_body_to_orbit(np.swapaxes(R_FO, -1, -2) @ self.rotation(t))


def line_image_from_record(record: DgSensor | DimapSensor | Spot5Sensor, image_id: str | None = None) -> LineImage:
    """The selfcal line camera of a vendor's physical model as read (:func:`selfcal.io.sensor_files.read_vendor_line`:
    a DigitalGlobe / Maxar, Pleiades DIMAP or SPOT 5 DIMAP record)."""
    from ..io.dg import DgSensor
    from ..io.dimap import DimapSensor
    if isinstance(record, DgSensor):
        from .dg import line_image_from_dg
        return line_image_from_dg(record, image_id)
    if isinstance(record, DimapSensor):
        from .dimap import line_image_from_dimap
        return line_image_from_dimap(record, image_id or "PHR")
    from .spot import line_image_from_spot5
    return line_image_from_spot5(record, image_id)


def line_image_from_file(path: str | os.PathLike, image_id: str | None = None) -> LineImage:
    """The selfcal line camera of a vendor sensor file, the format found from the content: a DigitalGlobe /
    Maxar XML (root ``isd``), a SPOT 5 DIMAP (root ``Dimap_Document`` with ``Data_Strip``) or a Pleiades DIMAP
    (root ``PHR_Dimap_Document``). Reader errors are :class:`~selfcal.errors.BlockError`."""
    from ..io.sensor_files import read_vendor_line
    return line_image_from_record(read_vendor_line(str(path)), image_id)


# --- the sensor contract: vendor line cameras in a block (model = "dimap" or "dg") ----------------------------

from .pushbroom.sensor import PushbroomBound, PushbroomSensor  # noqa: E402

#: line images built from their records, by (record, image): snooping and screening bind the same images again
_BUILT: dict = {}


def _line_image(record, image_id: str):
    key = (id(record), image_id)
    hit = _BUILT.get(key)
    if hit is None or hit[0] is not record:
        if len(_BUILT) > 256:
            _BUILT.clear()
        hit = _BUILT[key] = (record, line_image_from_record(record, image_id))
    return hit[1]


@dataclass(frozen=True)
class DimapCamera:
    """Line images whose physical model is their vendor's metadata, each image's file its ``sensor_file``
    (DESIGN.md §3a): ``model = "dimap"`` a Pleiades or SPOT 5 DIMAP, ``model = "dg"`` (:class:`DgCamera`) a
    DigitalGlobe / Maxar XML. The vendor's ephemeris, attitude and lines of sight are the nominal geometry;
    the adjustment estimates seed 001's corrections (``selfcal adjust --sensor-model M1 .. M7``, default M6).
    ``focal_mm``, ``pixel_size_mm``, ``columns`` and ``center_col`` come from the first image's file (the
    images of one camera share its focal length: the calibration parameter ``focal`` scales them together),
    ``width_px`` and ``height_px`` bound the image coordinates of all its images."""

    camera_id: str
    focal_mm: float = float("nan")
    pixel_size_mm: float = float("nan")
    columns: int = 0
    center_col: float = 0.0
    chip_starts: tuple = ()
    width_px: int = 0
    height_px: int = 0
    initial_ap = None

    model = "dimap"


@dataclass(frozen=True)
class DgCamera(DimapCamera):
    model = "dg"


class VendorLineBound(PushbroomBound):
    """Vendor line images: the nominal line camera of each image's record (no telemetry fit)."""

    def line_images(self, block, images, options):
        return {int(k): _line_image(block.image_models[str(block.images.image_id[k])], str(block.images.image_id[k]))
                for k in images}


class VendorLineSensor(PushbroomSensor):
    """Seed 001's pushbroom corrections on the vendor's physical model (:class:`DimapCamera`)."""

    needs_telemetry = False
    camera_keys = {"model": ("str", True)}

    def __init__(self, name: str, camera_type):
        self.name = name
        self.camera_type = camera_type

    bound_type = VendorLineBound

    def line_image(self, block, k, given_attitude=True):
        """The vendor's line camera of image ``k`` (its sensor_file as read)."""
        image_id = str(block.images.image_id[k])
        return _line_image(block.image_models[image_id], image_id)

    def check_camera(self, values):
        return []

    def configure_camera(self, camera, image_models):
        """The focal length, pixel size and detector line of the first image; every image of the camera has to
        share the focal length (a different one is another camera)."""
        from dataclasses import replace
        if not image_models:
            return camera
        lines = [line_image_from_record(m) for m in image_models]
        cams = [image.camera for image in lines]
        first = cams[0]
        other = [c.focal_mm for c in cams if abs(c.focal_mm - first.focal_mm) > 1e-9 * first.focal_mm]
        if other:
            raise ValueError(f"its images' sensor files differ in focal length ({first.focal_mm} and {other[0]} mm): "
                             f"give each its own camera")
        return replace(camera, focal_mm=float(first.focal_mm), pixel_size_mm=float(first.pixel_size_mm),
                       columns=int(first.columns), center_col=float(first.center_col),
                       chip_starts=tuple(first.chip_starts or ()), width_px=max(c.columns for c in cams),
                       height_px=max(image.rows for image in lines))


DIMAP_SENSOR = VendorLineSensor("dimap", DimapCamera)
DG_SENSOR = VendorLineSensor("dg", DgCamera)
