"""Results for other programs: the check points' errors as GeoJSON (GIS) and the adjusted object points with
their sigma as PLY (point-cloud viewers: CloudCompare, MeshLab, Open3D).

Both are in the object frame of points.csv: the block's CRS for frame cameras (a projected CRS and height,
or a local frame), Earth- or body-fixed for satellite and planetary sensors. GeoJSON gets a CRS GDAL/OGR
(and with it QGIS) reads in every case, in the ``crs`` member of GeoJSON 2008 (``{"type": "name",
"properties": {"name": ...}}``, which GDAL passes to ``OGRSpatialReference::SetFromUserInput``):

* an Earth-fixed frame (ECEF): longitude, latitude and WGS 84 ellipsoidal height, RFC 7946's own CRS, no
  ``crs`` member;
* a planetary body (a body-fixed ``crs``, :func:`selfcal.geometry.body.is_body_fixed`): planetocentric
  longitude, latitude and the height above the body's IAU 2015 sphere, ``urn:ogc:def:crs:IAU_2015::<NAIF
  code>00`` (``IAU_2015:30100``: the Moon); the body is the IAU code of the ``crs`` or the NAIF code its
  images' ISDs name (``BODY301_RADII``);
* a CRS with an authority code (``EPSG:32611``): that code as ``urn:ogc:def:crs:EPSG::32611``;
* anything else (a local frame, a body whose IAU CRS is unknown): an engineering CRS in WKT2 (``ENGCRS``,
  Cartesian, metres, axes X, Y, Z of unspecified direction), so that no GIS reads the metres as degrees.
"""
from __future__ import annotations

import re

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..stats.checks import CheckPoints

__all__ = ["check_points_geojson", "geojson_crs", "engineering_crs_wkt", "object_points_ply", "PLY_ROLES"]

#: PLY ``role`` codes
PLY_ROLES = {"tie": 0, "gcp": 1, "chk": 2}


def engineering_crs_wkt(name: str) -> str:
    """WKT2 of an engineering CRS named ``name``: Cartesian, metres, axes X, Y, Z of unspecified direction."""
    from pyproj import CRS
    axes = [{"name": a, "abbreviation": a, "direction": "unspecified", "unit": "metre"} for a in "XYZ"]
    return CRS.from_json_dict({"type": "EngineeringCRS", "name": name,
                               "datum": {"type": "EngineeringDatum", "name": "selfcal object frame"},
                               "coordinate_system": {"subtype": "Cartesian", "axis": axes}}).to_wkt()


def _iau_sphere(crs: str, body_naif_code: int | None):
    """(IAU_2015 code, sphere radius in m) of the body of a body-fixed ``crs``, or None if pyproj knows none."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError
    named = re.fullmatch(r"IAU(?:_\d{4})?:(\d+)", crs.strip(), flags=re.IGNORECASE)
    naif = int(named.group(1)) // 100 if named else body_naif_code
    if naif is None:
        return None
    try:
        geographic = CRS.from_authority("IAU_2015", str(100 * naif))
    except CRSError:
        return None
    ellipsoid = geographic.ellipsoid
    if ellipsoid is None or ellipsoid.semi_major_metre != ellipsoid.semi_minor_metre:
        return None
    return 100 * naif, float(ellipsoid.semi_major_metre)


def _authority_urn(crs: str) -> str | None:
    """``urn:ogc:def:crs:AUTH::CODE`` of a ``crs`` written as AUTH:CODE (EPSG, ESRI, IAU_2015 ...) that pyproj
    knows, else None."""
    code = re.fullmatch(r"([A-Za-z][A-Za-z0-9_]*):(\d+)", crs.strip())
    if not code:
        return None
    if code.group(1).upper() != "EPSG":
        from pyproj import CRS
        from pyproj.exceptions import CRSError
        try:
            CRS.from_authority(code.group(1), code.group(2))
        except CRSError:
            return None
    authority = "EPSG" if code.group(1).upper() == "EPSG" else code.group(1)
    return f"urn:ogc:def:crs:{authority}::{code.group(2)}"


def geojson_crs(crs: str, earth_fixed: bool, body_naif_code: int | None = None) -> tuple[str, str | None, float]:
    """How check_points.geojson places the points of a block (see the module docstring): (kind, the name of
    its ``crs`` member or None, the radius of the body's sphere in m or 0). kind: ``earth`` (longitude,
    latitude, WGS 84 height), ``body`` (longitude, latitude, height above the sphere), ``code`` (the block's
    coordinates in the named CRS) or ``engineering`` (the block's coordinates, an engineering CRS)."""
    from ..geometry.body import is_body_fixed
    if crs.strip() == "body-fixed" or (earth_fixed and is_body_fixed(crs)):
        body = _iau_sphere(crs, body_naif_code)
        if body is not None:
            return "body", f"urn:ogc:def:crs:IAU_2015::{body[0]}", body[1]
        return "engineering", engineering_crs_wkt(crs), 0.0
    if earth_fixed:
        return "earth", None, 0.0
    urn = _authority_urn(crs)
    if urn is not None:
        return "code", urn, 0.0
    return "engineering", engineering_crs_wkt(crs), 0.0


def check_points_geojson(checks: CheckPoints, crs: str, earth_fixed: bool, sigmas_m: np.ndarray | None = None,
                         body_naif_code: int | None = None) -> dict | None:
    """check_points.geojson: one Point feature per check point at its reference position (in the CRS of
    :func:`geojson_crs`), with its errors d = adjusted - reference along the check points' axes
    (:attr:`CheckPoints.axes`) and their sigma: ``dE_m, dN_m, dU_m`` and ``sigma_dE_m ...`` (east, north, up:
    Earth- or body-fixed) or ``dX_m, dY_m, dZ_m`` and ``sigma_dX_m ...`` (the frame's axes), ``error_xy_m``
    (the horizontal error). ``earth_fixed``: the sensors work in ECEF (or body-fixed) metres; ``sigmas_m``
    (n, 3): the a-posteriori sigmas along the axes (:func:`selfcal.stats.checks.check_point_sigmas_m`), None
    writes null (restituted check points); ``body_naif_code``: the target body of a body-fixed block. None
    without check points."""
    if checks is None or not len(checks):
        return None
    d = checks.errors_m
    sigma = np.full(d.shape, np.nan) if sigmas_m is None else np.asarray(sigmas_m, float)
    kind, name, radius_m = geojson_crs(crs, earth_fixed, body_naif_code)
    position = checks.reference
    if kind == "earth":
        from ..geometry.earth import geodetic_from_ecef
        lat, lon, h = geodetic_from_ecef(position)
        position = np.column_stack([np.degrees(lon), np.degrees(lat), h])
    elif kind == "body":
        from ..geometry.body import latlon_radius_from_xyz
        lat, lon, r = latlon_radius_from_xyz(position)
        position = np.column_stack([np.degrees(lon), np.degrees(lat), r - radius_m])
    enu = earth_fixed                          # errors along east, north, up (CheckPoints.axes: local_axes)
    axes = ["E", "N", "U"] if enu else ["X", "Y", "Z"]
    about: dict[str, object] = {"crs": crs, "axes": ["east", "north", "up"] if enu else axes,
                                "method": checks.method,
                                "note": "d = adjusted - reference, in metres along axes; sigma_d: the adjusted "
                                        "point's a-posteriori sigma (null: not known for this method)"}
    if kind == "body":
        about["height"] = f"above the body's IAU 2015 sphere of radius {radius_m:.1f} m"
    doc: dict[str, object] = {"type": "FeatureCollection", "name": "check_points"}
    if name is not None:
        doc["crs"] = {"type": "name", "properties": {"name": name}}
    doc["selfcal"] = about

    def value(x: float) -> float | None:
        return float(x) if np.isfinite(x) else None

    features = []
    for pid, role, p, e, s in zip(checks.point_id, checks.role, position, d, sigma):
        properties: dict[str, object] = {"point_id": str(pid), "role": str(role)}
        properties |= {f"d{a}_m": float(v) for a, v in zip(axes, e)}
        properties |= {f"sigma_d{a}_m": value(v) for a, v in zip(axes, s)}
        properties["error_xy_m"] = float(np.hypot(e[0], e[1]))
        features.append({"type": "Feature", "geometry": {"type": "Point", "coordinates": [float(v) for v in p]},
                         "properties": properties})
    doc["features"] = features
    return doc


def object_points_ply(result, view=None) -> dict:
    """points.ply: every adjusted object point (x, y, z as double, in points.csv's frame) with its sigma along
    the axes (m), the number of images that see it and its role (:data:`PLY_ROLES`); ``view``
    (:class:`~selfcal.report.frame.ResultView`): the points in the block's CRS."""
    block = result.block
    pts = block.points
    if view is None:
        from .frame import ResultView
        view = ResultView.of(result)
    sigma = np.sqrt(np.einsum("nii->ni", view.point_covariance))
    vertices = np.zeros(len(pts), dtype=[("x", "f8"), ("y", "f8"), ("z", "f8"), ("sigma_x_m", "f4"),
                                         ("sigma_y_m", "f4"), ("sigma_z_m", "f4"), ("n_images", "i4"),
                                         ("role", "u1")])
    xyz = view.points
    vertices["x"], vertices["y"], vertices["z"] = xyz.T
    vertices["sigma_x_m"], vertices["sigma_y_m"], vertices["sigma_z_m"] = sigma.T
    vertices["n_images"] = np.bincount(block.observations.point_index, minlength=len(pts))
    vertices["role"] = [PLY_ROLES.get(r, 0) for r in pts.role]
    comments = [f"selfcal adjusted object points of block {block.name}", f"crs {view.crs}",
                "role: " + ", ".join(f"{v} {k}" for k, v in PLY_ROLES.items()),
                "sigma_*_m: a-posteriori standard deviations along x, y, z in metres"]
    return {"vertices": vertices, "comments": comments}
