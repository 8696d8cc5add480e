"""Trajectory (GNSS/IMU) errors drawn independently of the adjustment's shift/drift model.

The default UAV simulation (:func:`selfcal.simulate.uav.simulate_uav`) builds its
GNSS/IMU errors exactly as Eq. (12) of seed 000 is parametrised in the
adjustment: a shift and a drift per strip counted from the strip's first
exposure, added to the angles, noise as declared. A model tested only on data
built its own way cannot show a parametrisation error. :class:`TrajectoryErrors`
draws the errors another way:

* per strip and axis, independently: shift magnitudes uniform in a range with a
  random sign, drift magnitudes uniform in a range with a random sign, and a
  share of the (sensor, strip) pairs without any drift (their drift terms are
  truly zero);
* the drift counted from the strip's first exposure or from its middle;
* the IMU error added to omega-phi-kappa, or applied as a small rotation of the
  body frame (observed attitude R(e) B^T M, e = shift + drift dt, a rotation
  vector);
* true noise of its own (the blocks declare their a-priori sigmas separately).

:func:`noise_free_terms` expresses such a truth in any polynomial model of the
adjustment: the per-image systematic error (observed minus noise minus what the
model's P0 gives at the true orientation) fitted per strip by the model's powers
of its dt, so that estimated terms can be compared with their truth term by
term whatever time origin or composition either side uses. :func:`true_terms`
does the whole comparison for an adjustment's trajectory terms, with the
camera-fixed rotation that the adjustment's attitudes take from the lens field
(:func:`camera_rotation_of_field`): AP bases orthogonalised against the rotation
fields (the wavelet APs) leave the part of a distortion field that a common tilt
of the camera produces to the attitudes, and the IMU shift of every strip
absorbs it (on the simulated block with local+brown at scale 1: 0.004, -0.011,
-0.008 deg in omega, phi, kappa, as much as the sigma of an IMU shift).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.rotation import matrix_from_opk, matrix_from_rotation_vector, opk_from_matrix
from ..sensors.frame import project

__all__ = ["TrajectoryErrors", "TrajectoryTruth", "draw_trajectory_errors", "noise_free_terms", "true_terms_by_name",
           "camera_rotation_of_field", "true_terms"]

ORIGINS = ("first", "middle")
COMPOSITIONS = ("opk", "rotation")


@dataclass(frozen=True)
class TrajectoryErrors:
    """How the GNSS/IMU errors are drawn (ranges are of the magnitude; the sign is random).

    Defaults are the magnitudes of issue 25: GNSS shifts 0.1-0.45 m, drifts up to 0.02 m/s;
    IMU shifts up to 0.13 deg, drifts up to 0.005 deg/s; noise 3/3/5 cm and 0.005/0.005/0.01 deg.
    """

    gnss_shift_m: tuple[float, float] = (0.10, 0.45)
    gnss_drift_m_s: tuple[float, float] = (0.0, 0.02)
    imu_shift_deg: tuple[float, float] = (0.0, 0.13)
    imu_drift_deg_s: tuple[float, float] = (0.0, 0.005)
    gnss_noise_m: tuple[float, float, float] = (0.03, 0.03, 0.05)
    imu_noise_deg: tuple[float, float, float] = (0.005, 0.005, 0.01)
    drift_origin: str = "first"          # "first" exposure of the strip or its "middle" (in time)
    imu_composition: str = "opk"         # "opk": added to the angles; "rotation": R(e) applied to the body frame
    drift_share: float = 0.5             # probability that a (sensor, strip) pair drifts at all

    def __post_init__(self):
        if self.drift_origin not in ORIGINS:
            raise ValueError(f"drift_origin must be one of {ORIGINS}, found {self.drift_origin!r}")
        if self.imu_composition not in COMPOSITIONS:
            raise ValueError(f"imu_composition must be one of {COMPOSITIONS}, found {self.imu_composition!r}")
        if not 0.0 <= self.drift_share <= 1.0:
            raise ValueError(f"drift_share must be in [0, 1], found {self.drift_share}")


@dataclass
class TrajectoryTruth:
    """The trajectory errors a simulation applied (per strip and per image)."""

    origin_s: np.ndarray            # (n_strips,) time from which the drift is counted
    gnss_shift_m: np.ndarray        # (n_strips, 3)
    gnss_drift_m_s: np.ndarray      # (n_strips, 3)
    imu_shift_rad: np.ndarray       # (n_strips, 3) omega-phi-kappa, or a rotation vector ("rotation")
    imu_drift_rad_s: np.ndarray     # (n_strips, 3)
    imu_composition: str
    gnss_noise_free_m: np.ndarray   # (n_images, 3) GNSS observation without its noise
    imu_noise_free_rad: np.ndarray  # (n_images, 3) IMU observation without its noise


def _magnitude(rng: np.random.Generator, bounds, shape) -> np.ndarray:
    lo, hi = bounds
    return rng.uniform(lo, hi, shape) * rng.choice([-1.0, 1.0], shape)


def draw_trajectory_errors(errors: TrajectoryErrors, rng: np.random.Generator, times: np.ndarray,
                           strip_of: np.ndarray, antenna_m: np.ndarray, body_rad: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray, TrajectoryTruth]:
    """GNSS and IMU observations of every image: the true antenna positions ``antenna_m`` and body
    attitudes ``body_rad`` (omega-phi-kappa of B^T M) with the drawn errors and noise.

    Returns the GNSS observations (n, 3), the IMU observations (n, 3, radians, wrapped) and the truth.
    """
    n_strips = int(strip_of.max()) + 1
    shape = (n_strips, 3)
    gnss_shift = _magnitude(rng, errors.gnss_shift_m, shape)
    gnss_drift = _magnitude(rng, errors.gnss_drift_m_s, shape)
    imu_shift = np.radians(_magnitude(rng, errors.imu_shift_deg, shape))
    imu_drift = np.radians(_magnitude(rng, errors.imu_drift_deg_s, shape))
    gnss_drift *= (rng.uniform(size=n_strips) < errors.drift_share)[:, None]
    imu_drift *= (rng.uniform(size=n_strips) < errors.drift_share)[:, None]
    first = np.array([times[strip_of == s].min() for s in range(n_strips)])
    last = np.array([times[strip_of == s].max() for s in range(n_strips)])
    origin = first if errors.drift_origin == "first" else 0.5 * (first + last)
    dt = times - origin[strip_of]

    gnss_clean = antenna_m + gnss_shift[strip_of] + gnss_drift[strip_of] * dt[:, None]
    e = imu_shift[strip_of] + imu_drift[strip_of] * dt[:, None]
    if errors.imu_composition == "opk":
        imu_clean = body_rad + e
    else:
        imu_clean = opk_from_matrix(matrix_from_rotation_vector(e) @ matrix_from_opk(body_rad))
    imu_clean = (imu_clean + np.pi) % (2 * np.pi) - np.pi
    n = len(times)
    gnss = gnss_clean + rng.normal(0.0, 1.0, (n, 3)) * np.asarray(errors.gnss_noise_m, float)
    imu = imu_clean + rng.normal(0.0, 1.0, (n, 3)) * np.radians(np.asarray(errors.imu_noise_deg, float))
    imu = (imu + np.pi) % (2 * np.pi) - np.pi
    truth = TrajectoryTruth(origin, gnss_shift, gnss_drift, imu_shift, imu_drift, errors.imu_composition,
                            gnss_clean, imu_clean)
    return gnss, imu, truth


def noise_free_terms(systematic: np.ndarray, strip_of: np.ndarray, dt: np.ndarray, order: int) -> np.ndarray:
    """The strip-wise polynomial terms that best describe a per-image systematic error.

    ``systematic`` (n, 3) is the error of each observation without its noise
    against the model's P0 at the true orientation (angles wrapped), ``strip_of``
    and ``dt`` the strip and time of each observation as the adjustment counts
    them, ``order`` the model's (0 shift, 1 drift, 2 quadratic). Returns
    (n_strips, order + 1, 3): the least-squares fit per strip and axis. Where the
    simulated error is of the model's form this is its exact value; otherwise the
    best the model can do.
    """
    n_strips = int(strip_of.max()) + 1
    out = np.zeros((n_strips, order + 1, 3))
    for s in range(n_strips):
        mine = strip_of == s
        A = dt[mine, None] ** np.arange(order + 1)[None, :]
        out[s] = np.linalg.lstsq(A, systematic[mine], rcond=None)[0]
    return out


def camera_rotation_of_field(distortion, camera, ap_basis=None, height_m: float = 215.0, nodes: int = 41) -> np.ndarray:
    """The camera-fixed rotation (rotation vector, radians, applied as R(e) M) that an adjustment's
    attitudes take from a true distortion field.

    The field (``distortion.displacement_px``, observed = ideal + Delta) is fitted over the frame of
    ``camera`` (a FrameCamera: focal_mm, pixel_size_mm, width_mm, height_mm) by the image fields of the
    three rotations of a vertical camera, of x0, y0 and c and, where given, by the AP basis the
    adjustment estimates (``ap_basis(x_mm, y_mm) -> (Bx, By)``, dimensionless, coefficients in pixels):
    the rotation part of the least-squares fit is what the attitudes carry.
    """
    c, p = camera.focal_mm, camera.pixel_size_mm
    rows = int(round((nodes - 1) * camera.height_mm / camera.width_mm)) + 1
    x, y = (a.ravel() for a in np.meshgrid(np.linspace(-camera.width_mm / 2, camera.width_mm / 2, nodes),
                                          np.linspace(-camera.height_mm / 2, camera.height_mm / 2, rows)))
    dx, dy = distortion.displacement_px(x, y)
    points = np.column_stack([height_m * x / c, height_m * y / c, np.zeros_like(x)])
    eop = np.broadcast_to(np.array([0.0, 0.0, height_m, 0.0, 0.0, 0.0]), (len(x), 6))
    iop = np.array([c, 0.0, 0.0])
    ideal = project(points, eop, iop)
    columns = []
    step = 1e-6
    for k in range(3):
        rotation = np.broadcast_to(matrix_from_rotation_vector(step * np.eye(3)[k]), (len(x), 3, 3))
        columns.append(((project(points, eop, iop, rotation) - ideal) / step).T.ravel())
    one, zero = np.ones_like(x), np.zeros_like(x)
    columns += [np.concatenate([one, zero]), np.concatenate([zero, one]), np.concatenate([x, y])]
    A = np.column_stack(columns)
    if ap_basis is not None:
        bx, by = ap_basis(x, y)
        A = np.column_stack([A, p * np.vstack([bx, by])])
    solution = np.linalg.lstsq(A, p * np.concatenate([dx, dy]), rcond=None)[0]
    return solution[:3]


def true_terms(truth, terms, image_rows: np.ndarray, mounting=None, rotation=None) -> np.ndarray:
    """The true shift/drift terms of one sensor in an adjustment's own parametrisation.

    ``truth`` is a UAVTruth with ``trajectory``; ``terms`` the adjustment's TrajectoryTerms of the sensor
    (``offset`` 0 GNSS / 3 IMU, ``strip_of``, ``dt``, ``order``); ``image_rows`` the truth row of each of its
    observations; ``mounting`` the lever arm (m) or boresight angles (rad) the model uses (block.toml's);
    ``rotation`` the camera-fixed rotation the attitudes take from the lens field
    (:func:`camera_rotation_of_field`). P0 is evaluated at the true orientation so turned; what the
    observations carry besides noise is fitted per strip by the model's powers of dt.
    Returns (n_strips, order + 1, 3).
    """
    M = matrix_from_opk(truth.eop[image_rows, 3:])
    if rotation is not None:
        M = matrix_from_rotation_vector(np.asarray(rotation, float)) @ M
    mounting = np.zeros(3) if mounting is None else np.asarray(mounting, float)
    if terms.offset == 0:
        p0 = truth.eop[image_rows, :3] + np.einsum("nji,j->ni", M, mounting)
        systematic = truth.trajectory.gnss_noise_free_m[image_rows] - p0
    else:
        p0 = opk_from_matrix(np.einsum("ji,njk->nik", matrix_from_opk(mounting), M))
        systematic = (truth.trajectory.imu_noise_free_rad[image_rows] - p0 + np.pi) % (2 * np.pi) - np.pi
    return noise_free_terms(systematic, terms.strip_of, terms.dt, terms.order)


def true_terms_by_name(truth, result) -> dict[str, tuple[float, bool]]:
    """name -> (true value in the adjustment's own parametrisation, truly zero) of every shift/drift term of
    ``result`` (an adjustment of a block simulated with ``truth``).

    The true value is :func:`true_terms` with the camera-fixed rotation that the attitudes take from the lens
    field under the adjustment's AP basis (:func:`camera_rotation_of_field`); a drift term is truly zero when its
    sensor does not drift in that strip."""
    camera = result.problem.cameras[0]
    rotation = camera_rotation_of_field(truth.distortion, truth.camera, camera.ap.basis if camera.ap.n_params else None)
    lookup = {i: k for k, i in enumerate(truth.image_id)}
    strip_index = {s: k for k, s in enumerate(truth.strip_id)}
    out = {}
    for t in result.problem.trajectory:
        if t.order < 0:
            continue
        rows = np.array([lookup[i] for i in result.block.images.image_id[t.index]])
        terms = true_terms(truth, t, rows, t.mounting, rotation)
        drift = truth.trajectory.gnss_drift_m_s if t.offset == 0 else truth.trajectory.imu_drift_rad_s
        for i, name in enumerate(t.names[:t.n_strip_params]):
            s, rest = divmod(i, 3 * (t.order + 1))
            k, a = divmod(rest, 3)
            out[name] = (float(terms[s, k, a]), bool(k >= 1 and np.all(drift[strip_index[t.strips[s]]] == 0)))
    return out
