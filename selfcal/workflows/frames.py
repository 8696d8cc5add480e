"""The object frame of an adjustment: a block's points in the frame its sensors work in.

Frame cameras work in Cartesian metres. A block in a local frame (``crs = "local"`` or any name that is not a
CRS) or in ECEF is adjusted in its own coordinates; a block in a projected CRS (``EPSG:32633``, or one with a
vertical datum, ``EPSG:32633+5773``) in the local tangent plane at its centre (DESIGN.md §2,
:func:`tangent_plane_block`; :class:`selfcal.geometry.tangent.TangentPlane`), and its results are written back
in the CRS (:class:`selfcal.report.frame.ResultView`). Satellite sensors work in Earth-fixed Cartesian metres
(ECEF, EPSG:4978): a block whose ``crs`` is another CRS of the Earth (``EPSG:4979``: longitude, latitude,
ellipsoidal height) has its points converted with pyproj before the adjustment; the control points' sigmas stay
east / north / up.
"""
from __future__ import annotations

import re
from dataclasses import replace

import numpy as np

from ..block import Block
from ..errors import BlockError
from ..geometry.tangent import TangentPlane, tangent_plane_reason
from ..sensors import sensor_of
from ..stats.loo import LeaveOneOut

__all__ = ["object_frame_block", "tangent_plane_block", "loo_in_crs", "TANGENT_PLANE_LABEL", "ECEF_NAMES"]

#: what the crs of a block converted to its tangent plane says (never a CRS pyproj reads: nothing converts its
#: coordinates as if they were the CRS's)
TANGENT_PLANE_LABEL = "{crs} (local tangent plane)"

#: crs names already in the ECEF (or body-fixed) Cartesian frame
ECEF_NAMES = ("EPSG:4978", "ECEF", "body-fixed")


def object_frame_block(block: Block) -> Block:
    """``block`` with its points in its sensors' object frame (see the module docstring)."""
    frames = {sensor_of(c).object_frame for c in block.cameras.values()}
    if frames != {"ECEF"} or block.crs in ECEF_NAMES or block.crs.upper().startswith("IAU"):
        return block
    from pyproj import CRS, Transformer
    from pyproj.exceptions import CRSError
    try:
        source = CRS.from_user_input(block.crs)
    except CRSError as exc:
        raise BlockError("block.toml", f"crs {block.crs!r} is not a coordinate reference system pyproj knows: {exc}",
                         None, "crs") from None
    transformer = Transformer.from_crs(source, "EPSG:4978", always_xy=True)
    xyz = block.points.xyz_m
    known = np.isfinite(xyz).all(axis=1)
    out = np.full_like(xyz, np.nan)
    if known.any():
        out[known] = np.column_stack(transformer.transform(xyz[known, 0], xyz[known, 1], xyz[known, 2]))
    return replace(block, crs="EPSG:4978", points=replace(block.points, xyz_m=out))


def tangent_plane_block(block: Block) -> tuple[Block, TangentPlane | None]:
    """A frame-camera block in a projected CRS in the local tangent plane at its centre, and the plane; any other
    block as it is, and None (module docstring).

    Converted: every position (points.csv's control, check and tie points, images.csv's X0, Y0, Z0, which are
    also the GNSS observations), every attitude (images.csv's omega, phi, kappa against the CRS's axes at the
    camera: grid east, grid north, the ellipsoid normal; also the IMU observations) and the a-priori sigmas: the
    control points keep theirs along the CRS's coordinates (``Points.sigma_axes``: the weight is diag(1 / sigma)
    times the Jacobian of the CRS coordinates), the GNSS and IMU observations get per image the sigmas of their
    covariance turned into the plane (its correlations, below 0.07 for sigma_X != sigma_Y and a convergence of
    2 degrees, 0 for equal horizontal sigmas, are left out: the engine weighs each axis on its own). The lever
    arm (camera axes) and the boresight (camera and IMU body axes) are not in object space and stay as given.

    Raises
    ------
    BlockError
        A crs written as ``AUTHORITY:CODE`` that pyproj does not know, a geographic crs (degrees are not metres),
        a geoid model the CRS's heights need that is not installed.
    """
    sensors = {sensor_of(c).object_frame for c in block.cameras.values()}
    crs = block.crs.strip()
    if sensors != {"block"} or not all(c.model == "frame" for c in block.cameras.values()) \
            or crs in ("", "local", *ECEF_NAMES) or crs.upper().startswith("IAU"):
        return block, None
    from pyproj import CRS
    from pyproj.exceptions import CRSError
    try:
        parsed = CRS.from_user_input(crs)
    except CRSError:
        if re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*:\S+", crs):
            raise BlockError("block.toml", f"crs {crs!r} is not a coordinate reference system pyproj knows",
                             None, "crs") from None
        return block, None                  # a name of the block's own frame ("local", "site grid")
    if parsed.is_geocentric:
        return block, None
    reason = tangent_plane_reason(crs)
    if reason:
        raise BlockError("block.toml", reason, None, "crs")
    points, images = block.points, block.images
    where = np.vstack([points.xyz_m, images.position_m])
    if not np.isfinite(where).all(axis=1).any():
        return block, None                  # (nothing placed yet: the adjustment says why it cannot start)
    try:
        plane = TangentPlane.at_centre(crs, where)
        xyz = plane.from_crs(points.xyz_m)
        positions = plane.from_crs(images.position_m)
    except ValueError as exc:
        raise BlockError("block.toml", f"crs {crs!r}: {exc}", None, "crs") from None
    # the derivatives of the CRS's coordinates at each point (identity where a point has no coordinates)
    known = np.isfinite(xyz).all(axis=1)
    sigma_axes = np.broadcast_to(np.eye(3), (len(xyz), 3, 3)).copy()
    if known.any():
        sigma_axes[known] = plane.jacobian(xyz[known])
    # at each camera (at the plane's origin where its position is not given)
    at = np.where(np.isfinite(positions).all(axis=1)[:, None], positions, 0.0)
    J = plane.jacobian(at)
    axes = plane.axes(at, J)
    attitude = plane.attitudes_from_crs(images.attitude_rad, axes)
    gnss_sigma, imu_sigma = images.gnss_sigma_m, images.imu_sigma_rad
    if block.gnss_sigma_m is not None:
        sigma = images.trajectory_sigma("GNSS", block.gnss_sigma_m)
        J_inv = np.linalg.inv(J)
        gnss_sigma = np.sqrt(np.einsum("nii->ni", TangentPlane.covariances(J_inv, _diagonal(sigma))))
    if block.imu_sigma_deg is not None:
        sigma = images.trajectory_sigma("IMU", np.radians(np.array(block.imu_sigma_deg, float)))
        opk = np.where(np.isfinite(images.attitude_rad), images.attitude_rad, 0.0)
        A = TangentPlane.attitude_jacobian(opk, axes)
        imu_sigma = np.sqrt(np.einsum("nii->ni", TangentPlane.covariances(A, _diagonal(sigma))))
    return replace(block, crs=TANGENT_PLANE_LABEL.format(crs=crs),
                   points=replace(points, xyz_m=xyz, sigma_axes=sigma_axes),
                   images=replace(images, position_m=positions, attitude_rad=attitude, gnss_sigma_m=gnss_sigma,
                                  imu_sigma_rad=imu_sigma)), plane


def _diagonal(sigma: np.ndarray) -> np.ndarray:
    """(n, 3, 3) diagonal covariances of (n, 3) sigmas."""
    return np.einsum("ni,ij->nij", np.asarray(sigma, float) ** 2, np.eye(3))


def loo_in_crs(loo: LeaveOneOut, plane: TangentPlane, points) -> LeaveOneOut:
    """A leave-one-out validation of the control (:class:`selfcal.stats.loo.LeaveOneOut`) of a block adjusted in
    ``plane``, its errors and cofactors turned into the CRS's coordinates at each control point (``points``: the
    adjusted block's, in the plane)."""
    row = {pid: k for k, pid in enumerate(points.point_id)}
    J = plane.jacobian(points.xyz_m[[row[p] for p in loo.point_id]])
    return replace(loo, d_m=np.einsum("nij,nj->ni", J, loo.d_m), cov_m2=TangentPlane.covariances(J, loo.cov_m2))
