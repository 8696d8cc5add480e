"""A simulated ALOS/PRISM triplet with known truth (seed 001).

An ALOS-like sun-synchronous orbit (circular, 691.65 km, 98.16 deg, descending over the
scene), the three PRISM cameras (forward +23.8 deg, nadir, backward -23.8 deg view
pitch; 7 um detectors merged into one 14,496-column virtual array; 2.5 m ground sample
distance), a terrain model, and 28 ground points measured in all three images.

What the telemetry gets wrong is the truth the adjustment must find:

* each camera's focal length differs from the nominal 1939 mm (Table 2 of seed 001:
  1937.45 nadir, 1938.20 forward, 1936.66 backward);
* the attitude telemetry has a bias and a drift (rad, rad/s) against the true attitude,
  and each telescope is misaligned by small boresight angles;
* quaternions (10 Hz) and ephemeris (1 Hz) carry white noise.

Times count from the simulation's epoch; the nadir scene is centred at
:data:`NADIR_CENTRE_S`. All geometry is in ECEF (ITRS) metres with telemetry in the ECI
(GCRS) frame, as DESIGN.md §3 fixes them.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..geometry.earth import ecef_from_geodetic, geodetic_from_ecef, itrs_from_gcrs, local_up, orbit_frame
from ..geometry.rotation import quaternion_from_matrix
from ..sensors.pushbroom import (LineCamera, LineImage, fit_polynomial, fit_trajectory, ground_to_image, image_to_ground,
                                 rotation_x, rotation_y, rotation_z, Trajectory)

__all__ = ["PrismSimulation", "PrismTruth", "AnalyticDem", "simulate_prism", "CAMERAS", "TRUE_FOCAL_MM",
           "NOMINAL_FOCAL_MM", "NADIR_CENTRE_S"]

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
ROWS = 14_000
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


@dataclass
class PrismTruth:
    images: list[LineImage]          # true trajectories and parameters (focal, boresight; zero attitude corrections)
    focal_mm: dict[str, float]
    boresight_rad: dict[str, tuple]
    attitude_bias_rad: np.ndarray
    attitude_drift_rad_s: np.ndarray
    points_ecef: np.ndarray          # (n, 3)


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
    fit_orders: tuple[int, int, int] = (7, 7, 3)
    notes: list[str] = field(default_factory=list)

    def images(self, given_attitude: bool = True, margin_s: float = 10.0) -> list[LineImage]:
        """The images as the adjustment starts: telemetry fitted by polynomials over each scene
        (+/- ``margin_s``), nominal focal length, no boresight or attitude corrections."""
        out = []
        for image_id in self.image_ids:
            t0 = self.t_first_s[image_id]
            t1 = t0 + self.rows * LINE_PERIOD_S
            e, a = self.ephemeris, self.attitude
            pick_e = (e["t"] >= t0 - margin_s) & (e["t"] <= t1 + margin_s)
            pick_a = (a["t"] >= t0 - margin_s) & (a["t"] <= t1 + margin_s)
            camera = self.cameras[image_id]
            t_ref = t0 + 0.5 * self.rows * camera.line_period_s
            trajectory = fit_trajectory("ECI", self.epoch_utc, e["t"][pick_e], e["position"][pick_e],
                                        e["velocity"][pick_e], a["t"][pick_a], a["quaternion"][pick_a],
                                        self.fit_orders, t_ref=t_ref, given_attitude=given_attitude)
            out.append(LineImage.nominal(image_id, camera, trajectory, t0, self.rows))
        return out


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


def simulate_prism(seed: int = 0, image_sigma_px: float = 0.3, n_points: int = 28,
                   ephemeris_sigma_m: float = 0.3, attitude_sigma_rad: float = 1.0e-6) -> PrismSimulation:
    """Simulate the PRISM triplet (see the module docstring)."""
    rng = np.random.default_rng(seed)
    raan, u0 = _place_orbit()
    dem = AnalyticDem()
    nominal = {k: LineCamera(k, COLUMNS, COLUMNS / 2, PIXEL_SIZE_MM, NOMINAL_FOCAL_MM, LINE_PERIOD_S, pitch)
               for k, pitch in CAMERAS.items()}
    duration = ROWS * LINE_PERIOD_S
    span = (NADIR_CENTRE_S - 80.0, NADIR_CENTRE_S + 80.0)
    true_traj = _true_trajectory(raan, u0, *span)

    def true_image(k: str, t_first: float) -> LineImage:
        image = LineImage.nominal(k, nominal[k], true_traj, t_first, ROWS)
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

    # ground points: a jittered 7 x 4 grid over the nadir scene (inset by 4 %), heights from the terrain
    gx, gy = 7, max(1, n_points // 7)
    cols = (np.arange(gx) + 0.5) / gx
    rows = (np.arange(gy) + 0.5) / gy
    cc, rr = np.meshgrid(cols, rows)
    cc = (0.04 + 0.92 * cc.ravel() + rng.uniform(-0.03, 0.03, cc.size)) * COLUMNS
    rr = (0.04 + 0.92 * rr.ravel() + rng.uniform(-0.03, 0.03, rr.size)) * ROWS
    points = image_to_ground(images[1], rr[:n_points], cc[:n_points], dem)

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
    given = _true_attitude(t_a) - (ATTITUDE_BIAS_RAD + np.outer(t_a - NADIR_CENTRE_S, ATTITUDE_DRIFT_RAD_S))
    given = given + rng.normal(0, attitude_sigma_rad, given.shape)
    p_true, v_true = _orbit(t_a, raan, u0)
    R_OB = rotation_y(given[:, 1]) @ rotation_x(given[:, 0]) @ rotation_z(given[:, 2])
    quaternion = quaternion_from_matrix(orbit_frame(p_true, v_true) @ R_OB, scalar_first=False)

    truth = PrismTruth(images, dict(TRUE_FOCAL_MM), dict(TRUE_BORESIGHT_RAD), ATTITUDE_BIAS_RAD.copy(),
                       ATTITUDE_DRIFT_RAD_S.copy(), points)
    return PrismSimulation(EPOCH_UTC, nominal, list(CAMERAS), t_first, ROWS,
                           {"t": t_e, "position": pos, "velocity": vel}, {"t": t_a, "quaternion": quaternion},
                           [f"p{k + 1:02d}" for k in range(n_points)], points, np.array(obs_image),
                           np.array(obs_point), np.array(obs_row), np.array(obs_col), image_sigma_px, dem, truth)
