"""A block's local tangent plane: the Cartesian frame a frame-camera block in a projected CRS is adjusted in
(DESIGN.md §2).

A projection is not Cartesian: its horizontal scale is k (0.9996-1.0004 in UTM) while heights are unscaled, the
Earth's surface falls away from any plane (2 cm at 500 m, 8 cm at 1 km), and grid north differs from true north
by the meridian convergence gamma. The tangent plane is east, north, up (ENU) at an origin near the block's
centre: a CRS position goes to geodetic latitude, longitude and ellipsoidal height on the CRS's own ellipsoid
(pyproj; a pure conversion, no datum shift), then to Earth-centred Cartesian metres and into the plane's axes
(a rotation and a shift). Nothing is approximated: the way back is the exact inverse (round trip 1e-9 m).

Heights. A plain projected CRS (``EPSG:32633``) has no vertical datum: its Z is taken as the ellipsoidal height
(``heights = "ellipsoidal"``). Orthometric heights given in such a CRS put the plane N (the geoid undulation)
off the ellipsoid, a scale error of N/R (8e-6 for N = 50 m) and the geoid's tilt across the block (about 1e-5) is
not modelled. A compound CRS with a vertical datum (``EPSG:32633+5773``) has orthometric heights and is converted
through its geoid model (``heights = "orthometric"``); without the geoid grid installed that is refused
(:func:`selfcal.geometry.gnss.require_best`), never passed through as PROJ's "ballpark" transformation would.

Derivatives. :meth:`TangentPlane.jacobian` is d(CRS coordinates)/d(plane coordinates) at a point (central
differences of the exact mapping, 1e-9 relative). For a conformal projection it is diag(k, k, 1) times the
rotation from the plane's axes to the CRS's axes at that point (grid east, grid north, the ellipsoid normal):
:meth:`TangentPlane.axes` is that rotation (the polar factor of the Jacobian). A camera's omega, phi, kappa in
the CRS are its rotation against those axes at its position: the plane's matrix is M_plane = M_crs · R.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .earth import ecef_from_geodetic, geodetic_from_ecef
from .rotation import matrix_from_opk, matrix_from_opk_with_derivatives, opk_from_matrix, \
    opk_from_matrix_with_derivatives

__all__ = ["TangentPlane", "tangent_plane_reason", "JACOBIAN_STEP_M"]

#: step of the central differences of :meth:`TangentPlane.jacobian` (m): the projection's third derivatives
#: (1/R^2) make the truncation error 1e-14, PROJ's rounding (1e-9 m) 1e-9 of the derivative
JACOBIAN_STEP_M = 1.0


def tangent_plane_reason(crs: str) -> str:
    """Why a frame block in ``crs`` cannot be adjusted in a tangent plane (a sentence), or "" when it can: the CRS
    must be one pyproj knows, projected (a 2-D projected CRS, or one compounded with a vertical CRS)."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError
    try:
        parsed = CRS.from_user_input(crs)
    except CRSError as exc:
        return f"crs {crs!r} is not a coordinate reference system pyproj knows: {exc}"
    horizontal = parsed.sub_crs_list[0] if parsed.is_compound else parsed
    if not horizontal.is_projected:
        return (f"crs {crs!r} is not projected: a frame-camera block gives its coordinates in metres, a projected "
                f"CRS (e.g. UTM, with heights) or \"local\"")
    return ""


@dataclass(frozen=True)
class TangentPlane:
    """East, north, up at ``origin`` (a position in ``crs``); see the module docstring."""

    crs: str
    origin_crs: tuple[float, float, float]
    #: latitude, longitude (degrees) and ellipsoidal height (m) of the origin on the CRS's ellipsoid
    origin_geodetic: tuple[float, float, float] = field(init=False)
    #: "ellipsoidal" (a CRS without vertical datum: Z taken as the height above its ellipsoid) or "orthometric"
    heights: str = field(init=False)
    semi_major_m: float = field(init=False)
    flattening: float = field(init=False)
    _origin_ecef: np.ndarray = field(init=False, repr=False, compare=False)
    _axes_ecef: np.ndarray = field(init=False, repr=False, compare=False)       # rows: east, north, up
    _to_geographic: object = field(init=False, repr=False, compare=False)
    _from_geographic: object = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        from pyproj import CRS, Transformer
        from pyproj.exceptions import ProjError
        from .gnss import require_best
        reason = tangent_plane_reason(self.crs)
        if reason:
            raise ValueError(reason)
        parsed = CRS.from_user_input(self.crs)
        horizontal = parsed.sub_crs_list[0] if parsed.is_compound else parsed
        source = parsed if parsed.is_compound else parsed.to_3d()
        geodetic = horizontal.geodetic_crs
        if geodetic is None or geodetic.ellipsoid is None:
            raise ValueError(f"crs {self.crs!r} has no geodetic CRS with an ellipsoid")
        geographic = geodetic.to_3d()
        if parsed.is_compound:
            require_best(source, geographic)
        try:
            to_geo = Transformer.from_crs(source, geographic, always_xy=True, only_best=True)
            from_geo = Transformer.from_crs(geographic, source, always_xy=True, only_best=True)
        except ProjError as exc:
            raise ValueError(f"pyproj cannot convert {parsed.name} to {geographic.name}: {exc}") from None
        ellipsoid = geodetic.ellipsoid
        a, f = float(ellipsoid.semi_major_metre), 1.0 / float(ellipsoid.inverse_flattening)
        set_ = object.__setattr__
        set_(self, "_to_geographic", to_geo)
        set_(self, "_from_geographic", from_geo)
        set_(self, "semi_major_m", a)
        set_(self, "flattening", f)
        set_(self, "heights", "orthometric" if parsed.is_compound else "ellipsoidal")
        e0, n0, h0 = (float(v) for v in self.origin_crs)
        lon, lat, h = to_geo.transform(e0, n0, h0, errcheck=True)
        set_(self, "origin_geodetic", (float(lat), float(lon), float(h)))
        la, lo = np.radians(lat), np.radians(lon)
        set_(self, "_origin_ecef", ecef_from_geodetic(la, lo, h, a, f))
        east = np.array([-np.sin(lo), np.cos(lo), 0.0])
        up = np.array([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)])
        set_(self, "_axes_ecef", np.stack([east, np.cross(up, east), up]))

    @classmethod
    def at_centre(cls, crs: str, xyz_crs: np.ndarray) -> "TangentPlane":
        """The plane of ``crs`` at the centre of the positions ``xyz_crs`` (n, 3; NaN rows ignored): the middle of
        their plan extent, at their median height."""
        xyz = np.asarray(xyz_crs, float).reshape(-1, 3)
        xyz = xyz[np.isfinite(xyz).all(axis=1)]
        if not len(xyz):
            raise ValueError("no position to put a tangent plane at")
        plan = 0.5 * (xyz[:, :2].min(axis=0) + xyz[:, :2].max(axis=0))
        return cls(crs, (float(plan[0]), float(plan[1]), float(np.median(xyz[:, 2]))))

    def describe(self) -> dict:
        """The plane for summary.json: its CRS, origin and the kind of heights."""
        lat, lon, h = self.origin_geodetic
        return {"kind": "local tangent plane (east, north, up)", "crs": self.crs,
                "origin_crs": [float(v) for v in self.origin_crs], "origin_lat_deg": lat, "origin_lon_deg": lon,
                "origin_height_m": h, "heights": self.heights}

    # ---------------------------------------------------------------- positions
    def from_crs(self, xyz_crs: np.ndarray) -> np.ndarray:
        """Positions (n, 3) in the CRS to the plane (NaN rows stay NaN)."""
        xyz = np.asarray(xyz_crs, float).reshape(-1, 3)
        out = np.full_like(xyz, np.nan)
        ok = np.isfinite(xyz).all(axis=1)
        if ok.any():
            lon, lat, h = self._to_geographic.transform(*xyz[ok].T, errcheck=True)  # type: ignore[attr-defined]
            ecef = ecef_from_geodetic(np.radians(lat), np.radians(lon), h, self.semi_major_m, self.flattening)
            out[ok] = (ecef - self._origin_ecef) @ self._axes_ecef.T
        return out

    def to_crs(self, enu: np.ndarray) -> np.ndarray:
        """Positions (n, 3) in the plane to the CRS (NaN rows stay NaN)."""
        p = np.asarray(enu, float).reshape(-1, 3)
        out = np.full_like(p, np.nan)
        ok = np.isfinite(p).all(axis=1)
        if ok.any():
            lat, lon, h = geodetic_from_ecef(p[ok] @ self._axes_ecef + self._origin_ecef, self.semi_major_m,
                                             self.flattening)
            out[ok] = np.column_stack(self._from_geographic.transform(  # type: ignore[attr-defined]
                np.degrees(lon), np.degrees(lat), h, errcheck=True))
        return out

    def jacobian(self, enu: np.ndarray) -> np.ndarray:
        """d(CRS coordinates)/d(plane coordinates) (n, 3, 3) at plane positions (rows: the CRS's coordinates)."""
        p = np.asarray(enu, float).reshape(-1, 3)
        h = JACOBIAN_STEP_M
        out = np.empty((len(p), 3, 3))
        for k in range(3):
            step = np.zeros(3)
            step[k] = h
            out[:, :, k] = (self.to_crs(p + step) - self.to_crs(p - step)) / (2.0 * h)
        return out

    def axes(self, enu: np.ndarray, jacobian: np.ndarray | None = None) -> np.ndarray:
        """R (n, 3, 3): the rotation from the plane's axes to the CRS's axes at plane positions (rows: grid east,
        grid north and the ellipsoid normal, in the plane): the polar factor of :meth:`jacobian`."""
        J = self.jacobian(enu) if jacobian is None else jacobian
        u, _, vt = np.linalg.svd(J)
        return u @ vt

    # ---------------------------------------------------------------- attitudes
    def attitudes_from_crs(self, opk_crs: np.ndarray, axes: np.ndarray) -> np.ndarray:
        """omega, phi, kappa (n, 3; radians) against the plane of cameras whose angles are ``opk_crs`` against the
        CRS's axes at their positions (``axes``: :meth:`axes` there); NaN rows stay NaN."""
        return opk_from_matrix(matrix_from_opk(opk_crs) @ axes)

    def attitudes_to_crs(self, opk_plane: np.ndarray, axes: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`attitudes_from_crs`."""
        return opk_from_matrix(matrix_from_opk(opk_plane) @ np.swapaxes(axes, -1, -2))

    @staticmethod
    def attitude_jacobian(opk: np.ndarray, rotation: np.ndarray) -> np.ndarray:
        """d(angles of M(opk) · rotation)/d(opk) (n, 3, 3): how the angles of a camera change from one object
        frame to another (``rotation``: :meth:`axes` from the CRS to the plane, its transpose the other way)."""
        M, dM = matrix_from_opk_with_derivatives(np.asarray(opk, float))
        _, d_angles = opk_from_matrix_with_derivatives(M @ rotation)
        dM_rotated = dM @ rotation[..., None, :, :]                    # (n, 3 [angle l], 3, 3)
        return np.einsum("nkij,nlij->nkl", d_angles, dM_rotated)

    # ---------------------------------------------------------------- covariances
    @staticmethod
    def covariances(linear: np.ndarray, covariance: np.ndarray) -> np.ndarray:
        """``linear`` C ``linear``^T for (n, 3, 3) maps and covariances."""
        return np.einsum("nij,njk,nlk->nil", linear, covariance, linear)
