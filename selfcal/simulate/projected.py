"""A simulated block placed on the Earth in a projected CRS, with its truth there.

The UAV simulation (:mod:`.uav`) is built in a Cartesian frame. Taken as the local tangent plane (east, north,
up) at a geodetic position, every coordinate of it — the points, their survey references, the perspective
centres, the GNSS observations — goes to the CRS exactly (:class:`selfcal.geometry.tangent.TangentPlane`), every
attitude and IMU observation to the CRS's axes at the camera (grid east, grid north, the ellipsoid normal). The
images are those of the Cartesian block: the block in the CRS is the same photogrammetric block, and an
adjustment that took the CRS for a Cartesian frame (its scale k, its curvature, the meridian convergence) shows
its error at the check points against the truth in the CRS.

``scale`` enlarges the object space about the block's centre (points and perspective centres; the survey and
GNSS errors scale with it, the images are unchanged: the projections of a similar figure are the same), so that
the seed-000 block of 900 x 530 m at 215 m above ground becomes a block of kilometres with hundreds of metres of
relief, where the projection's distortions are far above the noise.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..geometry.tangent import TangentPlane
from .uav import UAVSimulation

__all__ = ["place_in_crs"]


def place_in_crs(sim: UAVSimulation, crs: str, lon_deg: float, lat_deg: float, height_m: float = 0.0,
                 scale: float = 1.0) -> tuple[UAVSimulation, TangentPlane]:
    """``sim`` in ``crs`` with the centre of its plan at ``lon_deg``, ``lat_deg`` and its frame's zero height at
    ``height_m`` (ellipsoidal), object space enlarged ``scale`` times (module docstring); and the tangent plane
    its Cartesian frame was taken as. Every block of ``sim`` and its truth (``xyz``, ``eop``) are converted; the
    declared sigmas of the marks and the GNSS scale with ``scale``."""
    from pyproj import CRS, Transformer
    parsed = CRS.from_user_input(crs)
    geodetic = (parsed.sub_crs_list[0] if parsed.is_compound else parsed).geodetic_crs
    if geodetic is None:
        raise ValueError(f"crs {crs!r} has no geodetic CRS")
    target = parsed if parsed.is_compound else parsed.to_3d()
    e, n, h = Transformer.from_crs(geodetic.to_3d(), target, always_xy=True).transform(lon_deg, lat_deg, height_m)
    plane = TangentPlane(crs, (float(e), float(n), float(h)))
    truth = sim.truth
    centre = np.r_[0.5 * (truth.xyz[:, :2].min(axis=0) + truth.xyz[:, :2].max(axis=0)), 0.0]

    def enu(xyz: np.ndarray) -> np.ndarray:
        return (np.asarray(xyz, float) - centre) * scale

    def positions(xyz: np.ndarray) -> np.ndarray:
        return plane.to_crs(enu(xyz))

    def attitudes(opk: np.ndarray, xyz: np.ndarray) -> np.ndarray:
        at = enu(np.where(np.isfinite(xyz), xyz, centre))
        return plane.attitudes_to_crs(opk, plane.axes(at))

    true_positions = truth.eop[:, :3]
    blocks = {}
    for name, block in sim.blocks.items():
        im, pts = block.images, block.points
        images = replace(im, position_m=positions(im.position_m),
                         attitude_rad=attitudes(im.attitude_rad, true_positions))
        points = replace(pts, xyz_m=positions(pts.xyz_m), sigma_m=pts.sigma_m * scale)
        gnss = None if block.gnss_sigma_m is None else \
            (block.gnss_sigma_m[0] * scale, block.gnss_sigma_m[1] * scale, block.gnss_sigma_m[2] * scale)
        blocks[name] = replace(block, crs=crs, images=images, points=points, gnss_sigma_m=gnss)
    eop = np.column_stack([positions(true_positions), attitudes(truth.eop[:, 3:], true_positions)])
    placed = replace(truth, xyz=positions(truth.xyz), eop=eop, gsd_m=truth.gsd_m * scale)
    return UAVSimulation(blocks, placed, dict(sim.info, crs=crs, lon_deg=lon_deg, lat_deg=lat_deg,
                                              height_m=height_m, scale=scale)), plane
