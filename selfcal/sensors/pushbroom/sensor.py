"""Pushbroom images in the adjustment engine: seed 001's generic sensor model behind the sensor contract.

Unknowns (:mod:`selfcal.sensors.base`): per image the attitude corrections of Eq. 6 (a constant and a
linear term in time for roll, pitch and yaw, the image block); per camera its focal length and the
three boresight angles (the core parameters) and, with ``--ap wavelet1d:NAME``, the 1-D wavelet APs
of its detector line (:mod:`selfcal.ap.line`). The sensor models M1-M7 of seed 001 (Table 1) say
which of them are estimated and M6 weights them (:data:`M6_SIGMA`).

Observations are the focal-plane positions (x_d, y_d) in mm of the detectors that recorded the image
points (the ideal line, displaced by the chips' known offsets); the prediction is the collinearity
condition of :func:`~.model.photo_coordinates` at the time of the observed line: the photo
coordinates (x, y) of the ground point in that line's telescope frame. Their standard deviation is
the image sigma (px) times the image motion per line along track and the detector spacing across
track, taken once at the start values (:func:`~.model.image_scales`): the residuals are in image
units, so a sensor with longer lines than detectors on the ground (usgscsm's LRO NAC ISD) is
weighted right. Object points are ECEF metres.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, replace

import numpy as np

from ...block import PushbroomCamera
from ...errors import BlockError, UsageError
from ..base import BoundSensor, ImageGeometry, Parameter, Sensor, WorkingColumns
from .jitter import JitterSpec, TimeWaveletBasis, parse_jitter, time_basis
from .model import (PARAMETER_NAMES, LineCamera, LineImage, fit_trajectory, ground_to_image, image_scales,
                    image_to_ground, line_of_sight, photo_coordinates, track)

__all__ = ["SENSOR_MODELS", "M6_SIGMA", "SensorModel", "sensor_model", "PushbroomSensor", "PushbroomBound", "attitude_table",
           "SENSOR", "line_images", "jitter_table", "FIT_ORDERS", "TELEMETRY_MARGIN_S", "IMAGE_PARAMETERS", "CAMERA_PARAMETERS"]

_P = {name: k for k, name in enumerate(PARAMETER_NAMES)}

#: the parameter sets of seed 001 (Table 1); M6 is M5 with parameter weights
SENSOR_MODELS = {
    "M1": ("d_roll0", "d_pitch0"),
    "M2": ("d_roll0", "d_pitch0", "d_yaw0"),
    "M3": ("d_roll0", "d_pitch0", "focal"),
    "M4": ("d_roll0", "d_pitch0", "d_yaw0", "focal"),
    "M5": ("d_roll0", "d_roll1", "d_pitch0", "d_pitch1", "d_yaw0", "d_yaw1"),
    "M6": ("d_roll0", "d_roll1", "d_pitch0", "d_pitch1", "d_yaw0", "d_yaw1"),
    "M7": ("d_roll0", "d_roll1", "d_pitch0", "d_pitch1", "d_yaw0", "d_yaw1", "focal"),
}

#: a-priori sigma of M6's parameters (rad, rad/s): the uncertainty of the attitude data. Roll and
#: pitch are weighted more than yaw (seed 001: yaw steering takes the bulk of the yaw motion)
M6_SIGMA = {"d_roll0": 1.0e-4, "d_pitch0": 1.0e-4, "d_yaw0": 5.0e-4,
            "d_roll1": 1.0e-5, "d_pitch1": 1.0e-5, "d_yaw1": 5.0e-5}

#: polynomial orders of the ephemeris position, velocity and attitude fits (Eq. 5)
FIT_ORDERS = (7, 7, 3)
#: telemetry used beyond each end of an image
TELEMETRY_MARGIN_S = 10.0

_UNITS = dict(zip(PARAMETER_NAMES, ("rad", "rad/s", "rad", "rad/s", "rad", "rad/s", "mm", "rad", "rad", "rad")))
#: the image block: the attitude corrections of Eq. 6
IMAGE_PARAMETERS = tuple(Parameter(n, _UNITS[n], "EOP", screened=True) for n in PARAMETER_NAMES[:6])
#: the camera's own parameters: focal length and boresight angles
CAMERA_PARAMETERS = tuple(Parameter(n, _UNITS[n], "IOP", screened=True) for n in PARAMETER_NAMES[6:])


@dataclass(frozen=True)
class SensorModel:
    """Which calibration parameters are estimated, and with which a-priori sigma (inf: free)."""

    name: str
    free: tuple[str, ...]
    prior_sigma: dict

    def mask(self) -> np.ndarray:
        return np.array([n in self.free for n in PARAMETER_NAMES])

    def sigmas(self) -> np.ndarray:
        return np.array([self.prior_sigma.get(n, np.inf) for n in PARAMETER_NAMES])


def sensor_model(spec: str, prior_sigma: dict | None = None) -> SensorModel:
    """``M1`` ... ``M7``, or an explicit comma-separated list of parameter names (free unless
    ``prior_sigma`` weights them)."""
    if spec.upper() in SENSOR_MODELS:
        name = spec.upper()
        sigmas = dict(M6_SIGMA) if name == "M6" else {}
        sigmas.update(prior_sigma or {})
        return SensorModel(name, SENSOR_MODELS[name], sigmas)
    names = tuple(n.strip() for n in spec.split(",") if n.strip())
    unknown = [n for n in names if n not in _P]
    if unknown or not names:
        raise UsageError(f"unknown sensor model {spec!r}: use M1..M7 or parameter names from "
                         f"{', '.join(PARAMETER_NAMES)}")
    return SensorModel("custom", names, dict(prior_sigma or {}))


def _model_of(options) -> SensorModel:
    return sensor_model(options.model or "M6", options.parameter_sigma)


def _fit_image(block, k: int, given_attitude: bool, orders, margin_s: float) -> LineImage:
    """The nominal line image of image ``k``: its camera's telemetry within ``margin_s`` of its lines, fitted."""
    cam = block.cameras[block.images.camera_id[k]]
    t_first = float(block.images.time_s[k]) + cam.t0_s
    t_last = t_first + cam.rows * cam.line_period_s
    e, a = block.ephemeris, block.attitude
    pick_e = (e.camera_id == cam.camera_id) & (e.time_s >= t_first - margin_s) & (e.time_s <= t_last + margin_s)
    pick_a = (a.camera_id == cam.camera_id) & (a.time_s >= t_first - margin_s) & (a.time_s <= t_last + margin_s)
    for name, pick, order in (("ephemeris.csv", pick_e, max(orders[:2])), ("attitude.csv", pick_a, orders[2])):
        if pick.sum() <= order + 1:
            raise BlockError(name, f"image '{block.images.image_id[k]}' ({t_first:.3f} - {t_last:.3f} s) has "
                                   f"{int(pick.sum())} samples within {margin_s:g} s; the fit of order {order} "
                                   f"needs more")
    camera = LineCamera(cam.camera_id, cam.columns, cam.center_col, cam.pixel_size_mm, cam.focal_mm,
                        cam.line_period_s, cam.view_pitch_deg, cam.chip_starts or (), cam.chip_offsets_px or ())
    t_ref = t_first + 0.5 * cam.rows * cam.line_period_s
    trajectory = fit_trajectory(cam.frame, cam.epoch_utc, e.time_s[pick_e], e.position_m[pick_e],
                                e.velocity_m_s[pick_e], a.time_s[pick_a], a.quaternion[pick_a], orders,
                                t_ref=t_ref, given_attitude=given_attitude)
    return LineImage.nominal(str(block.images.image_id[k]), camera, trajectory, t_first, cam.rows)


#: fitted images by (telemetry, image, attitude use): snooping and screening re-adjust the same images
_FITTED: dict = {}


def line_images(block, given_attitude: bool = True, orders=FIT_ORDERS, margin_s: float = TELEMETRY_MARGIN_S,
                image_index=None) -> list[LineImage]:
    """The nominal line image of every image of a pushbroom block (``image_index``: of some), each with its
    camera's ephemeris and attitude fitted over its lines +/- ``margin_s`` (Eq. 5). The fits are kept for
    the next adjustment of the same telemetry."""
    index = range(len(block.images)) if image_index is None else image_index
    out = []
    for k in index:
        cam = block.cameras[block.images.camera_id[k]]
        key = (id(block.ephemeris), id(block.attitude), id(cam), str(block.images.image_id[k]),
               float(block.images.time_s[k]), bool(given_attitude), tuple(orders), float(margin_s))
        hit = _FITTED.get(key)
        if hit is None or hit[0] is not block.ephemeris or hit[1] is not block.attitude or hit[2] is not cam:
            if len(_FITTED) > 256:
                _FITTED.clear()
            hit = _FITTED[key] = (block.ephemeris, block.attitude, cam,
                                  _fit_image(block, k, given_attitude, orders, margin_s))
        out.append(hit[3])
    return out


class PushbroomBound(BoundSensor):
    """The pushbroom images of a problem (module docstring)."""

    def __init__(self, problem, block, o, pixel, sigma_px, options):
        self.problem = problem
        self.o = np.asarray(o)
        n = problem.n_image_observations
        mine = np.unique(problem.obs_image[self.o])
        self.images: dict[int, LineImage] = self.line_images(block, mine, options)
        self.row = np.full(n, np.nan)
        self.col = np.full(n, np.nan)
        self.row[self.o], self.col[self.o] = pixel[:, 1], pixel[:, 0]
        self.sigma_px = np.asarray(sigma_px, float)
        self.detector = np.zeros((n, 2))
        self.t = np.zeros(n)
        self.scale = np.ones((n, 2))         # image motion per line (x) and detector spacing (y), mm, signed
        for i, image in self.images.items():
            sel = self.o[problem.obs_image[self.o] == i]
            self.detector[sel] = image.detector_mm(self.col[sel])
            self.t[sel] = image.time_of_row(self.row[sel])
            self.scale[sel] = image.camera.pixel_size_mm
        self._by_image = {i: self.o[problem.obs_image[self.o] == i] for i in self.images}
        # the telemetry at every observation's time: what the calibration parameters leave unchanged
        self._track = {i: track(self.images[i], self.t[o]) for i, o in self._by_image.items()}
        self._track_row = np.zeros(n, np.int64)
        for o in self._by_image.values():
            self._track_row[o] = np.arange(len(o))
        self.jitter: TimeWaveletBasis | None = None
        self.jitter_offset = 0
        self._working: WorkingColumns | None = None
        self._slot_columns: np.ndarray | None = None

    def attach_jitter(self, basis: TimeWaveletBasis | None, offset: int) -> None:
        """Give the images the attitude jitter ``basis`` (:mod:`.jitter`), its coefficients in the image block from
        column ``offset`` on: the functions of every axis of :attr:`attitude_axes` in turn."""
        self.jitter, self.jitter_offset = basis, int(offset)
        self._working = None
        self._slot_columns = None
        if basis is None:
            return
        tau = np.zeros(self.problem.n_image_observations)
        for i, o in self._by_image.items():
            tau[o] = self.row[o] / self.images[i].rows
        self._jitter_tau = tau
        # the raw functions at each observation's line, constant over the adjustment: a few per observation
        self._jitter_index = np.full((self.problem.n_image_observations, basis.reach), -1, np.int64)
        self._jitter_value = np.zeros((self.problem.n_image_observations, basis.reach))
        self._jitter_index[self.o], self._jitter_value[self.o] = basis.local(tau[self.o])

    def working_columns(self) -> WorkingColumns | None:
        """With jitter of many functions: the image's own parameters and the raw scaling functions
        (:meth:`.jitter.TimeWaveletBasis.working_map`; the powers of time the functions are made orthogonal to are
        the own polynomial's columns, :meth:`power_columns`): an observation touches its own columns and
        :attr:`~.jitter.TimeWaveletBasis.reach` raw functions per axis. None where that is not under half the
        image's width (a few functions, or long ones: Meyer's)."""
        basis, offset, width = self.jitter, self.jitter_offset, self.problem.image_width
        if basis is None or width != offset + 3 * basis.size:
            return None
        slots = offset + 3 * basis.reach
        if 2 * slots >= width:
            return None
        if self._working is None or self._working.to_parameters.shape[-1] != width:
            maps = np.zeros((self.problem.n_images, width, width))
            for i in self.images:
                maps[i] = basis.working_map(offset, *self.power_columns(i))
            self._working = WorkingColumns(maps, slots)
        return self._working

    def power_columns(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """The own columns (3, n_powers) that are d f / d(constant increment of each attitude axis) times the powers
        of the jitter's s = 2 row / rows - 1 in image ``i``, and their scale (n_powers,): D_a s^k = scale[k] * own
        column [a, k]. Seed 001's d_0 + d_1 (t - t_ref): s = (t - t_ref) / (rows line_period / 2)."""
        image = self.images[i]
        return np.array([[0, 1], [2, 3], [4, 5]]), np.array([1.0, 2.0 / (image.rows * image.camera.line_period_s)])

    def _jitter_functions(self, o: np.ndarray) -> np.ndarray:
        """B (n, m): the jitter's functions at the lines of observations ``o``."""
        assert self.jitter is not None
        index, value = self._jitter_index[o], self._jitter_value[o]
        raw = np.zeros((len(o), self.jitter.size + 1))                    # index -1: the last, dropped column
        raw[np.arange(len(o))[:, None], index] = value                    # (a row's valid indices are distinct)
        return raw[:, :-1] - self.jitter.powers(self._jitter_tau[o]) @ self.jitter.kept_projection

    def undetermined_image_parameters(self, images):
        """The jitter functions of an image with fewer than :data:`JITTER_MIN_OBSERVATIONS` observations where their
        raw scaling function (before the polynomial is taken off) reaches a tenth of its peak: their support (the
        functions at the ends of the lines, or over a gap of tie points). Counted from the few raw functions at each
        observation's line (:meth:`~.jitter.TimeWaveletBasis.local`)."""
        if self.jitter is None:
            return None
        out = np.zeros((len(images), self.problem.image_width), bool)
        m = self.jitter.size
        peak = self.jitter.slot_peaks                  # phi's (and psi's, with details) largest value
        for row, i in enumerate(images):
            mine = self._by_image.get(int(i), np.zeros(0, np.int64))
            index, value = self._jitter_index[mine], self._jitter_value[mine]
            inside = (np.abs(value) >= 0.1 * peak[None, :]) & (index >= 0)
            count = np.bincount(index[inside], minlength=m)
            weak = np.tile(count < JITTER_MIN_OBSERVATIONS, 3)
            out[row, self.jitter_offset:self.jitter_offset + 3 * m] = weak
        return out

    def jitter_coefficients(self, state, i: int) -> np.ndarray:
        """(3, m) the jitter coefficients of image ``i`` along :attr:`attitude_axes` (rad)."""
        assert self.jitter is not None
        m = self.jitter.size
        return np.asarray(state.image[i, self.jitter_offset:self.jitter_offset + 3 * m], float).reshape(3, m)

    def _with_jitter(self, state, i: int) -> tuple | None:
        """(basis, roll/pitch/yaw coefficients (3, m)) of image ``i``, or None without jitter."""
        if self.jitter is None:
            return None
        return self.jitter, self.roll_pitch_yaw(i) @ self.jitter_coefficients(state, i)

    def roll_pitch_yaw(self, i: int) -> np.ndarray:
        """(3, 3): the roll, pitch, yaw increments of unit increments of :attr:`attitude_axes` (here the same)."""
        return np.eye(3)

    def line_images(self, block, images: np.ndarray, options) -> dict[int, LineImage]:
        """The nominal line image of each of ``images``: given in the block (its sensor_file), or fitted to the
        block's telemetry."""
        given = block.image_models or {}
        fitted = [k for k in images if block.images.image_id[k] not in given]
        out = dict(zip(fitted, line_images(block, options.attitude_telemetry, image_index=fitted)))
        out.update({k: given[block.images.image_id[k]] for k in images if k not in out})
        return {int(k): out[k] for k in images}

    def observations(self):
        return self.detector[self.o], np.abs(self.scale[self.o]) * self.sigma_px[:, None]

    def _image(self, state, i: int) -> LineImage:
        k = self.problem.image_camera[i]
        return self.images[i].with_parameters(np.concatenate([state.image[i, :6], state.cameras[k][:4]]),
                                              jitter=self._with_jitter(state, i))

    def refine_sigma(self, state, sigma):
        context = self.context(state)
        for i, o in self._by_image.items():
            self.scale[o] = image_scales(context[i], state.points[self.problem.obs_point[o]], self.row[o], self.col[o])
        mine = self.o
        sigma[mine] = np.abs(self.scale[mine]) * self.sigma_px[:, None]

    def context(self, state, jacobians: bool = True):
        return {i: self._image(state, i) for i in self.images}

    #: the image block's columns of a constant increment of each of :attr:`attitude_axes` (d_roll0, d_pitch0, d_yaw0)
    attitude_constant_columns: tuple[int, ...] = (0, 2, 4)

    def predict(self, context, o, img, cam, points, jacobians):
        """The sensor's prediction (:meth:`_predict`) and, with jitter, its columns: d f / d c_ak = d f / d(constant
        increment of axis a) phi_k(tau) (:meth:`attach_jitter`)."""
        out = self._predict(context, o, img, cam, points, jacobians)
        if not jacobians or self.jitter is None:
            return out
        f, j_own, j_p, j_c = out
        B = self._jitter_functions(o)                                                    # (n, m)
        j_axes = j_own[:, :, list(self.attitude_constant_columns)]                      # (n, 2, 3)
        m = B.shape[1]
        j_e = np.zeros((len(o), 2, self.problem.image_width))
        j_e[:, :, :self.jitter_offset] = j_own
        j_e[:, :, self.jitter_offset:self.jitter_offset + 3 * m] = \
            np.einsum("nra,nk->nrak", j_axes, B).reshape(len(o), 2, 3 * m)
        return f, j_e, j_p, j_c

    def predict_working(self, context, o, img, cam, points):
        """:meth:`predict`'s rows in the :meth:`working_columns`: the image's own columns and d f / d(constant
        increment of axis a) times the raw functions at the observation's line."""
        working = self.working_columns()
        assert working is not None and self.jitter is not None
        f, j_own, j_p, j_c = self._predict(context, o, img, cam, points, True)
        basis, offset, n = self.jitter, self.jitter_offset, len(o)
        reach, m = basis.reach, basis.size
        j_axes = j_own[:, :, list(self.attitude_constant_columns)]                      # (n, 2, 3)
        j_w = np.empty((n, 2, working.slots))
        j_w[:, :, :offset] = j_own
        np.multiply(j_axes[:, :, :, None], self._jitter_value[o][:, None, None, :],
                    out=j_w[:, :, offset:].reshape(n, 2, 3, reach))
        if self._slot_columns is None:                 # constant over the adjustment: the lines do not move
            index = np.maximum(self._jitter_index, 0)                                   # -1: a zero value
            self._slot_columns = np.concatenate(
                [np.broadcast_to(np.arange(offset), (len(index), offset)),
                 (offset + m * np.arange(3)[None, :, None] + index[:, None, :]).reshape(len(index), 3 * reach)], 1)
        return f, j_w, self._slot_columns[o], j_p, j_c

    @property
    def own_width(self) -> int:
        """The image columns of :meth:`_predict`: the sensor's own (the jitter's come after them)."""
        return self.jitter_offset if self.jitter is not None else self.problem.image_width

    def _predict(self, context, o, img, cam, points, jacobians):
        m = len(img)
        f = np.zeros((m, 2))
        if jacobians:
            j_e, j_p, j_c = np.zeros((m, 2, self.own_width)), np.zeros((m, 2, 3)), np.zeros((m, 2, 4))
        for i in np.unique(img):
            sel = np.flatnonzero(img == i)
            telemetry = self._track[int(i)].take(self._track_row[o[sel]])
            out = photo_coordinates(context[int(i)], points[sel], self.t[o[sel]], jacobians, telemetry)
            if not jacobians:
                f[sel] = out
                continue
            f[sel] = out[0]
            j_e[sel, :, :6], j_c[sel] = out[1][:, :, :6], out[1][:, :, 6:]
            j_p[sel] = out[2]
        return (f, j_e, j_p, j_c) if jacobians else f

    def ap_columns(self, camera, o, ap, out=None):
        """The line APs displace the detectors (the observations): Delta = -p B per coefficient."""
        B = ap.basis(self.col[o])
        m = B.shape[1]
        p = self.problem.cameras[camera].pixel_size_mm
        if out is None:
            out = np.zeros((len(o), 2, 2 * m))
        else:
            out[:] = 0.0
        out[:, 0, :m] = -p * B
        out[:, 1, m:] = -p * B
        return out

    def rays(self, context, img, pixel):
        origin, direction = np.zeros((len(img), 3)), np.zeros((len(img), 3))
        for i in np.unique(img):
            sel = np.flatnonzero(img == i)
            origin[sel], direction[sel] = line_of_sight(context[int(i)], pixel[sel, 1], pixel[sel, 0])
        return origin, direction

    def pixels(self, context, img, points):
        out = np.full((len(img), 2), np.nan)
        for i in np.unique(img):
            sel = np.flatnonzero(img == i)
            row, col = ground_to_image(context[int(i)], points[sel])
            out[sel] = np.column_stack([col, row])
        return out

    def ground_sample_distance(self, state):
        """Mean over the observations of the range times the detector spacing over the focal length."""
        context = self.context(state, False)
        gsd = []
        for i, o in self._by_image.items():
            S, _ = line_of_sight(context[i], self.row[o], self.col[o])
            distance = np.linalg.norm(state.points[self.problem.obs_point[o]] - S, axis=1)
            gsd.append(distance * np.abs(self.scale[o, 1]) / context[i].parameters[6])
        return float(np.mean(np.concatenate(gsd))) if gsd else None

    def height(self, points):
        """Ellipsoidal heights (WGS 84) of ECEF points."""
        from ...geometry.earth import geodetic_from_ecef
        return geodetic_from_ecef(points)[2]

    def ground(self, context, img, pixel, height):
        out = np.full((len(img), 3), np.nan)
        for i in np.unique(img):
            sel = np.flatnonzero(img == i)
            out[sel] = image_to_ground(context[int(i)], pixel[sel, 1], pixel[sel, 0], height)
        return out

    #: names of the attitude corrections that :meth:`attitude_design` maps the image parameters to
    attitude_axes = ("roll", "pitch", "yaw")

    def attitude_design(self, i: int, rows: np.ndarray) -> np.ndarray:
        """(n, 3, width): d(correction of each of :attr:`attitude_axes`, rad)/d(image parameters) at ``rows`` of
        image ``i``: the sensor's polynomial (:meth:`polynomial_design`) and the jitter's functions."""
        out = self.polynomial_design(i, rows)
        if self.jitter is not None:
            B = self.jitter(np.asarray(rows, float) / self.images[i].rows)
            m = B.shape[1]
            for a in range(3):
                out[:, a, self.jitter_offset + a * m:self.jitter_offset + (a + 1) * m] = B
        return out

    def polynomial_design(self, i: int, rows: np.ndarray) -> np.ndarray:
        """:meth:`attitude_design` of the sensor's polynomial alone: Eq. 6, d_0 + d_1 (t - t_ref)."""
        tau = self.images[i].time_of_row(rows) - self.images[i].t_ref
        out = np.zeros((len(rows), 3, self.problem.image_width))
        for a in range(3):
            out[:, a, 2 * a] = 1.0
            out[:, a, 2 * a + 1] = tau
        return out

    def pixel_residuals(self, o, v):
        """v = f - l in mm: across track over the detector spacing is the column, along track over the
        (signed) image motion per line the negative row (a later line images the point further back)."""
        return np.column_stack([v[:, 1] / self.scale[o, 1], -v[:, 0] / self.scale[o, 0]])


class PushbroomSensor(Sensor):
    """Seed 001's generic pushbroom sensor (module docstring)."""

    name = "pushbroom"
    image_parameters = IMAGE_PARAMETERS
    camera_parameters = CAMERA_PARAMETERS
    ap_domain = "line"
    object_frame = "ECEF"
    #: an image is oriented by its telemetry: a mono image with three weighted GCPs adjusts (M6)
    min_points_per_image = 1
    sensor_models = tuple(SENSOR_MODELS)
    camera_type = PushbroomCamera
    needs_telemetry = True
    camera_keys = {
    "model": ("str", True),
    "columns": ("int", True),
    "rows": ("int", True),
    "center_col": ("num", True),
    "pixel_size_mm": ("pos", True),
    "focal_mm": ("pos", True),
    "line_period_s": ("pos", True),
    "epoch_utc": ("str", True),
    "frame": ("str", False),
    "view_pitch_deg": ("num", False),
    "t0_s": ("num", False),
    "chip_starts": ("intlist", False),
    "chip_offsets_px": ("pairlist", False),
}

    #: its bound images (:class:`PushbroomBound` or a subclass)
    bound_type: type = PushbroomBound
    #: the attitude jitter of its images (:meth:`configured`): None, or the basis
    jitter: TimeWaveletBasis | None = None
    jitter_spec: JitterSpec | None = None
    #: the image parameters of its attitude polynomial (and whatever else it corrects), before the jitter's
    polynomial_parameters: tuple[Parameter, ...] = IMAGE_PARAMETERS
    #: the axes its attitude corrections turn about (the names of attitude_corrections.csv's columns)
    attitude_axes: tuple[str, ...] = ("roll", "pitch", "yaw")
    #: the degree of its attitude polynomial in time (the jitter's functions are orthogonal to it)
    attitude_degree = 1

    def bind(self, problem, block, o, pixel, sigma_px, options):
        bound = self.bound_type(problem, block, o, pixel, sigma_px, options)
        bound.attach_jitter(self.jitter, len(self.polynomial_parameters))
        return bound

    def configured(self, options) -> "PushbroomSensor":
        """This sensor with the attitude jitter of ``options.jitter`` (:mod:`.jitter`; a level must be given: ``auto``
        is resolved by the workflow, :mod:`selfcal.workflows.jitter`): its image block grows by the coefficients of
        every axis of :attr:`attitude_axes`, named ``jitter_{axis}_L{level}k{translation}``."""
        spec = parse_jitter(getattr(options, "jitter", None))
        if spec is None:
            return self
        spec = replace(spec, sigma_rad=getattr(options, "jitter_sigma_rad", None), axes=getattr(options, "jitter_axes", None))
        unknown = sorted(set(spec.axes or ()) - set(self.attitude_axes))
        if unknown:
            raise UsageError(f"jitter axes {', '.join(unknown)}: a {self.name} image's attitude axes are "
                             f"{', '.join(self.attitude_axes)}")
        if spec.level is None:
            raise UsageError(f"--jitter {spec.text}: the level is chosen by the tested workflow (selfcal adjust "
                             f"--jitter auto); a single adjustment needs wavelet1d:NAME:LEVEL")
        key = (id(self), spec)
        hit = _CONFIGURED.get(key)
        if hit is None or hit[0] is not self:
            basis = time_basis(spec.wavelet, spec.level, self.attitude_degree, spec.details)
            sensor = copy.copy(self)
            sensor.jitter = basis
            sensor.jitter_spec = spec
            sensor.image_parameters = tuple(self.polynomial_parameters) + tuple(
                Parameter(f"jitter_{axis}_{name}", "rad", "jitter") for axis in self.attitude_axes for name in basis.names)
            hit = _CONFIGURED[key] = (self, sensor)
        return hit[1]

    def line_image(self, block, k: int, given_attitude: bool = True) -> LineImage:
        """The nominal line image of image ``k`` of ``block`` (no corrections): given in the block, or fitted to its
        camera's telemetry."""
        image_id = block.images.image_id[k]
        given = block.image_models or {}
        return given[image_id] if image_id in given else line_images(block, given_attitude, image_index=[k])[0]

    def image_geometry(self, block, k, image_parameters, camera_parameters):
        """The line image with its adjusted attitude corrections (6) and its camera's focal length and boresight
        (4): :func:`~.model.ground_to_image` and :func:`~.model.image_to_ground` on WGS 84 (the line APs of
        ``--ap wavelet1d`` are not in it: the caller refuses a camera with active ones)."""
        from ...geometry.earth import ecef_from_geodetic, geodetic_from_ecef
        image = self.line_image(block, k).with_parameters(
            np.concatenate([np.asarray(image_parameters, float)[:6], np.asarray(camera_parameters, float)[:4]]))

        def project(lon, lat, h):
            return ground_to_image(image, ecef_from_geodetic(np.radians(lat), np.radians(lon), h))

        def localize(row, col, h):
            row, col, h = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, float)) for v in (row, col, h)))
            lat, lon, _ = geodetic_from_ecef(image_to_ground(image, row, col, h))
            return np.degrees(lon), np.degrees(lat)

        return ImageGeometry(image.image_id, float(image.rows), float(image.camera.columns), project, localize)

    def check_camera(self, values):
        from datetime import datetime
        starts, offsets = values.get("chip_starts"), values.get("chip_offsets_px")
        if (starts is None) != (offsets is None) or (offsets is not None and len(offsets) != len(starts) + 1):
            return [("chip_offsets_px", "chip_starts (first column of every chip after the first) and "
                                        "chip_offsets_px (one [along, across] pair per chip) go together")]
        if starts and starts[-1] >= values["columns"]:
            return [("chip_starts", f"chip start {starts[-1]} is beyond the {values['columns']} columns")]
        if values.get("frame", "ECI") not in ("ECI", "ECEF"):
            return [("frame", f"frame must be \"ECI\" or \"ECEF\", found {values['frame']!r}")]
        try:
            datetime.fromisoformat(values["epoch_utc"].replace("Z", "+00:00"))
        except ValueError:
            return [("epoch_utc", f"epoch_utc must be an ISO 8601 instant (e.g. 2007-05-12T01:45:00Z), found "
                                  f"{values['epoch_utc']!r}")]
        return []

    def image_setup(self, block, image_index, options):
        """(free, a-priori sigma) of the image parameters: the attitude polynomial's (:meth:`polynomial_setup`), then
        the jitter's (free, weighted by ``--jitter``'s sigma where given; axes the spec leaves out held)."""
        free, sigma = self.polynomial_setup(block, image_index, options)
        if self.jitter is None:
            return free, sigma
        spec = self.jitter_spec
        assert spec is not None                 # (a configured copy has both)
        m = self.jitter.size
        axes = spec.axes or self.attitude_axes
        # an axis whose attitude polynomial is held (seed 001's M1 holds yaw; a usgscsm camera with twist = false)
        # has no jitter either
        columns = list(getattr(self.bound_type, "attitude_constant_columns"))
        axis_free = free[:, columns] & \
            np.array([a in axes for a in self.attitude_axes])[None, :]
        jitter_sigma = np.repeat(np.broadcast_to(np.nan if spec.sigma_rad is None else spec.sigma_rad, 3), m)
        n = len(image_index)
        return (np.hstack([free, np.repeat(axis_free, m, axis=1)]),
                np.hstack([sigma, np.broadcast_to(jitter_sigma, (n, 3 * m))]))

    def polynomial_setup(self, block, image_index, options):
        """:meth:`image_setup` of the attitude polynomial alone (seed 001's sensor model)."""
        model = _model_of(options)
        sigma = model.sigmas()[:6]
        shape = (len(image_index), 6)
        return (np.broadcast_to(model.mask()[:6], shape).copy(),
                np.broadcast_to(np.where(np.isfinite(sigma), sigma, np.nan), shape).copy())

    def result_files(self, result, slot):
        """attitude_corrections.csv: the estimated attitude corrections along each image with their sigma; with jitter
        also jitter_terms.csv (:func:`jitter_table`)."""
        files = {"attitude_corrections.csv": attitude_table(result, slot)}
        if slot.bound.jitter is not None:
            files["jitter_terms.csv"] = jitter_table(result, slot)
        return files

    def camera_setup(self, camera, options):
        model = _model_of(options)
        sigma = model.sigmas()[6:]
        return (np.array([camera.focal_mm, 0.0, 0.0, 0.0]), model.mask()[6:].copy(),
                np.where(np.isfinite(sigma), sigma, np.nan))

    def create_ap(self, spec, camera, observed, settings, model=None):
        """``wavelet1d:NAME`` along the camera's detector line (:mod:`selfcal.ap.line`), or none."""
        from ...ap import AP_FAMILIES, parse_ap_spec
        from ...ap.line import create_line_ap
        from ...ap.none import NoAP
        if model is not None:
            return model, np.zeros(model.n_params)
        if spec.strip().lower() == "none":
            return NoAP(None), np.zeros(0)
        if AP_FAMILIES.get(parse_ap_spec(spec)[0], NoAP).domain != "line":
            raise UsageError(f"AP model {spec}: a pushbroom block takes none or wavelet1d:NAME (NAME = dbN, symN, "
                             f"meyer, blN), the 1-D wavelet APs along the detector line")
        grid = settings.get("grid", (12, 12))
        try:
            ap = create_line_ap(spec, camera.columns, camera.center_col, camera.chip_starts or (), grid[0])
        except ValueError as exc:
            raise UsageError(f"AP model {spec}: {exc}") from None
        return ap, np.zeros(ap.n_params)


#: attitude_corrections.csv samples every image at this many lines (with jitter: this many per cell of its basis, at
#: least)
ATTITUDE_SAMPLES = 41
#: the minimal detectable bias of a jitter coefficient is this many sigma (Baarda's delta_0: a test at alpha 0.1 %,
#: two-sided, of power 80 %)
MDB_SIGMA = 4.13
_CONFIGURED: dict = {}
#: a jitter function is held in an image with fewer observations than this where its raw scaling function reaches a
#: tenth of its peak (:meth:`PushbroomBound.undetermined_image_parameters`)
JITTER_MIN_OBSERVATIONS = 4


def attitude_table(result, slot, samples: int = ATTITUDE_SAMPLES) -> tuple:
    """attitude_corrections.csv: per image, at ``samples`` lines from the first to the last, the time from the
    image centre and each attitude correction of its sensor (``{axis}_urad``) with its a-posteriori sigma, the
    coefficients' covariance carried through (held coefficients contribute nothing)."""
    problem, bound = result.problem, slot.bound
    width = problem.image_width
    Q = result.variance_factor * result.Q_theta
    cols: dict = {"image_id": [], "line": [], "time_s": []}
    axes = bound.attitude_axes
    for a in axes:
        cols[f"{a}_urad"], cols[f"sigma_{a}_urad"] = [], []
    if bound.jitter is not None:
        samples = max(samples, 8 * bound.jitter.cells + 1)
    for i in slot.images:
        i = int(i)
        image = bound.images[i]
        rows = np.linspace(0.0, image.rows, samples)
        G = bound.attitude_design(i, rows)                                  # (n, 3, width)
        free = problem.image_free[i]
        Qi = Q[i * width:(i + 1) * width, i * width:(i + 1) * width] * np.outer(free, free)
        value = G @ result.state.image[i]
        sigma = np.sqrt(np.maximum(np.einsum("nak,kl,nal->na", G, Qi, G), 0.0))
        cols["image_id"] += [str(result.block.images.image_id[i])] * samples
        cols["line"] += list(rows)
        cols["time_s"] += list(image.time_of_row(rows) - image.t_ref)
        for a, name in enumerate(axes):
            cols[f"{name}_urad"] += list(value[:, a] * 1e6)
            cols[f"sigma_{name}_urad"] += list(sigma[:, a] * 1e6)
    header = list(cols)
    columns = [np.array(cols[h], dtype=object if h == "image_id" else float) for h in header]
    return header, columns, [""] + [".1f", ".4f"] + [".4f"] * (len(header) - 3)


def jitter_table(result, slot) -> tuple:
    """jitter_terms.csv: per image, attitude axis and function of the jitter basis (``term``: level and translation),
    its coefficient and a-posteriori sigma (urad), t = value / sigma, the minimal detectable bias (MDB_SIGMA sigma,
    urad) and whether it was estimated (0: held, an axis without jitter)."""
    problem, bound = result.problem, slot.bound
    width, offset, m = problem.image_width, bound.jitter_offset, bound.jitter.size
    Q = result.variance_factor * result.Q_theta
    cols: dict = {k: [] for k in ("image_id", "axis", "term", "value_urad", "sigma_urad", "t", "mdb_urad", "active")}
    names = bound.jitter.names
    for i in slot.images:
        i = int(i)
        index = np.arange(i * width + offset, i * width + offset + 3 * m)
        free = problem.image_free[i, offset:offset + 3 * m]
        sigma = np.where(free, np.sqrt(np.maximum(np.asarray(Q.diagonal())[index], 0.0)), np.nan)
        value = result.state.image[i, offset:offset + 3 * m]
        cols["image_id"] += [str(result.block.images.image_id[i])] * 3 * m
        cols["axis"] += [a for a in bound.attitude_axes for _ in range(m)]
        cols["term"] += names * 3
        cols["value_urad"] += list(value * 1e6)
        cols["sigma_urad"] += list(sigma * 1e6)
        cols["t"] += list(np.abs(value) / sigma)
        cols["mdb_urad"] += list(MDB_SIGMA * sigma * 1e6)
        cols["active"] += list(free.astype(int))
    header = list(cols)
    columns = [np.array(cols[h], dtype=object if h in ("image_id", "axis", "term") else
                        int if h == "active" else float) for h in header]
    return header, columns, ["", "", "", ".4f", ".4f", ".2f", ".4f", "d"]


SENSOR = PushbroomSensor()
