"""SPOT 5 (HRS, HRG) DIMAP level 1A metadata (``METADATA.DIM``, root ``Dimap_Document``): the physical model.

Read as the file gives it (SPOT 1-5 DIMAP profile ``SPOTSCENE_1A`` / ``SPOTSEGMENT_1A``):

* ``Raster_Dimensions/NCOLS, NROWS``; ``Raster_CS/PIXEL_ORIGIN`` (1: pixel centres are 1-based) and
  ``RASTER_CS_TYPE`` (POINT);
* ``Dataset_Frame/Vertex`` (4): ``FRAME_LON``, ``FRAME_LAT`` (degrees, WGS 84, on the ellipsoid as the
  ``Geoposition`` tie points' ``TIE_POINT_CRS_Z`` 0 says), ``FRAME_ROW``, ``FRAME_COL`` (1-based);
  ``Geoposition/Geoposition_Points/Tie_Point`` the same corners with their image coordinates;
* ``Data_Strip/Ephemeris/Points/Point``: ``Location/X, Y, Z`` (m) and ``Velocity/X, Y, Z`` (m/s), Earth-fixed
  (ITRF, "GCC"), at ``TIME`` (UTC), every 30 s;
* ``Data_Strip/Satellite_Attitudes/Corrected_Attitudes/Corrected_Attitude/Angles``: ``YAW``, ``PITCH``,
  ``ROLL`` (rad) at ``TIME``, every 0.125 s (the raw AOCS angles and star-tracker quaternions are not used, as
  by ASP);
* ``Data_Strip/Sensor_Configuration/Time_Stamp``: ``LINE_PERIOD`` (s), ``SCENE_CENTER_TIME``,
  ``SCENE_CENTER_LINE``, ``SCENE_CENTER_COL`` (1-based);
* ``Sensor_Configuration/Instrument_Look_Angles_List/Instrument_Look_Angles/Look_Angles_List/Look_Angles``:
  ``DETECTOR_ID`` (1-based), ``PSI_X``, ``PSI_Y`` (rad) of every detector (SPOT 1-4 list the first and last
  detector only: the angles between are linear, as ASP reads them).

Times are seconds after the first ephemeris point. Building a selfcal line camera from it is
:func:`selfcal.sensors.spot.line_image_from_spot5`.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .xmldoc import XmlDocument, iso_utc, seconds_between

__all__ = ["Spot5Sensor", "read_spot5", "SPOT_PIXEL_ORIGIN"]

#: image coordinate of the first pixel's centre in SPOT DIMAP (Raster_CS/PIXEL_ORIGIN)
SPOT_PIXEL_ORIGIN = 1.0


@dataclass(frozen=True)
class Spot5Sensor:
    path: str
    mission: str                         # e.g. "SPOT 5 HRS 1"
    rows: int
    columns: int
    pixel_origin: float                  # Raster_CS/PIXEL_ORIGIN
    epoch_utc: str                       # the first ephemeris point's time: every time below counts from it
    corners: np.ndarray                  # (4, 4): FRAME_COL, FRAME_ROW, FRAME_LON, FRAME_LAT of Dataset_Frame
    tie_points: np.ndarray               # (k, 5): DATA_X (col), DATA_Y (row), CRS_X (lon), CRS_Y (lat), CRS_Z (h)
    line_period_s: float
    center_time_s: float                 # SCENE_CENTER_TIME
    center_line: float                   # SCENE_CENTER_LINE (1-based, as in the file)
    center_col: float                    # SCENE_CENTER_COL (1-based)
    ephemeris_t_s: np.ndarray            # (n,)
    positions_m: np.ndarray              # (n, 3) Earth-fixed
    velocities_m_s: np.ndarray           # (n, 3)
    attitude_t_s: np.ndarray             # (m,)
    yaw_pitch_roll_rad: np.ndarray       # (m, 3) Corrected_Attitude
    detector_ids: np.ndarray             # (c,) 1-based
    psi_x_rad: np.ndarray                # (c,) along track
    psi_y_rad: np.ndarray                # (c,) across track


def _table(doc: XmlDocument, items: list, keys: tuple, start) -> tuple[np.ndarray, np.ndarray]:
    """(times (n,), values (n, len(keys))) of elements with a TIME and numeric children, times increasing."""
    times = np.array([seconds_between(start, doc.utc(item, "TIME")) for item in items])
    values = np.array([[doc.number(item, key) for key in keys] for item in items])
    bad = np.flatnonzero(np.diff(times) <= 0)
    if bad.size:
        item = items[bad[0] + 1]
        raise doc.error(item, f"{doc.name(item)}/TIME must increase", f"{doc.name(item)}/TIME")
    return times, values


def read_spot5(path: str | os.PathLike) -> Spot5Sensor:
    """Read the physical model of a SPOT 5 DIMAP file; errors name the file, the line and the element."""
    path = str(path)
    doc = XmlDocument(path, "SPOT DIMAP file")
    root = doc.root
    if root.tag != "Dimap_Document":
        raise doc.error(root, f"root element is {root.tag!r}, not 'Dimap_Document': not a SPOT DIMAP file")
    strip = doc.node(root, "Data_Strip")
    source = doc.find(root, "Dataset_Sources/Source_Information/Scene_Source")
    mission = "SPOT"
    if source is not None:
        parts = [doc.find(source, key) for key in ("MISSION", "MISSION_INDEX", "INSTRUMENT", "INSTRUMENT_INDEX")]
        mission = " ".join((p.text or "").strip() for p in parts if p is not None) or mission

    # --- ephemeris (its first time is the reference)
    points = doc.children(doc.node(doc.node(strip, "Ephemeris"), "Points"), "Point")
    if len(points) < 4:
        raise doc.error(strip, f"Ephemeris/Points has {len(points)} Point; at least 4 are needed",
                        "Dimap_Document/Data_Strip/Ephemeris/Points")
    start = doc.utc(points[0], "TIME")
    t_eph, position = _table(doc, points, ("Location/X", "Location/Y", "Location/Z"), start)
    _, velocity = _table(doc, points, ("Velocity/X", "Velocity/Y", "Velocity/Z"), start)

    # --- attitude
    corrected = doc.node(strip, "Satellite_Attitudes/Corrected_Attitudes/Corrected_Attitude")
    angles = doc.children(corrected, "Angles")
    if len(angles) < 2:
        raise doc.error(corrected, f"Corrected_Attitude has {len(angles)} Angles; at least 2 are needed",
                        doc.name(corrected))
    t_att, ypr = _table(doc, angles, ("YAW", "PITCH", "ROLL"), start)
    out_of_range = [a for a in angles if (a.findtext("OUT_OF_RANGE") or "N").strip().upper() == "Y"]
    if out_of_range:
        raise doc.error(out_of_range[0], "an attitude sample is flagged OUT_OF_RANGE",
                        f"{doc.name(corrected)}/Angles/OUT_OF_RANGE")

    # --- line times and look angles
    configuration = doc.node(strip, "Sensor_Configuration")
    stamp = doc.node(configuration, "Time_Stamp")
    period = doc.number(stamp, "LINE_PERIOD")
    if period <= 0:
        raise doc.error(doc.node(stamp, "LINE_PERIOD"), "LINE_PERIOD must be positive",
                        doc.name(stamp) + "/LINE_PERIOD")
    looks = doc.node(configuration, "Instrument_Look_Angles_List/Instrument_Look_Angles/Look_Angles_List")
    table = np.array([[doc.number(item, key) for key in ("DETECTOR_ID", "PSI_X", "PSI_Y")]
                      for item in doc.children(looks, "Look_Angles")])
    rows, columns = (doc.integer(doc.node(root, "Raster_Dimensions"), key, minimum=1) for key in ("NROWS", "NCOLS"))
    if len(table) == 2 and columns > 2:                 # SPOT 1-4: first and last detector, linear between
        f = np.linspace(0.0, 1.0, columns)[:, None]
        table = np.column_stack([np.arange(1, columns + 1), (1 - f) * table[0, 1:] + f * table[1, 1:]])
    if len(table) != columns:
        raise doc.error(looks, f"Look_Angles_List has {len(table)} Look_Angles for NCOLS {columns}", doc.name(looks))
    if np.any(np.diff(table[:, 0]) != 1):
        raise doc.error(looks, "DETECTOR_ID must count up by one", doc.name(looks) + "/Look_Angles/DETECTOR_ID")

    # --- corners
    frame = doc.node(root, "Dataset_Frame")
    corners = np.array([[doc.number(v, key) for key in ("FRAME_COL", "FRAME_ROW", "FRAME_LON", "FRAME_LAT")]
                        for v in doc.children(frame, "Vertex")])
    if len(corners) != 4:
        raise doc.error(frame, f"Dataset_Frame has {len(corners)} Vertex, not 4", "Dimap_Document/Dataset_Frame")
    ties = doc.find(root, "Geoposition/Geoposition_Points")
    tie_points = np.zeros((0, 5)) if ties is None else np.array(
        [[doc.number(p, key) for key in ("TIE_POINT_DATA_X", "TIE_POINT_DATA_Y", "TIE_POINT_CRS_X", "TIE_POINT_CRS_Y",
                                         "TIE_POINT_CRS_Z")] for p in doc.children(ties, "Tie_Point")]).reshape(-1, 5)
    raster_cs = doc.find(root, "Raster_CS")
    origin = SPOT_PIXEL_ORIGIN
    if raster_cs is not None and doc.find(raster_cs, "PIXEL_ORIGIN") is not None:
        origin = doc.number(raster_cs, "PIXEL_ORIGIN")
    if raster_cs is not None and doc.find(raster_cs, "RASTER_CS_TYPE") is not None:
        kind = doc.text(raster_cs, "RASTER_CS_TYPE").upper()
        if kind not in ("POINT", "CELL"):
            raise doc.error(raster_cs, f"RASTER_CS_TYPE must be POINT or CELL, not {kind!r}",
                            "Dimap_Document/Raster_CS/RASTER_CS_TYPE")
        origin += 0.5 if kind == "CELL" else 0.0
    return Spot5Sensor(
        path=path, mission=mission, rows=rows, columns=columns, pixel_origin=float(origin), epoch_utc=iso_utc(start),
        corners=corners, tie_points=tie_points, line_period_s=period,
        center_time_s=seconds_between(start, doc.utc(stamp, "SCENE_CENTER_TIME")),
        center_line=doc.number(stamp, "SCENE_CENTER_LINE"), center_col=doc.number(stamp, "SCENE_CENTER_COL"),
        ephemeris_t_s=t_eph, positions_m=position, velocities_m_s=velocity, attitude_t_s=t_att,
        yaw_pitch_roll_rad=ypr, detector_ids=table[:, 0].astype(int), psi_x_rad=table[:, 1], psi_y_rad=table[:, 2])
