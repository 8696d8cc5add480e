"""Camera GNSS in a block's CRS: geodetic positions converted with pyproj, and flight lines (strips) found
from the exposure times and the direction of flight.

Heights. A GNSS receiver gives the height above the WGS 84 ellipsoid (h); a block's ``Z`` is whatever its CRS
says: a compound CRS with a vertical datum (``EPSG:32632+5773``, UTM with EGM96 heights) has orthometric heights,
and pyproj converts h to them through the geoid model (its grid must be installed: without it the conversion
fails rather than passing h through as PROJ's "ballpark" fallback does, see :func:`positions_in_crs`); a plain projected CRS (``EPSG:32632``) has no
vertical datum, and the heights are taken over as given. Heights already orthometric (``heights="orthometric"``)
are never converted: only the plan position is.
"""
from __future__ import annotations

import numpy as np

__all__ = ["HEIGHTS", "require_best", "check_block_crs", "positions_in_crs", "detect_strips", "STRIP_TURN_DEG", "STRIP_GAP_FACTOR",
           "grid_bearing_of_north", "opk_from_yaw_pitch_roll"]

HEIGHTS = ("ellipsoidal", "orthometric")
#: a change of the direction of flight by more than this starts a new strip (degrees)
STRIP_TURN_DEG = 30.0
#: a pause longer than this many times the median interval between exposures starts a new strip
STRIP_GAP_FACTOR = 3.0


def check_block_crs(crs: str) -> str:
    """The reason (a sentence) why GNSS positions cannot be put into a block whose ``crs`` is this, or ""."""
    from .tangent import tangent_plane_reason
    if crs in ("local", "", None):
        return ("the block's crs is \"local\" (an arbitrary frame): GNSS positions need a block in a projected CRS "
                "(set crs in block.toml, e.g. \"EPSG:32632\", with the block's coordinates in it)")
    reason = tangent_plane_reason(crs)          # the CRS must be one pyproj knows, and projected
    return f"the block's {reason}" if reason else ""


def positions_in_crs(xyz: np.ndarray, source_crs: str, target_crs: str, heights: str = "ellipsoidal") -> np.ndarray:
    """(n, 3) positions ``xyz`` of ``source_crs`` in ``target_crs`` (NaN rows stay NaN; a NaN height gives NaN Z).

    A geographic source is read in the traditional GIS order: x the longitude, y the latitude (degrees).
    ``heights="ellipsoidal"``: the third coordinate is the ellipsoidal height of a geographic source (a 2-D
    geographic CRS such as EPSG:4326 is taken as its 3-D form, EPSG:4979) and converted along with the plan
    position by the most accurate transformation PROJ has (a missing geoid grid is an error, never PROJ's
    "ballpark" fallback, which passes h through as if it were an orthometric height). ``heights="orthometric"``: the plan position is converted and the height kept.

    Raises
    ------
    ValueError
        When pyproj cannot convert (no transformation, a missing grid, a position outside the CRS's area).
    """
    from pyproj import CRS, Transformer
    from pyproj.exceptions import ProjError
    if heights not in HEIGHTS:
        raise ValueError(f"heights must be one of {HEIGHTS}, found {heights!r}")
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    source, target = CRS.from_user_input(source_crs), CRS.from_user_input(target_crs)
    out = np.full_like(xyz, np.nan)
    plan = np.isfinite(xyz[:, :2]).all(axis=1)
    if not plan.any():
        return out
    try:
        if heights == "ellipsoidal":
            if source.is_geographic and len(source.axis_info) == 2:
                source = source.to_3d()
            require_best(source, target)
            transformer = Transformer.from_crs(source, target, always_xy=True, only_best=True)
            z = xyz[plan, 2]
            has_z = np.isfinite(z)
            done = np.column_stack(transformer.transform(xyz[plan, 0], xyz[plan, 1], np.where(has_z, z, 0.0),
                                                         errcheck=True))
            done[~has_z, 2] = np.nan
        else:
            horizontal = target.sub_crs_list[0] if target.is_compound else target
            src2d = source.sub_crs_list[0] if source.is_compound else source
            require_best(src2d, horizontal)
            transformer = Transformer.from_crs(src2d, horizontal, always_xy=True, only_best=True)
            e, n = transformer.transform(xyz[plan, 0], xyz[plan, 1], errcheck=True)
            done = np.column_stack([e, n, xyz[plan, 2]])
    except ProjError as exc:
        raise ValueError(f"pyproj cannot convert {source.name} to {target.name}: {exc}") from None
    if not np.isfinite(done[:, :2]).all():
        raise ValueError(f"pyproj gave no position in {target.name} for some of the points (outside its area?)")
    out[plan] = done
    return out


def require_best(source, target) -> None:
    """Refuse when PROJ's best transformation is not available here (a geoid grid not installed): pyproj would
    fall back to a "ballpark" one that passes the ellipsoidal height through as an orthometric one."""
    import warnings

    from pyproj.transformer import TransformerGroup
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        group = TransformerGroup(source, target, always_xy=True)
    if not group.best_available:
        missing = "; ".join(op.name for op in group.unavailable_operations[:2])
        raise ValueError(f"the best transformation from {source.name} to {target.name} needs a grid that is not "
                         f"installed ({missing}): install it (projsync, or PROJ_NETWORK=ON), or give heights already "
                         f"in the block's vertical datum with --heights orthometric")


def detect_strips(time_s: np.ndarray, xy_m: np.ndarray, turn_deg: float = STRIP_TURN_DEG,
                  gap_factor: float = STRIP_GAP_FACTOR) -> np.ndarray:
    """Strip number (0, 1, ...) of each exposure, from the exposure times and the plan positions.

    The rule: take the exposures in time order; the leg from one exposure to the next has a course (its
    direction in plan) and a duration. A strip's course is that of its first leg. A new strip starts at an
    exposure when

    * the pause before it is longer than ``gap_factor`` times the median interval between exposures, or
    * the course of the leg to it differs from the strip's course by more than ``turn_deg`` (a turn).

    After a turn the new strip's course is set by its own first leg, so the leg across from one flight line
    to the next (perpendicular to both) only starts the strip; an image taken in the turn is a strip of its own.
    Exposures without a time keep the order given; exposures without a position are strips of their own.

    Returns an int array of strip numbers in the order of the input, numbered in time order.
    """
    t = np.asarray(time_s, float)
    xy = np.asarray(xy_m, float)[:, :2]
    n = len(t)
    if n == 0:
        return np.zeros(0, np.int64)
    order = np.argsort(np.where(np.isfinite(t), t, np.inf), kind="stable") if np.isfinite(t).all() \
        else np.arange(n)
    steps = np.diff(t[order])
    median = float(np.median(steps[steps > 0])) if np.any(steps > 0) else np.inf
    strip = np.zeros(n, np.int64)
    current, course = 0, None
    for k in range(1, n):
        a, b = order[k - 1], order[k]
        leg = xy[b] - xy[a]
        new = not (np.isfinite(leg).all() and np.hypot(*leg) > 0)
        if not new and np.isfinite(steps[k - 1]) and steps[k - 1] > gap_factor * median:
            new = True
        if not new:
            heading = np.arctan2(leg[0], leg[1])
            if course is None:
                course = heading
            else:
                turn = abs((heading - course + np.pi) % (2 * np.pi) - np.pi)
                new = np.degrees(turn) > turn_deg
        if new:
            current += 1
            course = None
        strip[b] = current
    return strip


def grid_bearing_of_north(lon_deg: np.ndarray, lat_deg: np.ndarray, crs: str) -> np.ndarray:
    """(n,) the direction of true north in the grid of the projected ``crs`` at each position: the grid azimuth
    (radians, clockwise from grid north) of a step to the north (minus the meridian convergence, by whichever sign
    convention: computed here from two projected points, 1e-6 degrees apart)."""
    from pyproj import Transformer
    t = Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    lon, lat = np.asarray(lon_deg, float), np.asarray(lat_deg, float)
    e0, n0 = t.transform(lon, lat)
    e1, n1 = t.transform(lon, lat + 1e-6)
    return np.arctan2(np.asarray(e1) - e0, np.asarray(n1) - n0)


def opk_from_yaw_pitch_roll(yaw_rad, pitch_rad, roll_rad, north_bearing_rad=0.0) -> np.ndarray:
    """omega, phi, kappa (n, 3; radians) of a camera whose attitude is given as a gimbal's yaw, pitch and roll.

    The gimbal's convention (DJI's GimbalYawDegree, GimbalPitchDegree, GimbalRollDegree): the camera's body axes
    are x forward along the optical axis, y to the right of the image, z down (to the image's bottom); its
    attitude in north-east-down is R = Rz(yaw) Ry(pitch) Rx(roll) (aerospace order), so that yaw is the true
    azimuth of the view (clockwise from north), pitch 0 looks at the horizon and -90 straight down (the top of
    the image then towards the yaw), roll turns about the optical axis. The image axes of DESIGN.md §2 are
    x_image = y_body, y_image = -z_body, z_image = -x_body; turned from true north-east-up into the grid
    (``north_bearing_rad``, :func:`grid_bearing_of_north`) they are the rows of M (object -> image).
    A nadir image with yaw psi has kappa = -psi.
    """
    from .rotation import opk_from_matrix
    y, p, r = (np.atleast_1d(np.asarray(a, float)) for a in (yaw_rad, pitch_rad, roll_rad))
    beta = np.broadcast_to(np.asarray(north_bearing_rad, float), y.shape)
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    # columns: body x, y, z in north-east-down
    R = np.stack([np.stack([cy * cp, sy * cp, -sp], -1),
                  np.stack([cy * sp * sr - sy * cr, sy * sp * sr + cy * cr, cp * sr], -1),
                  np.stack([cy * sp * cr + sy * sr, sy * sp * cr - cy * sr, cp * cr], -1)], -1)
    enu_from_ned = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    cb, sb = np.cos(beta), np.sin(beta)
    zero, one = np.zeros_like(beta), np.ones_like(beta)
    # a true azimuth a becomes the grid azimuth a + beta: a turn by -beta about up
    grid_from_enu = np.stack([np.stack([cb, sb, zero], -1), np.stack([-sb, cb, zero], -1),
                              np.stack([zero, zero, one], -1)], -2)
    body = grid_from_enu @ enu_from_ned @ R                 # columns: body axes in the grid (east, north, up)
    M = np.stack([body[..., :, 1], -body[..., :, 2], -body[..., :, 0]], -2)
    return opk_from_matrix(M)
