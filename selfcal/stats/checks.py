"""Check points: the estimate of each against its reference coordinates.

Two ways to estimate a check point. *Intersection*: it is a tie point of the adjustment (seen in
two images or more), and its adjusted coordinates are compared. *Mono restitution*: it is seen
in one adjusted image only, and its image point is projected onto the terrain (a DEM or a
height) through the adjusted sensor (:meth:`selfcal.sensors.base.BoundSensor.ground`), as seed
001 checks a single pushbroom image.

Errors d = estimate - reference are given in the object frame's axes for a block in a projected
or local frame, and along east, north and up at the check points' centroid for ECEF: up is the WGS 84
normal on the Earth, the radial direction on a planetary body (a body-fixed ``crs``, as its control
points' sigmas are north, east, radial). An intersected check point's precision is its a-posteriori
covariance (:func:`check_point_sigmas_m`); a restituted one has none here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CheckPoints", "intersected", "restituted", "local_axes", "check_point_sigmas_m"]


@dataclass
class CheckPoints:
    point_id: np.ndarray
    role: np.ndarray               # role in the block as read (a gcp left out of the control is checked)
    reference: np.ndarray          # (n, 3) object frame
    estimate: np.ndarray           # (n, 3) object frame
    method: str                    # "intersection" or "restitution"
    axes: np.ndarray               # (3, 3) rows: the axes errors are given in (east, north, up or X, Y, Z)

    def __len__(self) -> int:
        return len(self.point_id)

    @property
    def errors_m(self) -> np.ndarray:
        """d = estimate - reference (n, 3) along :attr:`axes`."""
        return (self.estimate - self.reference) @ self.axes.T

    def rmsd_xy_m(self) -> float | None:
        d = self.errors_m
        return float(np.sqrt(np.mean(np.sum(d[:, :2] ** 2, axis=1)))) if len(d) else None

    def rmsd_z_m(self) -> float | None:
        d = self.errors_m
        return float(np.sqrt(np.mean(d[:, 2] ** 2))) if len(d) else None


def local_axes(points: np.ndarray, object_frame: str, crs: str = "") -> np.ndarray:
    """The axes (rows) check-point errors are reported in: east, north, up at the centroid of ``points``
    (ECEF; up radial for a body-fixed ``crs``, :func:`selfcal.geometry.body.is_body_fixed`), else the
    object frame's own."""
    if object_frame != "ECEF" or not len(points):
        return np.eye(3)
    from ..geometry.body import is_body_fixed, latlon_radius_from_xyz, north_east_radial
    if is_body_fixed(crs):
        lat_b, lon_b, _ = latlon_radius_from_xyz(np.mean(points, axis=0))
        north, east_b, radial = north_east_radial(lat_b, lon_b).T
        return np.stack([east_b, north, radial])
    from ..geometry.earth import geodetic_from_ecef, local_up
    lat, lon, _ = geodetic_from_ecef(np.mean(points, axis=0))
    up = local_up(lat, lon)
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    return np.stack([east, np.cross(up, east), up])


def _object_frame(result) -> str:
    return result.problem.sensors[0].sensor.object_frame if result.problem.sensors else "block"


def intersected(result) -> CheckPoints:
    """The check points of an adjustment (role ``chk``, tie points of it) against their references."""
    pts = result.block.points
    chk = np.flatnonzero(pts.role == "chk")
    return CheckPoints(pts.point_id[chk], pts.role[chk], pts.xyz_m[chk], result.state.points[chk], "intersection",
                       local_axes(pts.xyz_m[chk], _object_frame(result), result.block.crs))


def restituted(result, block, image_id: str, point_index: np.ndarray, height, role=None) -> CheckPoints:
    """Mono restitution of the points ``point_index`` of ``block`` (seen in image ``image_id`` of the
    adjustment ``result``) on ``height`` (metres or a DEM callable), against their references."""
    obs = block.observations
    image = int(np.flatnonzero(block.images.image_id == image_id)[0])
    sel = np.flatnonzero((obs.image_index == image) & np.isin(obs.point_index, point_index))
    points = obs.point_index[sel]
    k = int(np.flatnonzero(result.block.images.image_id == image_id)[0])
    slot = next(s for s in result.problem.sensors if k in s.images)
    context = slot.bound.context(result.state, False)
    estimate = slot.bound.ground(context, np.full(sel.size, k), obs.pixel[sel], height)
    reference = block.points.xyz_m[points]
    return CheckPoints(block.points.point_id[points], (block.points.role if role is None else role)[points], reference,
                       estimate, "restitution", local_axes(reference, slot.sensor.object_frame, block.crs))


def check_point_sigmas_m(checks: CheckPoints, result) -> np.ndarray | None:
    """The a-posteriori sigmas (n, 3), m, of intersected check points along :attr:`CheckPoints.axes`: the
    adjusted points' covariance (points.csv's sigma) turned into those axes; the reference's own sigma is not
    in it. None for restituted check points (no covariance is propagated through the restitution)."""
    if checks.method != "intersection" or not len(checks):
        return None
    row = {pid: k for k, pid in enumerate(result.block.points.point_id)}
    covariance = result.point_covariance()[[row[pid] for pid in checks.point_id]]
    return np.sqrt(np.einsum("ij,njk,ik->ni", checks.axes, covariance, checks.axes))
