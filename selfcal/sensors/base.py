"""The sensor contract: what the adjustment engine asks of a sensor model.

The engine (:mod:`selfcal.adjust`) knows three kinds of unknowns: the parameters of each image
(a block of the same width for every image of a problem), the parameters of each camera (shared
by its images: a sensor's own *core* parameters, then the coefficients of an additional-parameter
basis) and the object points, which it eliminates. A sensor says what its image and core
parameters are (:class:`Parameter`: name, unit, group, whether screening may drop it) and, for
the images of a block that use it, provides through :meth:`Sensor.bind` a :class:`BoundSensor`:

* the observation vector ``l`` of every image point and its standard deviation, in the sensor's
  *observation units* (millimetres in the focal plane for cameras; any unit in which the
  sensor's prediction is smooth), fixed for the problem;
* the prediction ``f`` of each observation with analytic Jacobians for the image parameters, the
  camera core parameters and the object point (:meth:`BoundSensor.predict`); the engine whitens
  ``l - (f + Delta)`` by the standard deviation, ``Delta`` being the additional parameters'
  displacement, linear in their coefficients with the columns of :meth:`BoundSensor.ap_columns`;
* where an image has many parameters of which each observation touches few (a line image's jitter: local
  functions of time, :mod:`selfcal.sensors.pushbroom.jitter`), the same rows in compact form
  (:meth:`BoundSensor.working_columns`, :meth:`BoundSensor.predict_working`);
* the rays of image points (:meth:`BoundSensor.rays`: initial points by intersection), the
  image position of object points (:meth:`BoundSensor.pixels`), and residuals in pixels
  (:meth:`BoundSensor.pixel_residuals`) for the results.

Object points are Cartesian metres of the problem's object frame (the block's coordinates for a
frame camera, ECEF for satellite sensors). Pixels are DESIGN.md §2's: (col, row), (0, 0) the
upper-left corner of the upper-left pixel.

A sensor is one module with one :class:`Sensor` subclass, registered by name in
:data:`selfcal.sensors.SENSORS`; the engine never branches on a sensor's name.
"""
from __future__ import annotations

import weakref
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

if TYPE_CHECKING:
    from ..adjust.options import SensorOptions
    from ..ap.base import SparseBasis
    from ..block import Block
    from .rpc import RpcModel

__all__ = ["Parameter", "Sensor", "BoundSensor", "ImageGeometry", "WorkingColumns", "display_unit"]

#: code unit -> (unit in files and reports, factor)
_DISPLAY = {"rad": ("deg", float(np.degrees(1.0))), "rad/s": ("deg/s", float(np.degrees(1.0)))}


def display_unit(unit: str) -> tuple[str, float]:
    """The unit a value in code ``unit`` is written in, and the factor that converts it."""
    return _DISPLAY.get(unit, (unit, 1.0))


@dataclass(frozen=True)
class Parameter:
    """One parameter of a sensor model.

    ``group`` names the kind of unknown for correlation tables and the report: ``"EOP"`` for an
    image's orientation (or its corrections), ``"IOP"`` for a camera's interior orientation and
    calibration. ``screened``: whether AP screening may hold it at its start value (tested as
    ``t = |x - x_start| / sigma(x)``); a frame camera's orientation is never screened, seed 001's
    calibration parameters are.
    """

    name: str
    unit: str
    group: str
    screened: bool = False
    key: str | None = None          # its column / key in the results files (default: name and display unit)
    #: how far it can move from its start, as a share of it, before the solution is absurd (None: no bound;
    #: :mod:`selfcal.stats.plausibility`)
    plausible: float | None = None
    #: what screening tests it against and holds it at, where that is not its start value (a rolling shutter's
    #: readout: 0, the global shutter); None: its start value
    reference: float | None = None
    #: it enters each image's equations through data of the image that carry errors of their own (a rolling
    #: shutter's readout, through the image's velocity): its sigma in the results adds the spread of the images' own
    #: values beyond their noise (:mod:`selfcal.stats.image_spread`)
    spread_by_image: bool = False

    @property
    def display(self) -> tuple[str, float]:
        """The unit it is written in, and the factor from code units."""
        return display_unit(self.unit)

    @property
    def file_key(self) -> str:
        """Column of its value in images.csv, key in camera.json: ``omega_deg``, ``focal_mm``, ``k1``."""
        return self.key or _with_unit(self.name, self.display[0])

    @property
    def sigma_key(self) -> str:
        """Column of its a-posteriori sigma: ``sigma_X0_m``, ``sigma_omega_deg``."""
        return "sigma_" + _with_unit(self.name, self.display[0])


def _with_unit(name: str, unit: str) -> str:
    return f"{name}_{unit.replace('/', '_')}" if unit else name


@dataclass(frozen=True)
class ImageGeometry:
    """One adjusted image as ground <-> image functions, for handing it to other programs (an RPC).

    ``project(lon_deg, lat_deg, h_m) -> (row_px, col_px)`` and ``localize(row_px, col_px, h_m) -> (lon_deg,
    lat_deg)`` (NaN where a point has none), longitude and latitude on WGS 84, h above the ellipsoid, pixels
    DESIGN.md §2's; the image spans 0 .. ``rows_px`` and 0 .. ``cols_px``. ``height_range_m``: the heights the
    sensor's own description is valid for (an RPC's HEIGHT_OFF -/+ HEIGHT_SCALE), None where it states none.
    ``rpc``: an RPC (:class:`~selfcal.sensors.rpc.RpcModel`) that *is* the adjusted image, where one exists (a
    vendor RPC with a shift bias); otherwise None and an RPC has to be fitted."""

    image_id: str
    rows_px: float
    cols_px: float
    project: Callable
    localize: Callable
    height_range_m: tuple[float, float] | None = None
    rpc: RpcModel | None = None


@dataclass(frozen=True)
class WorkingColumns:
    """An image's *working columns*: a basis of its Jacobian rows in which each observation's row has few non-zero
    entries, although its row in the image parameters may have many (a line image's jitter functions, orthogonal to
    the attitude polynomial, are dense in time; the raw scaling functions and the powers they are made orthogonal
    to are local or few).

    ``to_parameters`` T (working, width), or one per image of the problem (n_images, working, width): an observation's
    row in the image parameters is its working row times its image's T, j_theta = j_w T (held parameters: the engine
    zeroes their columns of T). ``slots``: how many working columns an observation's row touches at most
    (:meth:`BoundSensor.predict_working`)."""

    to_parameters: np.ndarray
    slots: int

    @property
    def width(self) -> int:
        return int(self.to_parameters.shape[-2])


class BoundSensor(ABC):
    """A sensor model bound to the images of one problem that use it.

    Every array argument named ``o`` indexes the problem's image observations (sorted by point);
    ``img`` and ``cam`` are the observations' image and camera indices in the problem; ``points``
    (m, 3) their object points.
    """

    @property
    def problem(self) -> Any:
        """The problem it is bound to, held by a weak reference: the problem holds its bound sensors
        (``Problem.sensors``), and a strong reference back made every problem a reference cycle that only the
        interpreter's cyclic collector frees, late: the leave-one-out validation of a 200-image block had
        about 420 MB of its finished re-adjustments' problems alive at once (DESIGN-NOTES, "Plan before the run")."""
        problem = self._problem() if hasattr(self, "_problem") else None
        if problem is None:
            raise ReferenceError(f"{type(self).__name__}: the problem it was bound to no longer exists")
        return problem

    @problem.setter
    def problem(self, problem: Any) -> None:
        self._problem = weakref.ref(problem)

    @abstractmethod
    def observations(self) -> tuple[np.ndarray, np.ndarray]:
        """(l, sigma): the observation vector (m, 2) of the observations it was bound to (``o`` of
        :meth:`Sensor.bind`, in that order) and its standard deviation (m, 2), observation units."""

    def refine_sigma(self, state: Any, sigma: np.ndarray) -> None:
        """Give observations whose standard deviation in observation units depends on the geometry
        (a pushbroom image's motion per line) their value at ``state`` (the start values), in place."""

    @abstractmethod
    def context(self, state: Any, jacobians: bool = True) -> Any:
        """What :meth:`predict` needs of the current estimate, computed once per evaluation (rotations...);
        without ``jacobians``, what a :meth:`predict` without Jacobians needs (it may be cheaper)."""

    @abstractmethod
    def predict(self, context: Any, o: np.ndarray, img: np.ndarray, cam: np.ndarray, points: np.ndarray,
                jacobians: bool) -> Any:
        """f (m, 2) of observations ``o``; with ``jacobians`` also (f, j_image (m, 2, width), j_point (m, 2, 3),
        j_core (m, 2, n_core)): derivatives with respect to the image's parameters, the object point and
        the camera's core parameters."""

    def working_columns(self) -> WorkingColumns | None:
        """The images' :class:`WorkingColumns` (the same for every image it binds), or None: :meth:`predict`'s rows
        in the image parameters are compact enough (the default)."""
        return None

    def predict_working(self, context: Any, o: np.ndarray, img: np.ndarray, cam: np.ndarray,
                        points: np.ndarray) -> tuple:
        """:meth:`predict` with Jacobians, the image rows in :meth:`working_columns`' compact form: (f, j_w (m, 2,
        slots), columns (m, slots) int64, j_point, j_core), j_w[o, :, s] the derivative with respect to working
        column ``columns[o, s]`` (a slot an observation does not need holds 0.0 and any valid column)."""
        raise NotImplementedError(f"{type(self).__name__} has no working columns")

    def ap_columns(self, camera: int, o: np.ndarray, ap: Any, out: np.ndarray | None = None) -> np.ndarray:
        """Delta per unit coefficient (n, 2, n_ap) of ``ap`` (the camera's additional parameters) at
        observations ``o`` of that camera, in observation units. Constant over the adjustment. With ``out``
        (n, 2, n_ap, possibly a strided view), written there and returned."""
        raise NotImplementedError(f"{type(self).__name__} takes no additional parameters")

    def sparse_ap_columns(self, camera: int, o: np.ndarray, ap: Any) -> SparseBasis | None:
        """:meth:`ap_columns` as a :class:`selfcal.ap.base.SparseBasis` (values in observation units), or None
        where ``ap``'s rows are dense or the sensor does not give them so (the default)."""
        return None

    @abstractmethod
    def rays(self, context: Any, img: np.ndarray, pixel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Origins (m, 3) and unit directions (m, 3) of the rays of image points (col, row) in images ``img``
        (object frame; the additional parameters left out)."""

    @abstractmethod
    def pixels(self, context: Any, img: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(col, row) (m, 2) of object points in images ``img``, additional parameters excluded (NaN
        where a point does not image)."""

    def ground_sample_distance(self, state: Any) -> float | None:
        """Mean ground sample distance (m) of its images at ``state``; None where it has no meaning."""
        return None

    def height(self, points: np.ndarray) -> np.ndarray:
        """Heights (m) of object points above the reference surface :meth:`ground` takes heights on."""
        raise NotImplementedError(f"{type(self).__name__} has no reference surface")

    def ground(self, context: Any, img: np.ndarray, pixel: np.ndarray,
               height: float | Callable[[np.ndarray, np.ndarray], np.ndarray]) -> np.ndarray:
        """Mono restitution: object points (m, 3) where the rays of image points (col, row) in images ``img``
        meet ``height`` (metres above the ellipsoid, or a callable ``height(lat_deg, lon_deg)``: a DEM)."""
        raise NotImplementedError(f"{type(self).__name__} has no mono restitution")

    def undetermined_image_parameters(self, images: np.ndarray) -> np.ndarray | None:
        """(n, width) bool: the image parameters of ``images`` its observations cannot determine (a local basis
        function of time with too few observations in its support), held by the problem; None: none."""
        return None

    @abstractmethod
    def pixel_residuals(self, o: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Residuals v (m, 2) of observations ``o`` in observation units, as (v_col, v_row) pixels."""


class Sensor(ABC):
    """A sensor model: its parameters and how its images are bound to a problem."""

    #: registry name (``model =`` of a camera in block.toml)
    name: str = ""
    #: the parameters of every image (the engine's image block)
    image_parameters: tuple[Parameter, ...] = ()
    #: the camera's own parameters, shared by its images (before any additional parameters)
    camera_parameters: tuple[Parameter, ...] = ()
    #: the domain of the additional parameters it takes: "frame" (over the image), "line" (along a
    #: detector line) or None
    ap_domain: str | None = None
    #: the object frame its points live in: "block" (the block's coordinates) or "ECEF"
    object_frame: str = "block"
    #: an image with fewer observed points is left out of an adjustment (selfcal.block.prune)
    min_points_per_image: int = 6
    #: its camera in a block (a plain dataclass) and the block.toml keys of ``[cameras.ID]``: key -> (type,
    #: required), types as selfcal.io.block_folder checks them ("str", "int", "pos", "num", "nonneg", ...)
    camera_type: type
    camera_keys: dict = {}
    #: sub-tables ``[cameras.ID.NAME]`` its cameras take (a frame camera's ``initial_ap``)
    camera_tables: tuple[str, ...] = ()
    #: whether its images need the block's telemetry (ephemeris.csv, attitude.csv)
    needs_telemetry: bool = False
    #: whether a point behind one of its cameras at a solution means the block folded (a central projection: its
    #: mirror image fits; :mod:`selfcal.stats.plausibility`)
    central_projection: bool = False
    #: whether block.toml's ``model = NAME`` names it; False for a variant that a camera's other keys choose (a frame
    #: camera with ``shutter = "rolling"``: the camera's ``sensor``)
    selectable: bool = True
    #: the named parameter sets it offers (seed 001's M1 ... M7), chosen by SensorOptions.model; with
    #: them come seed 001's workflow steps (focal-length calibration, GCP layouts, mono restitution)
    sensor_models: tuple[str, ...] = ()

    @property
    def image_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.image_parameters)

    @property
    def camera_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.camera_parameters)

    def configured(self, options: SensorOptions) -> "Sensor":
        """This sensor as ``options`` ask for it in one adjustment: itself, or a copy whose parameters depend on them
        (a line scanner's attitude jitter: more image parameters). The problem keeps what this returns."""
        return self

    @abstractmethod
    def bind(self, problem: Any, block: Block, o: np.ndarray, pixel: np.ndarray, sigma_px: np.ndarray,
             options: SensorOptions) -> BoundSensor:
        """Bind to ``problem`` its observations ``o`` (positions in the problem's sorted order) in the images that
        use this sensor: measured at ``pixel`` (m, 2; col, row) with standard deviations ``sigma_px`` (m,, pixels).
        ``block`` gives their cameras and sensor descriptions, ``options`` are the adjustment's :class:`~selfcal.adjust.SensorOptions`."""

    def result_files(self, result: Any, slot: Any) -> dict:
        """Files of its own for the results folder (DESIGN.md §4: a sensor adds, never renames): name -> a dict
        (JSON) or a (header, columns, formats) table, from the adjustment ``result`` of the images ``slot``."""
        return {}

    def configure_camera(self, camera: Any, image_models: list) -> Any:
        """The camera completed from its images' sensor descriptions (sensor_file), as read."""
        return camera

    def check_camera(self, values: dict) -> list[tuple[str, str]]:
        """Defects of a camera's block.toml values that the key types do not catch: (key, reason) each."""
        return []

    def initial_images(self, bound: BoundSensor, block: Block, image_index: np.ndarray) -> np.ndarray:
        """Start values (n, width) of the image parameters; NaN where the sensor cannot give one (a
        frame image without orientation, oriented later by space resection)."""
        return np.zeros((len(image_index), len(self.image_parameters)))

    def camera_setup(self, camera: Any, options: SensorOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(start value, free, a-priori sigma) of the camera's core parameters (NaN sigma: no prior)."""
        n = len(self.camera_parameters)
        return np.zeros(n), np.ones(n, bool), np.full(n, np.nan)

    def create_ap(self, spec: str, camera: Any, observed: np.ndarray, settings: dict,
                  model: Any = None) -> tuple[Any, np.ndarray]:
        """(the additional-parameter model ``spec`` of ``camera`` (a block camera), or ``model`` when given,
        and its initial coefficients); ``observed`` are the camera's observation vectors (adaptive bases).
        Sensors without additional parameters take ``none`` only."""
        from ..ap.none import NoAP
        from ..errors import UsageError
        if model is not None:
            return model, np.zeros(model.n_params)
        if spec.strip().lower() != "none":
            raise UsageError(f"AP model {spec}: {self.name} cameras take no additional parameters")
        return NoAP(None), np.zeros(0)

    def image_setup(self, block: Block, image_index: np.ndarray, options: SensorOptions) -> tuple[np.ndarray, np.ndarray]:
        """(free (n, width), a-priori sigma (n, width)) of the image parameters; NaN sigma: no prior."""
        shape = (len(image_index), len(self.image_parameters))
        return np.ones(shape, bool), np.full(shape, np.nan)

    def image_geometry(self, block: Block, k: int, image_parameters: np.ndarray,
                       camera_parameters: np.ndarray) -> ImageGeometry:
        """Image ``k`` of ``block`` with the adjusted values of its :attr:`image_parameters` and of its camera's
        :attr:`camera_parameters` (code units, in their order) as an :class:`ImageGeometry`. Sensors whose images
        are not on the Earth's ellipsoid, or have no such hand-over, raise NotImplementedError saying why."""
        raise NotImplementedError(f"a {self.name} image cannot be handed over as ground <-> image functions on "
                                  f"WGS 84 (only rpc and the Earth's line scanners can)")
