"""A frame camera with a rolling shutter: the sensor is read line by line, and the camera moves meanwhile.

Each image's pose (X0, Y0, Z0, omega, phi, kappa) is the pose at its **middle line**, at the image's time
(images.csv ``time_s``), as Pix4D and OpenDroneMap take it. An image point on line ``l`` of ``L`` lines was
exposed at

    dt = s * tau,   s = (l - L/2) / L   (from -1/2 at the first line to +1/2 at the last)

with the camera's readout time tau (the time from the first to the last line). For the lines read ``"down"``
(the default) l is the row and L the image height; ``"up"`` reads the last row first (s = -(row - H/2)/H),
``"right"`` and ``"left"`` read columns (a sensor turned by 90°). The collinearity of :mod:`.frame` then holds
with the projection centre and, optionally, the attitude at that time:

    X0(dt) = X0 + v dt,     (omega, phi, kappa)(dt) = (omega, phi, kappa) + w dt

The readout tau is one unknown of the camera (``readout`` in ms, a core parameter after c, x0, y0) with the
a-priori value ``readout_ms`` and sigma ``sigma_readout_ms`` of block.toml (a prior row of the engine's parameter
priors; absent: free; 0: held); screening tests it against 0 (a global shutter) and holds it there when it is
insignificant, as an AP. Its derivative is d(x, y)/d tau = (d(x, y)/dX0 . v + d(x, y)/d(omega, phi, kappa) . w) s.

**The velocity v** (and the rate w) of an image is *data*: the derivative of the positions (angles) of the images
of its strip over their times (images.csv ``X0..Z0`` - the GNSS, or the given orientation - and ``time_s``;
second-order differences on the uneven times, :func:`strip_rates`), taken once per problem and held. Why not the
adjusted positions, or a velocity estimated per image (Pix4D's choice)? Only the product v tau enters the
collinearity: with a free velocity per image the readout cannot be estimated (Pix4D estimates the displacement
per image with the readout known), and a velocity taken from the adjusted neighbours makes every observation
depend on three images (the Schur complement's structure is one image per observation) while changing the
velocity by its noise only: from GNSS of sigma 5 cm over the 2 x 2.5 s of a central difference, 0.014 m/s, 0.2 %
of 8 m/s. The strips are images.csv's ``strip_id`` (an empty id: all the camera's images in time order); a strip
needs two images with positions and times, images of it without a position take the velocity interpolated in
time. The attitude rate (``readout_rotation = true``) is taken the same way from the given attitudes (an IMU's);
it is worth it only where those are smooth in time (a gimbal's turns, not independent image attitudes).
"""
from __future__ import annotations

import numpy as np

from ..errors import UsageError
from ..geometry.rotation import matrix_from_opk, matrix_from_opk_with_derivatives
from .base import Parameter
from .frame import FrameBound, FrameSensor, photo_from_pixel, pixel_from_photo, project, \
    project_with_jacobians_indexed, rays

__all__ = ["READOUT_DIRECTIONS", "line_share", "strip_rates", "RollingFrameBound", "RollingFrameSensor", "SENSOR",
           "rolling_table"]

#: the direction the lines are read in, in the stored image: (axis of the line coordinate: 0 col, 1 row; sign)
READOUT_DIRECTIONS = {"down": (1, 1.0), "up": (1, -1.0), "right": (0, 1.0), "left": (0, -1.0)}
#: the readout's index among a rolling camera's core parameters (after c, x0, y0)
READOUT = 3


def line_share(pixel: np.ndarray, width_px: np.ndarray, height_px: np.ndarray, direction) -> np.ndarray:
    """s (n,) of image points (col, row): the time of their line after the middle line, as a share of the readout
    (-1/2 at the first line read, +1/2 at the last); ``direction`` one of :data:`READOUT_DIRECTIONS` per point
    (or one for all)."""
    pixel = np.asarray(pixel, float)
    direction = np.broadcast_to(np.asarray(direction, object), (len(pixel),))
    axis = np.array([READOUT_DIRECTIONS[d][0] for d in direction], np.int64)
    sign = np.array([READOUT_DIRECTIONS[d][1] for d in direction])
    size = np.where(axis == 1, np.asarray(height_px, float), np.asarray(width_px, float))
    coordinate = np.where(axis == 1, pixel[:, 1], pixel[:, 0])
    return sign * (coordinate - size / 2.0) / size


def strip_rates(time_s: np.ndarray, values: np.ndarray, groups: np.ndarray, unwrap: bool = False
                ) -> tuple[np.ndarray, list[str]]:
    """Rates (n, 3) of ``values`` (n, 3; positions or angles) over ``time_s`` within each group (a strip): second-order
    differences on the uneven times (one-sided at a strip's ends; a plain difference for a strip of two); where an
    image has no value, the rate interpolated in time from its strip's. ``unwrap``: angles (a turn across ±pi).
    Returns the rates (NaN where a strip has fewer than two images with values and times) and the groups that
    have too few."""
    rates = np.full((len(time_s), 3), np.nan)
    short = []
    for group in dict.fromkeys(groups.tolist()):
        members = np.flatnonzero(groups == group)
        members = members[np.argsort(time_s[members], kind="stable")]
        known = members[np.isfinite(values[members]).all(axis=1) & np.isfinite(time_s[members])]
        if len(known) < 2 or len(np.unique(time_s[known])) < len(known):
            short.append(str(group))
            continue
        v = np.unwrap(values[known], axis=0) if unwrap else values[known]
        t = time_s[known]
        rate = (v[1:] - v[:1]) / (t[1] - t[0]) if len(known) == 2 else np.gradient(v, t, axis=0, edge_order=2)
        rate = np.broadcast_to(rate, (len(known), 3))
        timed = members[np.isfinite(time_s[members])]
        for a in range(3):
            rates[timed, a] = np.interp(time_s[timed], t, rate[:, a])
    return rates, short


class RollingFrameBound(FrameBound):
    """Frame images of rolling-shutter cameras: :class:`~.frame.FrameBound`'s observations and APs, the projection
    centre (and attitude) moved to each observation's line. The context adds the readout of every camera (s)."""

    def __init__(self, problem, block, o, pixel, sigma_px):
        super().__init__(problem, block, o, pixel, sigma_px)
        cams = [block.cameras[c] for c in problem.camera_ids]
        self.direction = np.array([getattr(c, "readout_direction", None) or "down" for c in cams], object)
        cam_of_obs = problem.image_camera[problem.obs_image[self.o]]
        w, h, _ = self.format_px[cam_of_obs].T
        self.share = np.zeros(problem.n_image_observations)
        self.share[self.o] = line_share(pixel, w, h, self.direction[cam_of_obs])
        images = block.images
        mine = np.unique(problem.obs_image[self.o])
        groups = np.array([f"{c}\x00{s}" for c, s in zip(images.camera_id, images.strip_id)], object)
        self.velocity = np.zeros((problem.n_images, 3))
        self.rate = None
        rotating = [bool(getattr(c, "readout_rotation", False)) for c in cams]
        for name, values, unwrap, wanted in (("positions (X0, Y0, Z0)", images.position_m, False, True),
                                             ("attitudes (omega, phi, kappa)", images.attitude_rad, True,
                                              any(rotating))):
            if not wanted:
                continue
            rates, short = strip_rates(images.time_s, values, groups, unwrap)
            missing = mine[~np.isfinite(rates[mine]).all(axis=1)]
            if missing.size:
                camera, strip = str(groups[missing[0]]).split("\x00")
                raise UsageError(
                    f"camera '{camera}' has a rolling shutter: the {'velocity' if not unwrap else 'attitude rate'} "
                    f"of an image comes from the {name} and times (images.csv time_s) of the images of its strip, "
                    f"and strip '{strip}' has fewer than two images with both, or two at one time (image "
                    f"'{images.image_id[missing[0]]}')")
            if unwrap:
                self.rate = np.where(np.array(rotating)[problem.image_camera][:, None], rates, 0.0)
            else:
                self.velocity[mine] = rates[mine]

    def context(self, state, jacobians: bool = True):
        readout_s = np.array([c[READOUT] if len(c) > READOUT else 0.0 for c in state.cameras]) / 1000.0
        return (*super().context(state, jacobians), readout_s)

    def _exposure(self, image: np.ndarray, readout_s: np.ndarray, o: np.ndarray | None, img: np.ndarray,
                  cam: np.ndarray, share: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """(shift of the projection centre (n, 3), the attitude at each observation's line (n, 3) or None where
        the attitude does not turn, s) of observations ``o`` (or of lines at ``share``)."""
        s = share if share is not None else self.share[o]
        dt = s * readout_s[cam]
        shift = self.velocity[img] * dt[:, None]
        angles = None if self.rate is None else image[img, 3:] + self.rate[img] * dt[:, None]
        return shift, angles, s

    def predict(self, context, o, img, cam, points, jacobians):
        image, iop, rotation, _, readout_s = context
        shift, angles, s = self._exposure(image, readout_s, o, img, cam)
        if not jacobians:
            eop = image[img].copy()
            eop[:, :3] += shift
            M = rotation[img] if angles is None else matrix_from_opk(angles)
            if angles is not None:
                eop[:, 3:] = angles
            return project(points, eop, iop[cam], M)
        if angles is None:
            f, j_e, j_p, j_i = project_with_jacobians_indexed(points, image, iop, rotation, img, cam, shift)
        else:
            eop = np.column_stack([image[img, :3], angles])
            f, j_e, j_p, j_i = project_with_jacobians_indexed(points, eop, iop, matrix_from_opk_with_derivatives(angles),
                                                              np.arange(len(o)), cam, shift)
        # d/d readout (ms): the centre moves by v s / 1000 per ms, the attitude by w s / 1000
        motion = np.einsum("nij,nj->ni", j_e[:, :, :3], self.velocity[img])
        if self.rate is not None:
            motion += np.einsum("nij,nj->ni", j_e[:, :, 3:], self.rate[img])
        j_readout = motion * (s / 1000.0)[:, None]
        return f, j_e, j_p, np.concatenate([j_i, j_readout[:, :, None]], axis=2)

    def rays(self, context, img, pixel):
        image, iop, rotation, _, readout_s = context
        cam = self.problem.image_camera[img]
        w, h, p = self.format_px[cam].T
        share = line_share(pixel, w, h, self.direction[cam])
        shift, angles, _ = self._exposure(image, readout_s, None, img, cam, share)
        M = rotation[0] if isinstance(rotation, tuple) else rotation
        eop = image[img].copy()
        if angles is not None:
            eop[:, 3:] = angles
        m = M[img] if angles is None else matrix_from_opk(angles)
        return image[img, :3] + shift, rays(photo_from_pixel(pixel, w, h, p), eop, iop[cam], m)

    def photo_coordinates(self, context, img, points, iterations: int = 4) -> np.ndarray:
        """Eq. (1) at the time of the line the point images on, with the additional parameters (mm): the line
        found by iterating from the middle line (each step shrinks the error by the image motion during the
        readout over the image size, ~1e-3)."""
        image, iop, rotation, values, readout_s = context
        cam = self.problem.image_camera[img]
        w, h, p = self.format_px[cam].T
        M = rotation[0] if isinstance(rotation, tuple) else rotation
        share = np.zeros(len(img))
        for _ in range(iterations):
            shift, angles, _ = self._exposure(image, readout_s, None, img, cam, share)
            eop = image[img].copy()
            eop[:, :3] += shift
            if angles is not None:
                eop[:, 3:] = angles
            xy = project(points, eop, iop[cam], M[img] if angles is None else matrix_from_opk(angles))
            xy = self.with_additional_parameters(xy, cam, values)
            share = line_share(pixel_from_photo(xy, w, h, p), w, h, self.direction[cam])
        return xy


class RollingFrameSensor(FrameSensor):
    """A frame camera with a rolling shutter (block.toml ``shutter = "rolling"``): the frame camera's parameters
    and its readout time (ms), the images' poses at their middle lines."""

    name = "frame-rolling"
    selectable = False
    camera_parameters = FrameSensor.camera_parameters + (
        Parameter("readout", "ms", "IOP", screened=True, key="readout_ms", reference=0.0,
                  spread_by_image=True),)

    def bind(self, problem, block, o, pixel, sigma_px, options):
        return RollingFrameBound(problem, block, o, pixel, sigma_px)

    def camera_setup(self, camera, options):
        value, free, sigma = super().camera_setup(camera, options)
        readout = 0.0 if camera.readout_ms is None else float(camera.readout_ms)
        given = camera.sigma_readout_ms
        readout_sigma = np.nan if given is None else float(given)
        return (np.append(value, readout), np.append(free, given != 0),
                np.append(sigma, readout_sigma))

    def result_files(self, result, slot):
        """rolling_shutter.csv: every image's velocity, the readout of its camera and the motion it makes."""
        return {"rolling_shutter.csv": rolling_table(result, slot)}


SENSOR = RollingFrameSensor()


def rolling_table(result, slot) -> tuple:
    """rolling_shutter.csv of the images of ``slot``: ``image_id, camera_id, strip_id, time_s``, the velocity
    ``vx_m_s, vy_m_s, vz_m_s`` (data: from the strip's positions and times), ``speed_m_s``, ``heading_deg`` (of the
    horizontal velocity, clockwise from +Y), the attitude rates ``omega_rate_deg_s ...`` (0 where the attitude is not
    turned, ``readout_rotation``), the camera's ``readout_ms``, ``motion_m`` (the projection centre's path
    during the readout) and ``shear_col_px, shear_row_px``: the mean image displacement of the image's points
    between the first and the last line (what a global-shutter model would have to absorb)."""
    problem, state, bound = result.problem, result.state, slot.bound
    block = result.block
    images = np.asarray(slot.images)
    readout_ms = np.array([c[READOUT] if len(c) > READOUT else np.nan for c in state.cameras])
    cam = problem.image_camera[images]
    velocity = bound.velocity[images]
    speed = np.linalg.norm(velocity, axis=1)
    heading = np.degrees(np.arctan2(velocity[:, 0], velocity[:, 1])) % 360.0
    motion = speed * readout_ms[cam] / 1000.0
    # mean displacement of each image's points between the first (s = -1/2) and the last (s = +1/2) line
    o = slot.observations
    img, pt = problem.obs_image[o], problem.obs_point[o]
    context = bound.context(state, jacobians=False)
    image, iop, rotation, values, readout_s = context
    c = problem.image_camera[img]
    w, h, p = bound.format_px[c].T
    ends = []
    for s in (-0.5, 0.5):
        shift, angles, _ = bound._exposure(image, readout_s, None, img, c, np.full(len(o), s))
        eop = image[img].copy()
        eop[:, :3] += shift
        if angles is not None:
            eop[:, 3:] = angles
        M = rotation[img] if angles is None else matrix_from_opk(angles)
        ends.append(pixel_from_photo(project(state.points[pt], eop, iop[c], M), w, h, p))
    moved = ends[1] - ends[0]
    counts = np.maximum(np.bincount(img, minlength=problem.n_images), 1)
    shear = np.column_stack([np.bincount(img, moved[:, k], minlength=problem.n_images) / counts for k in (0, 1)])
    shear = shear[images]
    rate = np.zeros((len(images), 3)) if bound.rate is None else np.degrees(bound.rate[images])
    header = ["image_id", "camera_id", "strip_id", "time_s", "vx_m_s", "vy_m_s", "vz_m_s", "speed_m_s",
              "heading_deg", "omega_rate_deg_s", "phi_rate_deg_s", "kappa_rate_deg_s", "readout_ms", "motion_m",
              "shear_col_px", "shear_row_px"]
    columns = [block.images.image_id[images], block.images.camera_id[images], block.images.strip_id[images],
               block.images.time_s[images], *velocity.T, speed, heading, *rate.T, readout_ms[cam], motion, *shear.T]
    formats = ["", "", "", ".4f", ".4f", ".4f", ".4f", ".4f", ".2f", ".6f", ".6f", ".6f", ".4f", ".4f", ".3f",
               ".3f"]
    return header, columns, formats

