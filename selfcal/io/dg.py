"""DigitalGlobe / Maxar image support data in one XML file (root ``isd``): the rigorous line camera.

Read as the file gives it (the blocks of DigitalGlobe's ISD: IMD, EPH, ATT, GEO, and RPB when present):

* ``IMD``: ``NUMROWS``, ``NUMCOLUMNS``, ``BANDID``; ``IMAGE/SATID``, ``SCANDIRECTION``, ``TLCTIME``,
  ``NUMTLC`` and ``TLCLISTList/TLCLIST`` (pairs *line, seconds after TLCTIME*: the time of each listed
  image line), ``FIRSTLINETIME``, ``AVGLINERATE`` (lines per second);
* ``EPH``: ``STARTTIME``, ``TIMEINTERVAL``, ``NUMPOINTS`` and ``EPHEMLISTList/EPHEMLIST``, each *index
  (1-based), X, Y, Z (m), VX, VY, VZ (m/s)* in the Earth-fixed frame (ECF, WGS 84) and 6 covariance terms
  (m², upper triangle of the position covariance);
* ``ATT``: the same times, ``ATTLISTList/ATTLIST``, each *index, q1, q2, q3, q4* and 10 covariance terms: the
  unit quaternion (q4 the scalar) rotating satellite-body vectors into the Earth-fixed frame;
* ``GEO``: ``PRINCIPAL_DISTANCE/PD`` (mm), ``OPTICAL_DISTORTION`` (``POLYORDER``, ``ALIST``, ``BLIST``; only
  zero coefficients are accepted: no distortion model is implemented), ``PERSPECTIVE_CENTER/CX, CY, CZ`` (m,
  body frame), ``CAMERA_ATTITUDE/QCS1..QCS4`` (camera -> body, QCS4 scalar) and
  ``DETECTOR_MOUNTING/BAND_<BANDID>/DETECTOR_ARRAY``: ``DETORIGINX``, ``DETORIGINY`` (mm, the focal-plane
  position of the first detector's centre), ``DETROTANGLE`` (degrees, the line's rotation about the camera z
  axis), ``DETPITCH`` (mm);
* ``RPB``: the vendor's RPC00B of the image (read by :func:`selfcal.io.rpc.read_rpc`, not here).

Times are seconds after ``EPH/STARTTIME`` (ASP's reference as well). ``ATT`` must share ``EPH``'s start and
interval, as ASP requires. Building a selfcal line camera from it is
:func:`selfcal.sensors.dg.line_image_from_dg`.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .xmldoc import XmlDocument, iso_utc, seconds_between

__all__ = ["DgSensor", "read_dg", "is_dg_xml"]


@dataclass(frozen=True)
class DgSensor:
    path: str
    satellite: str
    band: str
    rows: int
    columns: int
    scan_forward: bool                   # SCANDIRECTION Forward
    epoch_utc: str                       # EPH/STARTTIME (ISO 8601): every time below counts from it
    tlc_lines: np.ndarray                # (k,) image lines (0-based, pixel centres) of the TLC list
    tlc_times_s: np.ndarray              # (k,) their times
    first_line_time_s: float             # FIRSTLINETIME
    average_line_rate: float             # AVGLINERATE (lines/s)
    ephemeris_t0_s: float                # time of the first EPHEMLIST sample (0: it is the reference)
    ephemeris_dt_s: float
    positions_m: np.ndarray              # (n, 3) ECF
    velocities_m_s: np.ndarray           # (n, 3)
    position_covariance: np.ndarray      # (n, 6)
    attitude_t0_s: float
    attitude_dt_s: float
    quaternions: np.ndarray              # (n, 4) q1 q2 q3 q4 (scalar last): body -> ECF
    quaternion_covariance: np.ndarray    # (n, 10)
    principal_distance_mm: float
    detector_origin_mm: tuple[float, float]
    detector_rotation_deg: float
    detector_pitch_mm: float
    camera_attitude: tuple[float, float, float, float]    # QCS1..QCS4 (scalar last): camera -> body
    perspective_center_m: tuple[float, float, float]     # body frame
    has_rpb: bool


def is_dg_xml(path: str) -> bool:
    """Whether ``path`` looks like a DigitalGlobe ISD XML (root element ``isd``), from its first 4 kB."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(4096)
    except OSError:
        return False
    return b"<isd>" in head or b"<isd " in head


def _samples(doc: XmlDocument, block, list_key: str, item_key: str, width: int, start: tuple) -> tuple:
    """(t0, dt, values (n, width - 1)) of an EPH or ATT list: the rows sorted by their 1-based index."""
    name = doc.name(block)
    count = doc.integer(block, "NUMPOINTS", minimum=2)
    interval = doc.number(block, "TIMEINTERVAL")
    if interval <= 0:
        raise doc.error(doc.node(block, "TIMEINTERVAL"), f"{name}/TIMEINTERVAL must be positive",
                        f"{name}/TIMEINTERVAL")
    items = doc.children(doc.node(block, list_key), item_key)
    if len(items) != count:
        raise doc.error(block, f"{name}/NUMPOINTS is {count} but {name}/{list_key} holds {len(items)} {item_key}",
                        f"{name}/{list_key}")
    rows = np.array([_row(doc, item, width) for item in items])
    index = rows[:, 0]
    if np.any(index != np.round(index)) or np.any((index < 1) | (index > count)) \
            or sorted(index.astype(int)) != list(range(1, count + 1)):
        raise doc.error(block, f"{name}/{list_key}: the first number of each {item_key} must be its index 1..{count}",
                        f"{name}/{list_key}")
    rows = rows[np.argsort(index)]
    t0 = seconds_between(start, doc.utc(block, "STARTTIME"))
    return t0, interval, rows[:, 1:]


def _row(doc: XmlDocument, item, width: int) -> np.ndarray:
    text = item.text or ""
    try:
        values = np.array(text.split(), float)
    except ValueError:
        raise doc.error(item, f"{doc.name(item)} must hold numbers", doc.name(item)) from None
    if len(values) != width or not np.all(np.isfinite(values)):
        raise doc.error(item, f"{doc.name(item)} must hold {width} finite numbers, found {len(values)}", doc.name(item))
    return values


def read_dg(path: str | os.PathLike) -> DgSensor:
    """Read a DigitalGlobe / Maxar XML camera file; errors name the file, the line and the element."""
    path = str(path)
    doc = XmlDocument(path, "DigitalGlobe XML file")
    root = doc.root
    if root.tag != "isd":
        raise doc.error(root, f"root element is {root.tag!r}, not 'isd': not a DigitalGlobe/Maxar XML file")
    imd, eph, att, geo = (doc.node(root, key) for key in ("IMD", "EPH", "ATT", "GEO"))
    image = doc.node(imd, "IMAGE")
    start = doc.utc(eph, "STARTTIME")

    # --- ephemeris and attitude
    e_t0, e_dt, ephemeris = _samples(doc, eph, "EPHEMLISTList", "EPHEMLIST", 13, start)
    a_t0, a_dt, attitude = _samples(doc, att, "ATTLISTList", "ATTLIST", 15, start)
    if abs(a_t0 - e_t0) > 1e-9 or abs(a_dt - e_dt) > 1e-12 or len(attitude) != len(ephemeris):
        raise doc.error(att, "ATT must have the STARTTIME, TIMEINTERVAL and NUMPOINTS of EPH (ASP's requirement)",
                        "isd/ATT/STARTTIME")
    q = attitude[:, :4]
    norm = np.linalg.norm(q, axis=1)
    if np.any(np.abs(norm - 1.0) > 1e-3):
        k = int(np.argmax(np.abs(norm - 1.0)))
        raise doc.error(doc.children(doc.node(att, "ATTLISTList"), "ATTLIST")[k],
                        f"ATTLIST {k + 1}: quaternion norm {norm[k]:.6f} is not 1", "isd/ATT/ATTLISTList/ATTLIST")

    # --- line times
    tlc_time = doc.utc(image, "TLCTIME")
    count = doc.integer(image, "NUMTLC", minimum=1)
    items = doc.children(doc.node(image, "TLCLISTList"), "TLCLIST")
    if len(items) != count:
        raise doc.error(image, f"NUMTLC is {count} but TLCLISTList holds {len(items)} TLCLIST",
                        "isd/IMD/IMAGE/TLCLISTList")
    tlc = np.array([_row(doc, item, 2) for item in items])
    if np.any(np.diff(tlc[:, 0]) <= 0) or np.any(np.diff(tlc[:, 1]) <= 0):
        raise doc.error(image, "TLCLIST lines and times must increase", "isd/IMD/IMAGE/TLCLISTList")
    tlc_offset = seconds_between(start, tlc_time)
    rate = doc.number(image, "AVGLINERATE")
    if rate <= 0:
        raise doc.error(doc.node(image, "AVGLINERATE"), "AVGLINERATE must be positive", "isd/IMD/IMAGE/AVGLINERATE")
    scan = doc.text(image, "SCANDIRECTION")
    if scan.lower() not in ("forward", "reverse"):
        raise doc.error(doc.node(image, "SCANDIRECTION"), f"SCANDIRECTION must be Forward or Reverse, not {scan!r}",
                        "isd/IMD/IMAGE/SCANDIRECTION")

    # --- camera
    band = doc.text(imd, "BANDID")
    pd = doc.number(doc.node(geo, "PRINCIPAL_DISTANCE"), "PD")
    distortion = doc.node(geo, "OPTICAL_DISTORTION")
    order = doc.integer(distortion, "POLYORDER")
    coefficients = np.concatenate([_all_numbers(doc, node) for node in distortion.iter()
                                   if node.tag.startswith(("ALIST", "BLIST"))] or [np.zeros(0)])
    if order > 0 and np.any(coefficients != 0):
        raise doc.error(distortion, "optical distortion (POLYORDER > 0 with non-zero ALIST/BLIST) is not supported",
                        "isd/GEO/OPTICAL_DISTORTION")
    centre = doc.node(geo, "PERSPECTIVE_CENTER")
    attitude_node = doc.node(geo, "CAMERA_ATTITUDE")
    qcs = (doc.number(attitude_node, "QCS1"), doc.number(attitude_node, "QCS2"), doc.number(attitude_node, "QCS3"),
           doc.number(attitude_node, "QCS4"))
    if abs(np.linalg.norm(qcs) - 1.0) > 1e-6:
        raise doc.error(attitude_node, "CAMERA_ATTITUDE QCS1..QCS4 must be a unit quaternion",
                        "isd/GEO/CAMERA_ATTITUDE")
    mounting = doc.node(geo, "DETECTOR_MOUNTING")
    arrays = {node.tag: doc.node(doc.node(mounting, node.tag), "DETECTOR_ARRAY")
              for node in mounting if node.tag.startswith("BAND_")}
    if not arrays:
        raise doc.error(mounting, "DETECTOR_MOUNTING has no BAND_* element", "isd/GEO/DETECTOR_MOUNTING")
    keys = ("DETORIGINX", "DETORIGINY", "DETROTANGLE", "DETPITCH")
    values = {tag: tuple(doc.number(node, key) for key in keys) for tag, node in arrays.items()}
    if f"BAND_{band}" in values:
        origin_x, origin_y, rotation, pitch = values[f"BAND_{band}"]
    elif len(set(values.values())) == 1:
        origin_x, origin_y, rotation, pitch = next(iter(values.values()))
    else:
        raise doc.error(mounting, f"no DETECTOR_MOUNTING/BAND_{band} for BANDID {band} and the bands differ",
                        "isd/GEO/DETECTOR_MOUNTING")
    if pitch <= 0 or pd <= 0:
        raise doc.error(geo, "DETPITCH and PD must be positive", "isd/GEO")
    rows, columns = doc.integer(imd, "NUMROWS", minimum=1), doc.integer(imd, "NUMCOLUMNS", minimum=1)
    return DgSensor(
        path=path, satellite=doc.text(image, "SATID"), band=band, rows=rows, columns=columns,
        scan_forward=scan.lower() == "forward", epoch_utc=iso_utc(start),
        tlc_lines=tlc[:, 0], tlc_times_s=tlc[:, 1] + tlc_offset,
        first_line_time_s=seconds_between(start, doc.utc(image, "FIRSTLINETIME")), average_line_rate=rate,
        ephemeris_t0_s=e_t0, ephemeris_dt_s=e_dt, positions_m=ephemeris[:, 0:3], velocities_m_s=ephemeris[:, 3:6],
        position_covariance=ephemeris[:, 6:12], attitude_t0_s=a_t0, attitude_dt_s=a_dt,
        quaternions=q / norm[:, None], quaternion_covariance=attitude[:, 4:14],
        principal_distance_mm=pd, detector_origin_mm=(origin_x, origin_y), detector_rotation_deg=rotation,
        detector_pitch_mm=pitch, camera_attitude=qcs,
        perspective_center_m=(doc.number(centre, "CX"), doc.number(centre, "CY"), doc.number(centre, "CZ")),
        has_rpb=doc.find(root, "RPB") is not None)


def _all_numbers(doc: XmlDocument, node) -> np.ndarray:
    try:
        return np.array((node.text or "").split(), float)
    except ValueError:
        raise doc.error(node, f"{node.tag} must hold numbers", node.tag) from None
