"""Pleiades DIMAP (``PHRDIMAP_*.XML``): the physical sensor model of a sensor-geometry product.

Read from ``Geometric_Data/Sensor_Model_Characteristics``, as the file gives it:

* ``UTC_Sensor_Model_Range/START``: the time of the first image row (rows are 1-based at pixel
  centres, as the product's ``PIXEL_ORIGIN`` 1 says);
* ``SENSOR_LINE_PERIOD`` (ms);
* ``Sensor_Ephemeris/Point_List``: Earth-fixed (WGS 84) positions (m) and velocities (m/s) at UTC times;
* ``Sensor_Attitudes/Polynomial_Models``: the attitude quaternion components Q0 (scalar) .. Q3 as
  polynomials in (t - OFFSET) / SCALE, t in seconds of the UTC day of START;
* ``Sensor_Viewing_Model``: the look angles PsiX, PsiY (rad) of the detectors as polynomials in
  the retina column (``FIRST_COL`` .. ``LAST_COL``).

Times are returned in seconds from START. Building a selfcal line camera from it is
:func:`selfcal.sensors.dimap.line_image_from_dimap`.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass
from datetime import datetime

import numpy as np

from ..errors import BlockError
from .xmlfile import xml_root

__all__ = ["DimapSensor", "read_dimap_sensor"]


@dataclass(frozen=True)
class DimapSensor:
    path: str
    start_utc: str                       # ISO 8601: the time of row 1 (times below count from it)
    rows: int
    columns: int
    line_period_s: float
    ephemeris_t_s: np.ndarray            # (n,)
    positions_m: np.ndarray              # (n, 3) ECEF
    velocities_m_s: np.ndarray           # (n, 3)
    attitude_offset_s: float             # polynomial time (t_s - offset) / scale, t_s from START
    attitude_scale_s: float
    quaternion_polynomials: tuple        # Q0 (scalar) .. Q3: coefficients, lowest degree first
    psi_x: tuple                         # coefficients in the retina column, rad
    psi_y: tuple
    first_retina_col: int


def _utc(text: str) -> datetime:
    return datetime.fromisoformat(text.strip().replace("Z", "+00:00"))


def read_dimap_sensor(path: str | os.PathLike) -> DimapSensor:
    """Read the physical model of a Pleiades DIMAP file; errors name the file and the element."""
    path = str(path)
    root = xml_root(path, "DIMAP file")
    model = root.find("Geometric_Data/Sensor_Model_Characteristics")
    if model is None:
        raise BlockError(path, "no Geometric_Data/Sensor_Model_Characteristics: not a DIMAP file with the physical "
                               "sensor model")

    def text(node, key: str, where: str = "Sensor_Model_Characteristics") -> str:
        found = node.find(key)
        if found is None or found.text is None:
            raise BlockError(path, f"missing element {where}/{key}")
        return found.text

    def numbers(node, key: str, where: str = "Sensor_Model_Characteristics") -> np.ndarray:
        value = text(node, key, where)
        try:
            array = np.array(value.split(), float)
        except ValueError:
            array = np.array([np.nan])
        if not np.all(np.isfinite(array)) or np.any(np.abs(array) > 1e100):
            raise BlockError(path, f"must be finite numbers, found {value.strip()[:60]!r}",
                             column=f"{where}/{key}")
        return array

    def number(node, key: str, where: str = "Sensor_Model_Characteristics", positive: bool = False) -> float:
        array = numbers(node, key, where)
        if array.size != 1 or positive and not array[0] > 0:
            raise BlockError(path, f"must be one {'positive ' if positive else ''}number, found "
                                   f"{text(node, key, where).strip()[:60]!r}", column=f"{where}/{key}")
        return float(array[0])

    def integer(node, key: str, where: str, low: int) -> int:
        value = text(node, key, where).strip()
        if not re.fullmatch(r"[+-]?[0-9]{1,12}", value) or int(value) < low:
            raise BlockError(path, f"must be an integer of at least {low}, found {value[:60]!r}",
                             column=f"{where}/{key}")
        return int(value)

    def utc(node, key: str, where: str = "Sensor_Model_Characteristics") -> datetime:
        value = text(node, key, where)
        try:
            return _utc(value)
        except ValueError:
            raise BlockError(path, f"must be an ISO 8601 UTC time, found {value.strip()[:60]!r}",
                             column=f"{where}/{key}") from None

    start = utc(model, "UTC_Sensor_Model_Range/START")
    day = start.replace(hour=0, minute=0, second=0, microsecond=0)
    points = model.findall("Sensor_Ephemeris/Point_List/Point")
    if len(points) < 4:
        raise BlockError(path, f"Sensor_Ephemeris/Point_List has {len(points)} points; at least 4 are needed")
    where = "Sensor_Ephemeris/Point_List/Point"
    try:
        t = np.array([(utc(p, "UTC_TIME", where) - start).total_seconds() for p in points])
    except TypeError:                                        # one time with a zone, another without
        raise BlockError(path, f"{where}/UTC_TIME: times with and without a time zone", column="UTC_TIME") from None
    for p in points:
        for key, unit in (("LOCATION_VALUES", "m"), ("VELOCITY_VALUES", "m/s")):
            found = p.find(key)
            if found is not None and found.get("unit", unit) != unit:
                raise BlockError(path, f"is in '{found.get('unit')}'; expected '{unit}'",
                                 column=f"{where}/{key}")
    positions = np.array([numbers(p, "LOCATION_VALUES", where) for p in points])
    velocities = np.array([numbers(p, "VELOCITY_VALUES", where) for p in points])
    if positions.shape != (len(points), 3) or velocities.shape != (len(points), 3):
        raise BlockError(path, f"{where}: LOCATION_VALUES and VELOCITY_VALUES need 3 numbers each")
    if np.any(np.diff(t) <= 0):
        raise BlockError(path, f"{where}/UTC_TIME must increase")
    attitudes = model.find("Sensor_Attitudes")
    if attitudes is None:
        raise BlockError(path, "missing element Sensor_Model_Characteristics/Sensor_Attitudes")
    quaternions = []
    for name in ("Q0", "Q1", "Q2", "Q3"):
        coefficients = numbers(attitudes, f"Polynomial_Models/{name}/COEFFICIENTS", "Sensor_Attitudes")
        degree = integer(attitudes, f"Polynomial_Models/{name}/DEGREE", "Sensor_Attitudes", 0)
        if len(coefficients) != degree + 1:
            raise BlockError(path, f"Sensor_Attitudes/{name}: {len(coefficients)} coefficients for degree {degree}")
        quaternions.append(tuple(coefficients))
    offset_sod = number(attitudes, "OFFSET", "Sensor_Attitudes")
    scale = number(attitudes, "SCALE", "Sensor_Attitudes", positive=True)
    viewing = "Sensor_Viewing_Model/Viewing_Directions"
    psi = [tuple(numbers(model, f"{viewing}/{name}/COEFFICIENTS")) for name in ("PsiX_Model", "PsiY_Model")]
    rows = integer(root, "Raster_Dimensions/NROWS", "PHR_Dimap_Document", 1)
    columns = integer(root, "Raster_Dimensions/NCOLS", "PHR_Dimap_Document", 1)
    return DimapSensor(
        path=path, start_utc=start.isoformat().replace("+00:00", "Z"), rows=rows, columns=columns,
        line_period_s=number(model, "SENSOR_LINE_PERIOD", positive=True) * 1e-3,
        ephemeris_t_s=t, positions_m=positions, velocities_m_s=velocities,
        attitude_offset_s=offset_sod - (start - day).total_seconds(), attitude_scale_s=scale,
        quaternion_polynomials=tuple(quaternions), psi_x=psi[0], psi_y=psi[1],
        first_retina_col=integer(model, "Sensor_Viewing_Model/Position_In_Retina/FIRST_COL",
                                 "Sensor_Model_Characteristics", 0))
