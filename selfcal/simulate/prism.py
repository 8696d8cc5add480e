"""A simulated ALOS/PRISM triplet with known truth (seed 001).

An ALOS-like sun-synchronous orbit (circular, 691.65 km, 98.16 deg, descending over the
scene), the three PRISM cameras (forward +23.8 deg, nadir, backward -23.8 deg view
pitch; 7 um detectors of three chips merged into one 14,496-column virtual array, each chip
displaced from the ideal line by a known fraction of a pixel; 2.5 m ground sample distance), a terrain model, and 28 ground points measured in all three images.

What the telemetry gets wrong is the truth the adjustment must find:

* each camera's focal length differs from the nominal 1939 mm (Table 2 of seed 001:
  1937.45 nadir, 1938.20 forward, 1936.66 backward);
* the attitude telemetry has a bias and a drift (rad, rad/s) against the true attitude,
  and each telescope is misaligned by small boresight angles;
* quaternions (10 Hz) and ephemeris (1 Hz) carry white noise;
* with ``jitter`` (:class:`Jitter`), the platform oscillates in roll and pitch: sinusoids of absolute time (the
  three cameras share the platform, so each image sees the same motion at its own times) that the attitude
  telemetry does not record (the star trackers and gyros are too slow or filtered), as CTX, HiRISE, ASTER
  and PRISM images show it.

Times count from the simulation's epoch; the nadir scene is centred at
:data:`NADIR_CENTRE_S`. All geometry is in ECEF (ITRS) metres with telemetry in the ECI
(GCRS) frame, as DESIGN.md §3 fixes them.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ..geometry.earth import geodetic_from_ecef, itrs_from_gcrs, orbit_frame
from ..geometry.rotation import quaternion_from_matrix
from ..sensors.pushbroom import (LineCamera, LineImage, Trajectory, fit_polynomial, ground_to_image, image_to_ground,
                                 rotation_x, rotation_y, rotation_z)

__all__ = ["PrismSimulation", "PrismTruth", "AnalyticDem", "Jitter", "JITTER", "simulate_prism", "detector_error", "prism_block",
           "dem_grid", "prism_truth_files", "LINE_ERROR_PX", "CAMERAS", "TRUE_FOCAL_MM", "NOMINAL_FOCAL_MM",
           "NADIR_CENTRE_S", "GCP_SIGMA_M"]

GM_M3_S2 = 3.986004418e14
ALTITUDE_M = 691_650.0
INCLINATION_DEG = 98.16
EPOCH_UTC = "2007-05-12T01:45:00Z"
NADIR_CENTRE_S = 60.0
SCENE_LAT_DEG, SCENE_LON_DEG = 36.2, 138.4

NOMINAL_FOCAL_MM = 1939.0
#: camera -> view pitch (deg), after seed 001; forward sees the scene first
CAMERAS = {"F": 23.8, "N": 0.0, "B": -23.8}
TRUE_FOCAL_MM = {"F": 1938.20, "N": 1937.45, "B": 1936.66}
#: true boresight misalignment of each telescope (roll, pitch, yaw), rad
TRUE_BORESIGHT_RAD = {"F": (1.0e-5, -2.0e-5, 3.0e-5), "N": (0.0, 0.0, 0.0), "B": (-1.5e-5, 1.0e-5, -2.0e-5)}
#: error of the attitude telemetry: true = given + bias + drift (t - NADIR_CENTRE_S), per axis roll, pitch, yaw
ATTITUDE_BIAS_RAD = np.array([3.0e-5, -4.0e-5, 6.0e-5])
ATTITUDE_DRIFT_RAD_S = np.array([1.5e-6, 3.0e-6, 3.0e-6])

COLUMNS = 14_496
#: the virtual array of each camera: three chips (first columns of the second and third) with known
#: (along, across) offsets in pixels
CHIP_STARTS = (4_832, 9_664)
CHIP_OFFSETS_PX = {"F": ((0.0, 0.0), (0.4, 0.5), (-0.7, -0.2)), "N": ((0.0, 0.0), (0.6, -0.4), (-0.5, 0.3)),
                   "B": ((0.0, 0.0), (-0.3, 0.6), (0.5, -0.5))}
ROWS = 14_000
#: the chip-wise error of the nadir camera's detector line that ``selfcal simulate prism --line-error`` adds
#: (unknown to the block): chips 2 and 3 misaligned by up to 0.9 px, the line bent by 1 px along track
#: and 0.5 px across at its centre
LINE_ERROR_PX = {"N": {"chip_px": ((0.0, 0.0), (0.9, -0.7), (-0.6, 0.9)), "bow_px": (1.0, 0.5)}}
PIXEL_SIZE_MM = 0.007
LINE_PERIOD_S = 0.000_37


@dataclass(frozen=True)
class AnalyticDem:
    """Rolling terrain (ellipsoidal heights, m) around the scene centre: 250 - 1150 m."""

    lat0_deg: float = SCENE_LAT_DEG
    lon0_deg: float = SCENE_LON_DEG

    def __call__(self, lat_deg, lon_deg) -> np.ndarray:
        north = (np.asarray(lat_deg, float) - self.lat0_deg) * 111_000.0
        east = (np.asarray(lon_deg, float) - self.lon0_deg) * 111_000.0 * np.cos(np.radians(self.lat0_deg))
        return (700.0 + 300.0 * np.sin(2 * np.pi * east / 23_000.0) * np.cos(2 * np.pi * north / 31_000.0)
                + 150.0 * np.sin(2 * np.pi * (east + north) / 47_000.0))


@dataclass(frozen=True)
class Jitter:
    """Attitude jitter of the platform: per axis (roll, pitch, yaw) sinusoids ``amplitude_rad[a][k] sin(2 pi
    frequency_hz[a][k] t + phase)`` of absolute time, their phases drawn per seed. Not in the telemetry."""

    frequency_hz: tuple[tuple[float, ...], ...] = ((1.3, 4.1), (2.2, 3.7), ())
    amplitude_rad: tuple[tuple[float, ...], ...] = ((3.0e-6, 2.0e-6), (3.0e-6, 2.0e-6), ())

    def phases(self, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
        return tuple(rng.uniform(0.0, 2 * np.pi, len(f)) for f in self.frequency_hz)

    def angles(self, t, phases) -> np.ndarray:
        """(n, 3) roll, pitch, yaw jitter at times t."""
        t = np.atleast_1d(np.asarray(t, float))
        out = np.zeros((len(t), 3))
        for a, (f, amp, ph) in enumerate(zip(self.frequency_hz, self.amplitude_rad, phases)):
            for fk, ak, pk in zip(f, amp, ph):
                out[:, a] += ak * np.sin(2 * np.pi * fk * t + pk)
        return out


#: the jitter of issue 42's triplet: 5 urad (about 1.4 px at 2.5 m) in roll and pitch at two frequencies of 1-4.5 Hz
JITTER = Jitter()


@dataclass(frozen=True)
class _Jittered:
    """A fitted attitude plus the platform's jitter (a time function of :class:`Trajectory`)."""

    smooth: Callable
    jitter: Jitter
    phases: tuple

    def __call__(self, t):
        smooth = self.smooth(t)
        return smooth + (self.jitter.angles(t, self.phases) if np.ndim(smooth) > 1 else
                         self.jitter.angles(t, self.phases)[0])


@dataclass
class PrismTruth:
    images: list[LineImage]          # true trajectories and parameters (focal, boresight; zero attitude corrections)
    focal_mm: dict[str, float]
    boresight_rad: dict[str, tuple]
    attitude_bias_rad: np.ndarray
    attitude_drift_rad_s: np.ndarray
    points_ecef: np.ndarray          # (n, 3)
    detector_error_px: dict = field(default_factory=dict)   # camera -> detector_error() arguments
    jitter: Jitter | None = None
    jitter_phases: tuple = ()

    def jitter_rad(self, t) -> np.ndarray:
        """(n, 3) the true roll, pitch, yaw jitter at times t (zero without jitter)."""
        t = np.atleast_1d(np.asarray(t, float))
        return np.zeros((len(t), 3)) if self.jitter is None else self.jitter.angles(t, self.jitter_phases)

    def jitter_error_urad(self, result, samples: int = 2001) -> tuple[np.ndarray, np.ndarray]:
        """The error of an adjustment's jitter (``result`` of the triplet F, N, B) against this truth beyond each
        image's linear part (bias and drift take that), RMS over the lines in urad, (roll, pitch): in all, and in what
        the tie points of one scene's fore-nadir-aft views can see: the roll beyond the part common to the three
        images (the ground under them moving alike) and the pitch along (1, -2, 1) (the common part moves the ground
        along the track, fore minus aft its heights)."""
        slot = result.problem.sensors[0]
        bound = slot.bound
        images, estimates = [], []
        for i in slot.images:
            image = bound.images[int(i)]
            rows = np.linspace(0, image.rows, samples)
            estimate = np.zeros((samples, 3))
            if bound.jitter is not None:
                G = bound.attitude_design(int(i), rows)
                estimate = G[:, :, bound.jitter_offset:] @ result.state.image[int(i), bound.jitter_offset:]
            images.append(image)
            estimates.append(estimate)
        return self.jitter_error_of(images, estimates)

    def jitter_sigma_urad(self, result, samples: int = 2001) -> np.ndarray:
        """The precision an adjustment states for its jitter (``result`` of the triplet), RMS over the lines and images
        of the a-posteriori sigma of the jitter's correction (urad, roll and pitch; the coefficients' covariance
        carried through, the priors' share included, held coefficients contributing nothing): what the observations
        and the priors determine, the floor against which :meth:`jitter_error_urad` is measured (zero without
        jitter)."""
        slot = result.problem.sensors[0]
        bound = slot.bound
        if bound.jitter is None:
            return np.zeros(2)
        problem, offset, width = result.problem, bound.jitter_offset, result.problem.image_width
        Q = result.variance_factor * result.Q_theta
        variances = []
        for i in slot.images:
            i = int(i)
            G = bound.attitude_design(i, np.linspace(0, bound.images[i].rows, samples))[:, :2, offset:]
            free = problem.image_free[i, offset:]
            block = slice(i * width + offset, (i + 1) * width)
            Qi = Q[block, block] * np.outer(free, free)
            variances.append(np.einsum("nak,kl,nal->na", G, Qi, G))
        return np.sqrt(np.maximum(np.mean(variances, axis=(0, 1)), 0.0)) * 1e6

    def jitter_error_of(self, images, estimates) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`jitter_error_urad` of estimated jitter curves: per image of the triplet (F, N, B) its
        :class:`LineImage` and the estimated roll, pitch, yaw (rad, (samples, 3)) at ``linspace(0, rows, samples)``
        (an estimator that is not selfcal's, e.g. ``benchmarks/referee_asp_jitter.py``, gives its own curves)."""
        errors = []
        for image, estimate in zip(images, estimates):
            samples = len(estimate)
            rows = np.linspace(0, image.rows, samples)
            truth = self.jitter_rad(image.time_of_row(rows))
            V = np.stack([np.ones(samples), 2 * rows / image.rows - 1], -1)
            truth -= V @ np.linalg.lstsq(V, truth, rcond=None)[0]
            errors.append((np.asarray(estimate, float) - truth)[:, :2])
        error = np.array(errors)                                         # (F, N, B), lines, (roll, pitch)
        roll = error[:, :, 0] - error[:, :, 0].mean(axis=0)
        pitch = np.einsum("k,kn->n", np.array([1.0, -2.0, 1.0]) / np.sqrt(6.0), error[:, :, 1])
        total = np.sqrt(np.mean(error ** 2, axis=(0, 1))) * 1e6
        return total, np.array([np.sqrt(np.mean(roll ** 2)), np.sqrt(np.mean(pitch ** 2) / 3)]) * 1e6


@dataclass
class PrismSimulation:
    epoch_utc: str
    cameras: dict[str, LineCamera]   # nominal: focal 1939 mm, no boresight
    image_ids: list[str]             # "F", "N", "B"
    t_first_s: dict[str, float]
    rows: int
    ephemeris: dict[str, np.ndarray]  # t (n,), position (n, 3), velocity (n, 3): ECI, 1 Hz, noisy
    attitude: dict[str, np.ndarray]   # t (n,), quaternion (n, 4) q1..q4 scalar last, body -> ECI, 10 Hz, noisy
    point_ids: list[str]
    points_ecef: np.ndarray           # true coordinates (n, 3)
    obs_image: np.ndarray             # index into image_ids
    obs_point: np.ndarray
    obs_row: np.ndarray
    obs_col: np.ndarray
    image_sigma_px: float
    dem: AnalyticDem
    truth: PrismTruth


# --- the true motion ------------------------------------------------------------------------------

def _orbit(t: np.ndarray, raan: float, u0: float):
    """Circular Keplerian orbit in the GCRS: position and velocity (n, 3)."""
    radius = 6_378_137.0 + ALTITUDE_M
    n = np.sqrt(GM_M3_S2 / radius ** 3)
    inc = np.radians(INCLINATION_DEG)
    P = np.array([np.cos(raan), np.sin(raan), 0.0])
    Q = np.array([-np.cos(inc) * np.sin(raan), np.cos(inc) * np.cos(raan), np.sin(inc)])
    u = u0 + n * (np.asarray(t, float) - NADIR_CENTRE_S)
    pos = radius * (np.cos(u)[:, None] * P + np.sin(u)[:, None] * Q)
    vel = radius * n * (-np.sin(u)[:, None] * P + np.cos(u)[:, None] * Q)
    return pos, vel


def _true_attitude(t: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw (n, 3) of the body in the orbit frame: slow orbital variations and a
    small constant yaw (smooth over a scene, as a star tracker controlled platform)."""
    phase = 2 * np.pi * np.asarray(t, float) / 5_900.0
    return np.stack([2.0e-4 * np.sin(phase + 0.3), 1.5e-4 * np.cos(phase), 1.0e-3 + 1.0e-4 * np.sin(2 * phase)], -1)


def _true_trajectory(raan: float, u0: float, t0: float, t1: float) -> Trajectory:
    """Noise-free trajectory over [t0, t1], as high-order polynomials of dense samples (fit
    residuals below 1 um and 1e-12 rad: the polynomials are the truth)."""
    t = np.linspace(t0, t1, 201)
    pos, vel = _orbit(t, raan, u0)
    p, _ = fit_polynomial(t, pos, 9)
    v, _ = fit_polynomial(t, vel, 9)
    a, _ = fit_polynomial(t, _true_attitude(t), 9)
    return Trajectory("ECI", EPOCH_UTC, p, v, a)


def _place_orbit() -> tuple[float, float]:
    """RAAN and argument of latitude at NADIR_CENTRE_S for a descending pass over the scene."""
    inc = np.radians(INCLINATION_DEG)
    lat = np.radians(SCENE_LAT_DEG)
    u0 = np.pi - np.arcsin(np.sin(lat) / np.sin(inc))          # descending branch
    raan = 0.0
    for _ in range(3):
        pos, _ = _orbit(np.array([NADIR_CENTRE_S]), raan, u0)
        ecef = itrs_from_gcrs(EPOCH_UTC, [NADIR_CENTRE_S])[0] @ pos[0]
        _, lon, _ = geodetic_from_ecef(ecef)
        raan += np.radians(SCENE_LON_DEG) - float(lon)
    return raan, u0


def detector_error(camera: LineCamera, chip_px=(), bow_px=(0.0, 0.0)) -> LineCamera:
    """``camera`` with its detector line displaced: ``chip_px`` adds (along, across) pixels to each chip's
    offset, ``bow_px`` bends the line by (along, across) pixels at its centre, 0 at its ends
    (a parabola in the column)."""
    if not len(chip_px) and not np.any(bow_px):
        return camera
    offsets = np.array(camera.chip_offsets_px or [(0.0, 0.0)] * (len(camera.chip_starts) + 1), float)
    if len(chip_px):
        offsets = offsets + np.asarray(chip_px, float)
    p = camera.pixel_size_mm
    bow_x, bow_y = np.asarray(bow_px, float) * p
    mid = (0.5 * camera.columns - camera.center_col) / camera.columns   # the line's middle in s = (col - center_col) / columns
    parabola = np.array([1.0 - 4 * mid * mid, 8 * mid, -4.0])          # 1 - ((s - mid) / 0.5)^2 in powers of s
    line = (tuple(bow_x * parabola), tuple(np.array([0.0, camera.columns * p, 0.0]) + bow_y * parabola))
    return replace(camera, chip_offsets_px=tuple(map(tuple, offsets)), focal_plane_mm=line)


def simulate_prism(seed: int = 0, image_sigma_px: float = 0.3, n_points: int = 28,
                   ephemeris_sigma_m: float = 0.3, attitude_sigma_rad: float = 1.0e-6,
                   attitude_bias_rad=ATTITUDE_BIAS_RAD, attitude_drift_rad_s=ATTITUDE_DRIFT_RAD_S,
                   detector_error_px: dict | None = None, jitter: Jitter | None = None) -> PrismSimulation:
    """Simulate the PRISM triplet (see the module docstring); the attitude error (roll, pitch, yaw) can
    be chosen. ``detector_error_px``: camera -> :func:`detector_error` arguments, an error of its
    detector line that the block does not know (the block keeps the known chip offsets). ``jitter``: the
    platform's attitude jitter (:class:`Jitter`, :data:`JITTER`), unknown to the telemetry; its phases are drawn
    from a generator of their own, so that the rest of the simulation is the same with and without it."""
    attitude_bias_rad = np.asarray(attitude_bias_rad, float)
    attitude_drift_rad_s = np.asarray(attitude_drift_rad_s, float)
    rng = np.random.default_rng(seed)
    raan, u0 = _place_orbit()
    dem = AnalyticDem()
    nominal = {k: LineCamera(k, COLUMNS, COLUMNS / 2, PIXEL_SIZE_MM, NOMINAL_FOCAL_MM, LINE_PERIOD_S, pitch,
                             CHIP_STARTS, CHIP_OFFSETS_PX[k]) for k, pitch in CAMERAS.items()}
    duration = ROWS * LINE_PERIOD_S
    span = (NADIR_CENTRE_S - 80.0, NADIR_CENTRE_S + 80.0)
    true_traj = _true_trajectory(raan, u0, *span)
    phases = jitter.phases(np.random.default_rng(seed + 4200)) if jitter is not None else ()

    def true_image(k: str, t_first: float) -> LineImage:
        camera = detector_error(nominal[k], **(detector_error_px or {}).get(k, {}))
        image = LineImage.nominal(k, camera, true_traj, t_first, ROWS)
        params = image.parameters.copy()
        params[6] = TRUE_FOCAL_MM[k]
        params[7:10] = TRUE_BORESIGHT_RAD[k]
        return image.with_parameters(params)

    # the scene centre seen by the nadir camera, then each camera's first line and active detectors so
    # that it is centred in every image (PRISM reads out the part of its CCD row that sees the scene:
    # the Earth turns by about 17 km across track between the forward and the backward view)
    nadir = true_image("N", NADIR_CENTRE_S - duration / 2)
    centre = image_to_ground(nadir, ROWS / 2, COLUMNS / 2, dem)[0]
    images, t_first = [], {}
    for k in CAMERAS:
        t0 = NADIR_CENTRE_S - duration / 2 - 45.0 * np.sign(CAMERAS[k])
        for _ in range(4):
            row, col = ground_to_image(true_image(k, t0), centre[None])
            t0 += (row[0] - ROWS / 2) * LINE_PERIOD_S
        nominal[k] = replace(nominal[k], center_col=float(COLUMNS - np.round(col[0])))
        t_first[k] = float(t0)
        images.append(true_image(k, t0))

    # ground points: a jittered grid over the nadir scene (inset by 4 %; 7 x 4 for the 28 points of
    # seed 001, about square cells for more), heights from the terrain
    gx = max(7, int(round(np.sqrt(n_points))))
    gy = max(1, n_points // gx)
    cols = (np.arange(gx) + 0.5) / gx
    rows = (np.arange(gy) + 0.5) / gy
    cc, rr = np.meshgrid(cols, rows)
    jitter_x, jitter_y = min(0.03, 0.46 / gx), min(0.03, 0.46 / gy)      # at most half a cell
    cc = (0.04 + 0.92 * cc.ravel() + rng.uniform(-jitter_x, jitter_x, cc.size)) * COLUMNS
    rr = (0.04 + 0.92 * rr.ravel() + rng.uniform(-jitter_y, jitter_y, rr.size)) * ROWS
    points = image_to_ground(images[1], rr[:n_points], cc[:n_points], dem)

    if jitter is not None:      # the scene and the points are placed as without jitter; the images see it
        shaken = replace(true_traj, attitude=_Jittered(true_traj.attitude, jitter, phases))
        images = [replace(image, trajectory=shaken) for image in images]
    obs_image, obs_point, obs_row, obs_col = [], [], [], []
    for i, image in enumerate(images):
        row, col = ground_to_image(image, points)
        ok = np.isfinite(row) & (row >= 0) & (row < ROWS) & (col >= 0) & (col < COLUMNS)
        idx = np.flatnonzero(ok)
        obs_image += [i] * idx.size
        obs_point += idx.tolist()
        obs_row += (row[idx] + rng.normal(0, image_sigma_px, idx.size)).tolist()
        obs_col += (col[idx] + rng.normal(0, image_sigma_px, idx.size)).tolist()

    # telemetry: ephemeris at 1 Hz, quaternions at 10 Hz, with the attitude error and noise
    t_e = np.arange(np.ceil(span[0]) + 5, span[1] - 5, 1.0)
    pos, vel = _orbit(t_e, raan, u0)
    pos = pos + rng.normal(0, ephemeris_sigma_m, pos.shape)
    vel = vel + rng.normal(0, ephemeris_sigma_m / 100.0, vel.shape)
    t_a = np.arange(span[0] + 5, span[1] - 5, 0.1)
    given = _true_attitude(t_a) - (attitude_bias_rad + np.outer(t_a - NADIR_CENTRE_S, attitude_drift_rad_s))
    given = given + rng.normal(0, attitude_sigma_rad, given.shape)
    p_true, v_true = _orbit(t_a, raan, u0)
    R_OB = rotation_y(given[:, 1]) @ rotation_x(given[:, 0]) @ rotation_z(given[:, 2])
    quaternion = quaternion_from_matrix(orbit_frame(p_true, v_true) @ R_OB, scalar_first=False)

    truth = PrismTruth(images, dict(TRUE_FOCAL_MM), dict(TRUE_BORESIGHT_RAD), attitude_bias_rad.copy(),
                       attitude_drift_rad_s.copy(), points, dict(detector_error_px or {}), jitter, phases)
    return PrismSimulation(EPOCH_UTC, nominal, list(CAMERAS), t_first, ROWS,
                           {"t": t_e, "position": pos, "velocity": vel}, {"t": t_a, "quaternion": quaternion},
                           [f"p{k + 1:02d}" for k in range(len(points))], points, np.array(obs_image),
                           np.array(obs_point), np.array(obs_row), np.array(obs_col), image_sigma_px, dem, truth)


#: a-priori sigma (and simulated error) of the surveyed GCP coordinates, per axis
GCP_SIGMA_M = 0.1
#: the GCPs of the simulated block, as (row, col) fractions of the nadir image: four corners and the centre
GCP_LAYOUT = ((0.1, 0.1), (0.1, 0.9), (0.9, 0.1), (0.9, 0.9), (0.5, 0.5))


def prism_block(sim: PrismSimulation, seed: int = 0, dem_file: str | None = "dem.tif"):
    """The simulation as a block (DESIGN.md §3): three pushbroom cameras F, N, B with one image
    each, the telemetry as ephemeris.csv / attitude.csv (ECI), points in ECEF (EPSG:4978).

    Five points spread over the scene are GCPs (their surveyed coordinates carry
    :data:`GCP_SIGMA_M` of error); the others are check points at their true coordinates.
    """
    from ..block import AttitudeSamples, Block, Ephemeris, Images, Observations, Points, PushbroomCamera

    rng = np.random.default_rng(seed + 1000)
    cameras = {k: PushbroomCamera(k, c.columns, sim.rows, c.center_col, c.pixel_size_mm, c.focal_mm,
                                  c.line_period_s, sim.epoch_utc, "ECI", c.view_pitch_deg, 0.0, c.chip_starts,
                                  c.chip_offsets_px)
               for k, c in sim.cameras.items()}
    n_img = len(sim.image_ids)
    nan3 = np.full((n_img, 3), np.nan)
    images = Images(np.array(sim.image_ids, object), np.array(sim.image_ids, object), np.full(n_img, "", object),
                    np.array([sim.t_first_s[k] for k in sim.image_ids]), nan3, nan3.copy(), np.arange(2, n_img + 2))
    nadir = sim.obs_image == 1
    rows, cols, pts = sim.obs_row[nadir] / sim.rows, sim.obs_col[nadir] / COLUMNS, sim.obs_point[nadir]
    gcps: list[int] = []
    for r, c in GCP_LAYOUT:
        for k in np.argsort((rows - r) ** 2 + (cols - c) ** 2):
            if pts[k] not in gcps:
                gcps.append(int(pts[k]))
                break
    n_pt = len(sim.point_ids)
    role = np.full(n_pt, "chk", dtype=object)
    role[gcps] = "gcp"
    xyz = sim.points_ecef.copy()
    xyz[gcps] += rng.normal(0.0, GCP_SIGMA_M, (len(gcps), 3))
    sigma = np.full((n_pt, 3), np.nan)
    sigma[gcps] = GCP_SIGMA_M
    points = Points(np.array(sim.point_ids, object), role, xyz, sigma, np.arange(2, n_pt + 2))
    pixel = np.column_stack([sim.obs_col, sim.obs_row])
    m = len(sim.obs_row)
    observations = Observations(sim.obs_image.copy(), sim.obs_point.copy(), pixel, np.full(m, sim.image_sigma_px),
                                np.arange(2, m + 2))
    e, a = sim.ephemeris, sim.attitude
    ids_e = np.repeat(np.array(sim.image_ids, object), len(e["t"]))
    ids_a = np.repeat(np.array(sim.image_ids, object), len(a["t"]))
    ephemeris = Ephemeris(ids_e, np.tile(e["t"], n_img), np.tile(e["position"], (n_img, 1)),
                          np.tile(e["velocity"], (n_img, 1)))
    attitude = AttitudeSamples(ids_a, np.tile(a["t"], n_img), np.tile(a["quaternion"], (n_img, 1)))
    return Block(name="prism-triplet", crs="EPSG:4978", cameras=cameras, images=images, points=points,
                 observations=observations, image_sigma_px=sim.image_sigma_px, ephemeris=ephemeris,
                 attitude=attitude, dem_path=dem_file)


def dem_grid(sim: PrismSimulation, spacing_deg: float = 0.0005, margin_deg: float = 0.05):
    """The simulated terrain sampled on a geographic grid (about 50 m) covering the points."""
    from ..geometry.terrain import GridDem

    lat, lon, _ = geodetic_from_ecef(sim.points_ecef)
    lat0, lat1 = np.degrees(lat.min()) - margin_deg, np.degrees(lat.max()) + margin_deg
    lon0, lon1 = np.degrees(lon.min()) - margin_deg, np.degrees(lon.max()) + margin_deg
    cols = int(np.ceil((lon1 - lon0) / spacing_deg))
    rows = int(np.ceil((lat1 - lat0) / spacing_deg))
    lons = lon0 + (np.arange(cols) + 0.5) * spacing_deg
    lats = lat1 - (np.arange(rows) + 0.5) * spacing_deg
    heights = sim.dem(lats[:, None], lons[None, :])
    return GridDem(heights, (spacing_deg, 0.0, lon0, 0.0, -spacing_deg, lat1))


def prism_truth_files(sim: PrismSimulation) -> dict:
    """truth/: what the adjustment should find (JSON: focal lengths, attitude error, boresight; CSV: points)."""
    truth = sim.truth
    cameras = {k: {"focal_mm": truth.focal_mm[k], "boresight_roll_pitch_yaw_rad": list(truth.boresight_rad[k]),
                   "center_col": sim.cameras[k].center_col, "nominal_focal_mm": NOMINAL_FOCAL_MM}
               for k in sim.image_ids}
    jitter = {} if truth.jitter is None else {"jitter": {
        "axes": ["roll", "pitch", "yaw"], "frequency_hz": [list(f) for f in truth.jitter.frequency_hz],
        "amplitude_rad": [list(a) for a in truth.jitter.amplitude_rad],
        "phase_rad": [[float(v) for v in p] for p in truth.jitter_phases],
        "note": "true attitude = telemetry + bias + drift + sum amplitude sin(2 pi frequency t + phase), t in s"}}
    for k, error in truth.detector_error_px.items():
        cameras[k]["detector_error_px"] = {"chip_px": [list(map(float, c)) for c in error.get("chip_px", ())],
                                           "bow_px": list(map(float, error.get("bow_px", (0.0, 0.0))))}
    return {
        "camera_truth.json": {"cameras": cameras,
                              "attitude_bias_rad": truth.attitude_bias_rad.tolist(),
                              "attitude_drift_rad_s": truth.attitude_drift_rad_s.tolist(),
                              "attitude_error_reference_time_s": NADIR_CENTRE_S,
                              "note": "true attitude = telemetry + bias + drift (t - reference time)"} | jitter,
        "points_truth.csv": (["point_id", "X", "Y", "Z"],
                             [np.array(sim.point_ids, object), *truth.points_ecef.T], ["", ".4f", ".4f", ".4f"]),
    }
