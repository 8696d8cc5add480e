"""The RPC of an adjusted image (``selfcal export rpc``): the vendor RPC with its bias folded in, or an RPC fitted
to the adjusted model. ``rows_px``, ``cols_px`` of the result are the image's size as the sensor knows it (an RPC
image without ``width_px``/``height_px``: its RPC's normalisation), for checking a raster it is attached to.

The results folder holds the adjusted values (parameters.csv: every image and camera parameter, in the files'
units) but not the sensor descriptions they correct (an image's vendor RPC, its DIMAP or DigitalGlobe metadata, a
pushbroom camera's telemetry): those stay in the block folder, which the caller reads (``--block``). The sensor of
the image's camera turns both into an :class:`~selfcal.sensors.base.ImageGeometry`
(:meth:`~selfcal.sensors.base.Sensor.image_geometry`); then

* an ``rpc`` image whose bias has no linear terms (``bias = "shift"`` or ``"none"``) *is* an RPC: the shift is
  folded into LINE_OFF and SAMP_OFF, exactly (:func:`~selfcal.sensors.rpc.shifted_rpc`);
* any other image (an affine bias, a rigorous line scanner: ``pushbroom``, ``dimap``, ``dg``) gets an RPC fitted on
  a 3-D grid over the image and its height range (:func:`~selfcal.sensors.rpc_fit.fit_rpc`, Tao & Hu 2001), with
  its misfit on an independent check grid.

Pixels: the models here are in selfcal's pixels (DESIGN.md §2; a fitted RPC has ``pixel_origin`` 0.5, a vendor RPC
keeps its file's); the writers of :mod:`selfcal.io.rpc_gdal` move the offsets to GDAL's convention (the centre of the
first pixel at line, sample 0, 0: line = row - 0.5), which GDAL's transformer turns back into corner-based pixels
equal to selfcal's.

Height range of the fit: ``heights_m`` when given; else the image's own RPC's (HEIGHT_OFF -/+ HEIGHT_SCALE); else
the adjusted points' ellipsoidal heights widened by :data:`HEIGHT_MARGIN` of their span (at least
:data:`HEIGHT_MARGIN_MIN_M`) on each side.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import BlockError, UsageError
from ..geometry.earth import geodetic_from_ecef
from ..sensors import sensor_of
from ..sensors.rpc import RpcModel
from ..sensors.rpc_fit import FIT_GRID, RpcFit, fit_rpc

__all__ = ["AdjustedRpc", "adjusted_rpc", "image_parameter_values", "points_height_range", "HEIGHT_MARGIN",
           "HEIGHT_MARGIN_MIN_M"]

#: the fit's heights beyond the adjusted points' range, as a fraction of it on each side ...
HEIGHT_MARGIN = 0.1
#: ... and at least this (m)
HEIGHT_MARGIN_MIN_M = 100.0


@dataclass(frozen=True)
class AdjustedRpc:
    """The RPC of one adjusted image: ``exact`` when it is the vendor RPC with its shift folded in, else ``fit``
    holds the fit and its misfit (px). ``model`` is in selfcal's pixels (a writer moves it to its format's)."""

    image_id: str
    sensor: str
    model: RpcModel
    exact: bool
    fit: RpcFit | None
    heights_m: tuple[float, float] | None
    grid: tuple[int, int, int] | None
    rows_px: float
    cols_px: float


def image_parameter_values(table: dict, owner: str, parameters, path: str = "parameters.csv") -> np.ndarray:
    """The values (code units, in the order of ``parameters``, a sensor's :class:`~selfcal.sensors.base.Parameter`
    tuple) of ``owner``'s parameters in a parameters.csv table (file units: :attr:`Parameter.display`)."""
    owners, names = np.asarray(table["owner"]).astype(str), np.asarray(table["parameter"]).astype(str)
    out = np.zeros(len(parameters))
    for k, p in enumerate(parameters):
        hit = np.flatnonzero((owners == owner) & (names == p.name))
        if hit.size != 1:
            raise BlockError(path, f"{'no' if not hit.size else 'more than one'} row for parameter {p.name} of "
                                   f"{owner}", column="parameter")
        value = float(table["value"][hit[0]])
        if not np.isfinite(value):
            raise BlockError(path, f"parameter {p.name} of {owner} has no value", int(hit[0]) + 2, "value")
        out[k] = value / p.display[1]
    return out


def points_height_range(xyz: np.ndarray) -> tuple[float, float] | None:
    """The ellipsoidal heights of adjusted points (results points.csv X, Y, Z: ECEF metres, the object frame of the
    satellite sensors, in which their results are written) widened by the margins (module docstring); None without
    points near the Earth's surface (6200-6600 km from its centre)."""
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    ecef = xyz[np.all(np.isfinite(xyz), axis=1)]
    if not len(ecef):
        return None
    radius = np.linalg.norm(ecef, axis=1)
    if np.any((radius < 6.2e6) | (radius > 6.6e6)):
        return None
    h = geodetic_from_ecef(ecef)[2]
    span = float(np.max(h) - np.min(h))
    margin = max(HEIGHT_MARGIN * span, HEIGHT_MARGIN_MIN_M)
    return float(np.min(h)) - margin, float(np.max(h)) + margin


def _check_camera(entry, camera_id: str, model: str, image_id: str) -> None:
    if not isinstance(entry, dict) or entry.get("model") != model:
        raise UsageError(f"camera {camera_id} ({model}) of the block is not in the results' camera.json as such: are "
                         f"RESULTS an adjustment of --block?")
    if (entry.get("ap") or {}).get("n_active"):
        raise UsageError(f"--image {image_id}: camera {camera_id} has {entry['ap']['n_active']} active additional "
                         f"parameters ({entry['ap'].get('spec')}); the RPC export does not carry them")


def adjusted_rpc(block, parameters: dict, image_id: str, heights_m=None, points_heights_m=None,
                 grid=FIT_GRID, cameras: dict | None = None) -> AdjustedRpc:
    """The RPC of image ``image_id`` of ``block`` adjusted by a parameters.csv table (module docstring).

    ``heights_m`` (min, max) overrides the fit's height range; ``points_heights_m`` is the fallback from the
    adjusted points (:func:`points_height_range`). ``cameras`` (camera.json's ``cameras`` of the same results)
    checks that the results are the block's (the camera there with the block's model) and that the camera has no
    active additional parameters (line APs are not in the hand-over). UsageError where they are not, where the
    image's sensor has no RPC hand-over, or where no height range is known.
    """
    ids = [str(i) for i in block.images.image_id]
    if image_id not in ids:
        raise UsageError(f"--image {image_id}: not an image of the block (it has: {', '.join(ids[:20])})")
    k = ids.index(image_id)
    camera_id = str(block.images.camera_id[k])
    camera = block.cameras[camera_id]
    if cameras is not None:
        _check_camera(cameras.get(camera_id), camera_id, camera.model, image_id)
    sensor = sensor_of(camera)
    image_values = image_parameter_values(parameters, image_id, sensor.image_parameters)
    camera_values = image_parameter_values(parameters, camera_id, sensor.camera_parameters)
    try:
        geometry = sensor.image_geometry(block, k, image_values, camera_values)
    except NotImplementedError as exc:
        raise UsageError(f"--image {image_id}: camera {camera_id} (model {camera.model!r}): {exc}") from None
    if geometry.rpc is not None:
        return AdjustedRpc(image_id, sensor.name, geometry.rpc, True, None, geometry.height_range_m, None,
                           geometry.rows_px, geometry.cols_px)
    heights = heights_m or geometry.height_range_m or points_heights_m
    if heights is None:
        raise UsageError(f"--image {image_id}: no height range for the fit (the results hold no adjusted point on "
                         f"the Earth): give --heights MIN,MAX")
    try:
        fit = fit_rpc(geometry.project, geometry.localize, geometry.rows_px, geometry.cols_px, heights, grid)
    except ValueError as exc:
        raise UsageError(f"--image {image_id}: cannot fit an RPC: {exc}") from None
    return AdjustedRpc(image_id, sensor.name, fit.model, False, fit, tuple(heights), tuple(grid), geometry.rows_px,
                       geometry.cols_px)
