"""Results for other programs: the check points' errors as GeoJSON (GIS) and the adjusted object points with
their sigma as PLY (point-cloud viewers: CloudCompare, MeshLab, Open3D).

Both are in the object frame of points.csv: the block's CRS for frame cameras (a projected CRS and height,
or a local frame), Earth-fixed for satellite sensors. GeoJSON puts an Earth-fixed frame into longitude,
latitude and ellipsoidal height (RFC 7946's own CRS, with no ``crs`` member); an ``EPSG:N`` CRS is named
by the ``crs`` member of GeoJSON 2008 (``urn:ogc:def:crs:EPSG::N``), which GDAL/OGR and QGIS honour; a
block in a local frame gets no GeoJSON (without a ``crs`` member a GIS would read its metres as degrees).
"""
from __future__ import annotations

import re

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..stats.checks import CheckPoints

__all__ = ["check_points_geojson", "object_points_ply", "PLY_ROLES"]

#: PLY ``role`` codes
PLY_ROLES = {"tie": 0, "gcp": 1, "chk": 2}


def check_points_geojson(checks: CheckPoints, crs: str, earth_fixed: bool) -> dict | None:
    """check_points.geojson: one Point feature per check point at its reference position, with its errors
    d = adjusted - reference (``d1_m, d2_m, d3_m`` along ``axes``: east, north, up for an Earth-fixed frame,
    else X, Y, Z) and ``error_xy_m``. ``earth_fixed``: the frame is ECEF (the sensors' object frame). None
    without check points, and in a local frame (no CRS a GIS could place it in)."""
    if checks is None or not len(checks):
        return None
    d = checks.errors_m
    position = checks.reference
    doc: dict[str, object] = {"type": "FeatureCollection", "name": "check_points"}
    if earth_fixed:
        from ..geometry.earth import geodetic_from_ecef
        lat, lon, h = geodetic_from_ecef(position)
        position = np.column_stack([np.degrees(lon), np.degrees(lat), h])
        axes = ["east", "north", "up"]
    else:
        code = re.fullmatch(r"EPSG:(\d+)", crs.strip(), flags=re.IGNORECASE)
        if not code:            # a local frame: GeoJSON without a crs member means longitude and latitude
            return None
        doc["crs"] = {"type": "name", "properties": {"name": f"urn:ogc:def:crs:EPSG::{code.group(1)}"}}
        axes = ["X", "Y", "Z"]
    doc["selfcal"] = {"crs": crs, "axes": axes, "method": checks.method,
                      "note": "d = adjusted - reference, in metres along axes"}
    doc["features"] = [
        {"type": "Feature",
         "geometry": {"type": "Point", "coordinates": [float(v) for v in p]},
         "properties": {"point_id": str(pid), "role": str(role), "d1_m": float(e[0]), "d2_m": float(e[1]),
                        "d3_m": float(e[2]), "error_xy_m": float(np.hypot(e[0], e[1]))}}
        for pid, role, p, e in zip(checks.point_id, checks.role, position, d)]
    return doc


def object_points_ply(result) -> dict:
    """points.ply: every adjusted object point (x, y, z as double, in points.csv's frame) with its sigma along
    the axes (m), the number of images that see it and its role (:data:`PLY_ROLES`)."""
    block = result.block
    pts = block.points
    sigma = np.sqrt(np.einsum("nii->ni", result.point_covariance()))
    vertices = np.zeros(len(pts), dtype=[("x", "f8"), ("y", "f8"), ("z", "f8"), ("sigma_x_m", "f4"),
                                         ("sigma_y_m", "f4"), ("sigma_z_m", "f4"), ("n_images", "i4"),
                                         ("role", "u1")])
    xyz = result.state.points
    vertices["x"], vertices["y"], vertices["z"] = xyz.T
    vertices["sigma_x_m"], vertices["sigma_y_m"], vertices["sigma_z_m"] = sigma.T
    vertices["n_images"] = np.bincount(block.observations.point_index, minlength=len(pts))
    vertices["role"] = [PLY_ROLES.get(r, 0) for r in pts.role]
    comments = [f"selfcal adjusted object points of block {block.name}", f"crs {block.crs}",
                "role: " + ", ".join(f"{v} {k}" for k, v in PLY_ROLES.items()),
                "sigma_*_m: a-posteriori standard deviations along x, y, z in metres"]
    return {"vertices": vertices, "comments": comments}
