"""What an adjustment is asked to estimate, and how: :class:`AdjustOptions`."""
from __future__ import annotations

from dataclasses import dataclass, field

from .solver import SolverOptions

__all__ = ["AdjustOptions"]


@dataclass(frozen=True)
class AdjustOptions:
    """What to estimate and how.

    Attributes
    ----------
    ap : str
        Additional-parameter model, e.g. ``"none"``, ``"brown"``, ``"wavelet:db4"``.
    grid : (int, int)
        Gx x Gy grid of the wavelet APs (Eq. 10 of seed 000).
    gnss_drift, imu_drift : int
        Order of the strip-wise shift/drift of GNSS positions and IMU attitudes
        (Eq. 12 of seed 000): -1 none, 0 shift, 1 shift + linear drift (default), 2 quadratic.
    lever_arm, boresight : bool
        Estimate the GNSS lever arm and the IMU boresight angles (need the order -1).
    sensor_model : str, optional
        Which parameters of a sensor are estimated, where the sensor offers a choice: seed 001's
        ``M1`` ... ``M7`` or a comma-separated list of parameter names for pushbroom images.
    parameter_sigma : dict, optional
        A-priori sigmas (code units) by parameter name, overriding the sensor model's weights.
    ap_cameras : tuple of str, optional
        The cameras that get additional parameters (default: all).
    ap_sigma_px : float, optional
        A-priori sigma of every AP coefficient (a prior observation of its start value); default free.
    attitude_telemetry : bool
        Pushbroom images: fit the attitude of attitude.csv (False: roll = pitch = yaw = 0 before the
        corrections, seed 001 Table 5).
    solver : SolverOptions
    """

    ap: str = "none"
    grid: tuple[int, int] = (9, 6)
    gnss_drift: int = 1
    imu_drift: int = 1
    lever_arm: bool = False
    boresight: bool = False
    sensor_model: str | None = None
    parameter_sigma: dict | None = None
    ap_cameras: tuple[str, ...] | None = None
    ap_sigma_px: float | None = None
    attitude_telemetry: bool = True
    solver: SolverOptions = field(default_factory=SolverOptions)

