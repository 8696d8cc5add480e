"""GNSS positions and IMU attitudes of the images as observations, with strip-wise shift and drift (Eq. 12 of
seed 000), and the sensors' mounting (lever arm, boresight angles).

Each sensor's observations are one :class:`TrajectoryTerms` block; its shift/drift terms and the mounting, where
estimated, are parameters of its own (the ``x`` part of theta).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...errors import UsageError
from ...geometry.rotation import matrix_from_opk_with_derivatives, opk_from_matrix_with_derivatives
from .base import ParameterResiduals, Triplets

__all__ = ["TrajectoryTerms", "trajectory_terms", "mounted_sensor", "wrap_angle", "from_block"]


@dataclass
class TrajectoryTerms(ParameterResiduals):
    """Trajectory observations of one sensor with strip-wise shift and drift, Eq. (12) of seed 000:

        P_observed = P0 + D0 + D1 dt + D2 dt^2

    with P0 the image's exterior orientation (position for GNSS, attitude for
    IMU) and dt the time since the strip's middle (half-way between its first and last
    exposure), so that D0 is the strip's mean offset and D0, D1 are nearly uncorrelated
    (counted from the first exposure they were correlated at -0.4 to -0.9 on the simulated
    block, and the screening tested each against a partner that moved with it). ``order``
    -1 means plain observations (no shift/drift); 0 a shift D0; 1 shift and drift; 2 adds D2.

    The mounting of the sensor enters P0: the GNSS antenna sits at the lever arm
    ``a`` (camera frame, metres), P0 = X0 + M^T a; the IMU body frame is turned by
    the boresight angles ``b`` from the camera, P0 = opk(B(b)^T M) (M the camera's
    object-to-image rotation). ``mounting`` holds a or b (radians) as given; with
    ``estimate_mounting`` they are three more unknowns, starting from it.

    Parameters are laid out per strip as [D0 (3), D1 (3), D2 (3)], then the mounting (3) if estimated.
    """

    sensor: str                 # "GNSS" or "IMU"
    index: np.ndarray           # images with an observation
    observed: np.ndarray        # (k, 3)
    sigma: np.ndarray           # (k, 3) a-priori sigma of each observation, metres or radians (the image's own
                                # from images.csv where given, else block.toml's)
    offset: int                 # 0: X0 Y0 Z0, 3: omega phi kappa
    order: int
    strip_of: np.ndarray        # (k,) strip number of each observation
    dt: np.ndarray              # (k,) seconds since the strip's middle (half-way between first and last exposure)
    strips: list[str]
    free: np.ndarray            # bool over the parameters (screening holds some at zero)
    names: list[str]
    mounting: np.ndarray = field(default_factory=lambda: np.zeros(3))
    estimate_mounting: bool = False

    @property
    def n_params(self) -> int:
        return len(self.free)

    @property
    def n_strip_params(self) -> int:
        return len(self.strips) * (self.order + 1) * 3 if self.order >= 0 else 0

    @property
    def wrap(self) -> bool:
        return self.offset == 3

    @property
    def mounted(self) -> bool:
        """Whether the mounting enters the model (estimated, or given and not zero)."""
        return self.estimate_mounting or bool(np.any(self.mounting != 0))

    def initial(self) -> np.ndarray:
        """Initial values of the parameters: zero shift/drift, the given mounting."""
        return np.concatenate([np.zeros(self.n_strip_params), self.mounting if self.estimate_mounting else []])

    def mounting_of(self, values: np.ndarray) -> np.ndarray:
        """The lever arm or boresight angles in effect, from this sensor's parameter values."""
        if self.estimate_mounting:
            return values[self.n_strip_params:self.n_strip_params + 3]
        return self.mounting

    def design(self) -> np.ndarray:
        """(k, order + 1) powers of dt."""
        return self.dt[:, None] ** np.arange(self.order + 1)[None, :] if self.order >= 0 else np.zeros((len(self.dt), 0))


    owns_parameters = True

    @property
    def group(self) -> str:                     # type: ignore[override]  # its sensor's name: "GNSS", "IMU"
        return self.sensor

    def n_rows(self, problem) -> int:
        return 3 * len(self.index)

    def triplets(self, problem, state, own_column: int, own_values: np.ndarray) -> Triplets:
        t, n = self, len(self.index)
        width = problem.image_width
        rows, cols, vals = [], [], []
        powers = t.design()                                            # (n, order + 1)
        model, d_eop, d_mount = mounted_sensor(t, state.image[t.index], t.mounting_of(own_values))
        if t.order >= 0:
            coeff = own_values[:t.n_strip_params].reshape(len(t.strips), t.order + 1, 3)
            model += np.einsum("nk,nka->na", powers, coeff[t.strip_of])
        diff = t.observed - model
        if t.wrap:
            diff = wrap_angle(diff)
        rows_here = np.arange(3 * n).reshape(n, 3)
        # d(model)/d(the image's six orientation unknowns), whitened: (n, 3 rows, 6 columns)
        nz = d_eop != 0
        rows.append(np.broadcast_to(rows_here[:, :, None], (n, 3, 6))[nz])
        cols.append(np.broadcast_to(width * t.index[:, None, None] + np.arange(6)[None, None, :], (n, 3, 6))[nz])
        vals.append((d_eop / t.sigma[:, :, None])[nz])
        if t.estimate_mounting:
            free_pos = np.cumsum(t.free) - 1
            ok = t.free[t.n_strip_params:t.n_strip_params + 3]
            mount_cols = own_column + free_pos[t.n_strip_params + np.arange(3)]
            rows.append(np.broadcast_to(rows_here[:, :, None], (n, 3, 3))[:, :, ok].ravel())
            cols.append(np.broadcast_to(mount_cols[None, None, :], (n, 3, 3))[:, :, ok].ravel())
            vals.append((d_mount / t.sigma[:, :, None])[:, :, ok].ravel())
        if t.order >= 0:
            # column of (strip s, power j, axis a) among this sensor's free parameters
            full_index = (t.strip_of[:, None, None] * (t.order + 1) + np.arange(t.order + 1)[None, :, None]) * 3 \
                + np.arange(3)[None, None, :]                           # (n, order + 1, 3)
            free_pos = np.cumsum(t.free) - 1
            ok = t.free[full_index]
            r_idx = np.broadcast_to(rows_here[:, None, :], full_index.shape)
            rows.append(r_idx[ok])
            cols.append(own_column + free_pos[full_index[ok]])
            vals.append((np.broadcast_to(powers[:, :, None], full_index.shape) / t.sigma[:, None, :])[ok])
        return (np.concatenate(rows), np.concatenate(cols), np.concatenate(vals), (diff / t.sigma).ravel())


def trajectory_terms(sensor: str, images, index: np.ndarray, observed: np.ndarray, sigma: np.ndarray,
                     offset: int, order: int, mounting=None, estimate_mounting: bool = False) -> TrajectoryTerms:
    """Set up one sensor's trajectory observations with strip-wise shift/drift of ``order``.

    ``sigma``: the a-priori sigma of each observation, (k, 3), or one (3,) for all of them.

    ``mounting``: the lever arm (GNSS, metres) or boresight angles (IMU, radians); with
    ``estimate_mounting`` they are unknowns. They cannot be told apart from strip-wise
    shifts (the attitude is nearly constant along a strip), so estimating them needs ``order`` -1
    (:class:`~selfcal.adjust.TrajectoryOptions` says so when it is made).
    """
    from ...errors import AdjustmentError
    assert not (estimate_mounting and order >= 0), "TrajectoryOptions lets a mounting be estimated only with order -1"
    strip_ids = images.strip_id[index]
    strips = list(dict.fromkeys(strip_ids.tolist()))
    strip_of = np.array([strips.index(s) for s in strip_ids], dtype=np.int64)
    times = images.time_s[index]
    if order >= 1 and np.isnan(times).any():
        bad = ", ".join(images.image_id[index[np.isnan(times)]][:5])
        raise AdjustmentError(f"{sensor} drift of order {order} needs time_s of every image; missing for {bad}")
    t0 = np.array([0.5 * (np.nanmin(times[strip_of == s]) + np.nanmax(times[strip_of == s])) if order >= 1 else 0.0
                   for s in range(len(strips))])
    dt = np.nan_to_num(times - t0[strip_of]) if order >= 1 else np.zeros(len(index))
    axes = ("X", "Y", "Z") if offset == 0 else ("omega", "phi", "kappa")
    names = [f"{sensor} {strip} D{k} {a}" for strip in strips for k in range(order + 1) for a in axes]
    if estimate_mounting:
        names += [f"GNSS lever arm {a}" for a in "xyz"] if offset == 0 else \
            [f"IMU boresight {a}" for a in ("omega", "phi", "kappa")]
    sigma = np.broadcast_to(np.asarray(sigma, float), (len(index), 3)).copy()
    return TrajectoryTerms(sensor, index, observed, sigma, offset, order, strip_of, dt, strips,
                           np.ones(len(names), bool), names,
                           np.zeros(3) if mounting is None else np.asarray(mounting, float), estimate_mounting)



def wrap_angle(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2 * np.pi) - np.pi


def mounted_sensor(t, eop: np.ndarray, mounting: np.ndarray):
    """What a trajectory sensor observes of each image before shift/drift, with derivatives.

    GNSS: X0 + M^T a (lever arm a in the camera frame). IMU: the angles of
    B(b)^T M (boresight angles b). Returns the model (n, 3), its derivatives with
    respect to the image's six orientation unknowns (n, 3, 6) and with respect to
    the mounting (n, 3, 3).
    """
    n = len(eop)
    d_eop = np.zeros((n, 3, 6))
    if not t.mounted:
        d_eop[:, np.arange(3), t.offset + np.arange(3)] = 1.0
        return eop[:, t.offset:t.offset + 3].copy(), d_eop, np.zeros((n, 3, 3))
    M, dM = matrix_from_opk_with_derivatives(eop[:, 3:])
    if t.offset == 0:
        d_eop[:, np.arange(3), np.arange(3)] = 1.0
        d_eop[:, :, 3:] = np.einsum("nkji,j->nik", dM, mounting)       # d(M^T a)/d angle k
        return eop[:, :3] + np.einsum("nji,j->ni", M, mounting), d_eop, np.swapaxes(M, 1, 2)
    B, dB = matrix_from_opk_with_derivatives(mounting)
    N = np.einsum("ji,njk->nik", B, M)                                  # B^T M
    angles, d_angles = opk_from_matrix_with_derivatives(N)
    d_eop[:, :, 3:] = np.einsum("naij,nkij->nak", d_angles, np.einsum("ji,nkjl->nkil", B, dM))
    d_mount = np.einsum("naij,nkij->nak", d_angles, np.einsum("kji,njl->nkil", dB, M))  # dB_k^T M
    return angles, d_eop, d_mount



def from_block(block, problem, settings) -> list[ParameterResiduals]:
    """The block's GNSS (``[gnss]``) and IMU (``[imu]``) observations, each a :class:`TrajectoryTerms` with the
    shift/drift order and mounting that ``settings.trajectory`` asks for."""
    images = block.images
    settings = settings.trajectory
    out: list[ParameterResiduals] = []
    if settings.lever_arm and block.gnss_sigma_m is None:
        raise UsageError("the GNSS lever arm needs GNSS observations ([gnss] in block.toml)")
    if settings.boresight and block.imu_sigma_deg is None:
        raise UsageError("the IMU boresight angles need IMU observations ([imu] in block.toml)")
    if block.gnss_sigma_m is not None:
        index = np.flatnonzero(np.isfinite(images.position_m).all(axis=1))
        sigma = images.trajectory_sigma("GNSS", block.gnss_sigma_m)[index]
        out.append(trajectory_terms("GNSS", images, index, images.position_m[index], sigma, 0, settings.gnss_drift,
                                    block.gnss_lever_arm_m, settings.lever_arm))
    if block.imu_sigma_deg is not None:
        index = np.flatnonzero(np.isfinite(images.attitude_rad).all(axis=1))
        sigma = images.trajectory_sigma("IMU", np.radians(np.array(block.imu_sigma_deg, float)))[index]
        out.append(trajectory_terms("IMU", images, index, images.attitude_rad[index], sigma, 3, settings.imu_drift,
                                    None if block.imu_boresight_deg is None else
                                    np.radians(np.array(block.imu_boresight_deg, float)), settings.boresight))
    return out
