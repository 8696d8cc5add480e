"""What an adjustment is asked to estimate, and how: :class:`AdjustOptions`, in four groups validated once, where
they are made — the additional parameters (:class:`APOptions`), the GNSS/IMU trajectory
(:class:`TrajectoryOptions`), what a sensor offers to estimate (:class:`SensorOptions`) and how to iterate
(:class:`SolverOptions`). The engine passes each part only to what reads it: the sensors
get :class:`SensorOptions`, the AP models :class:`APOptions`."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import UsageError

__all__ = ["APOptions", "AdjustOptions", "SensorOptions", "SolverOptions", "TrajectoryOptions"]

#: the orders of the strip-wise shift and drift of GNSS positions and IMU attitudes (Eq. 12 of seed 000)
DRIFT_ORDERS = (-1, 0, 1, 2)


#: where the AP correction of an image observation may be evaluated (APOptions.evaluated_at)
AP_POSITIONS = ("adjusted", "measured")


@dataclass(frozen=True)
class APOptions:
    """The additional parameters.

    Attributes
    ----------
    model : str
        The AP model, e.g. ``"none"``, ``"brown"``, ``"wavelet:db4"``.
    grid : (int, int)
        Gx x Gy grid of the wavelet APs (Eq. 10 of seed 000).
    cameras : tuple of str, optional
        The cameras that get additional parameters (default: all).
    sigma_px : float, optional
        A-priori sigma of every AP coefficient (a prior observation of its start value); default free.
    evaluated_at : str
        Where a frame camera's AP correction of an observation is evaluated: ``"adjusted"`` (default) at its
        adjusted image coordinates (the adjustment converges with the basis at the measured ones, moves it to
        the adjusted ones and converges again), ``"measured"`` at the measured ones throughout (Eq. (1) of seed
        000 read literally: an errors-in-variables estimate, biased where the APs trade with c, x0, y0; see
        DESIGN-NOTES "Honest precision").
    """

    model: str = "none"
    grid: tuple[int, int] = (9, 6)
    cameras: tuple[str, ...] | None = None
    sigma_px: float | None = None
    evaluated_at: str = "adjusted"

    def __post_init__(self) -> None:
        from ..ap import check_ap_spec
        try:
            check_ap_spec(self.model)
        except ValueError as error:
            raise UsageError(f"AP model: {error}") from None
        if len(self.grid) != 2 or any(int(g) != g or g < 1 for g in self.grid):
            raise UsageError(f"AP grid {tuple(self.grid)}: two positive whole numbers (Gx, Gy) expected")
        object.__setattr__(self, "grid", (int(self.grid[0]), int(self.grid[1])))
        if self.sigma_px is not None and not self.sigma_px > 0:
            raise UsageError(f"AP sigma {self.sigma_px} px: a positive number expected")
        if self.evaluated_at not in AP_POSITIONS:
            raise UsageError(f"AP evaluated_at '{self.evaluated_at}': one of {', '.join(AP_POSITIONS)} expected")


@dataclass(frozen=True)
class TrajectoryOptions:
    """The GNSS positions and IMU attitudes of the images (where the block has them).

    Attributes
    ----------
    gnss_drift, imu_drift : int
        Order of the strip-wise shift/drift of GNSS positions and IMU attitudes
        (Eq. 12 of seed 000): -1 none, 0 shift, 1 shift + linear drift (default), 2 quadratic.
    lever_arm, boresight : bool
        Estimate the GNSS lever arm and the IMU boresight angles (need the order -1).
    """

    gnss_drift: int = 1
    imu_drift: int = 1
    lever_arm: bool = False
    boresight: bool = False

    def __post_init__(self) -> None:
        for name in ("gnss_drift", "imu_drift"):
            if getattr(self, name) not in DRIFT_ORDERS:
                raise UsageError(f"{name.replace('_', ' ')} order {getattr(self, name)!r}: one of "
                                 f"{', '.join(map(str, DRIFT_ORDERS))} expected (-1 none, 0 shift, 1 shift and drift, "
                                 f"2 quadratic)")
        for name, what, order in (("lever_arm", "GNSS lever arm", "gnss_drift"),
                                  ("boresight", "IMU boresight angles", "imu_drift")):
            if getattr(self, name) and getattr(self, order) != -1:
                raise UsageError(f"the {what} cannot be separated from strip-wise {what.split()[0]} shifts (the attitude "
                                 f"hardly changes along a strip): estimate it with {order} = -1 (no strip-wise terms)")


@dataclass(frozen=True)
class SensorOptions:
    """What a sensor offers to estimate, where it offers a choice (pushbroom images).

    Attributes
    ----------
    model : str, optional
        Seed 001's ``M1`` ... ``M7`` or a comma-separated list of parameter names for pushbroom images.
    parameter_sigma : dict, optional
        A-priori sigmas (code units) by parameter name, overriding the sensor model's weights.
    attitude_telemetry : bool
        Pushbroom images: fit the attitude of attitude.csv (False: roll = pitch = yaw = 0 before the
        corrections, seed 001 Table 5).
    jitter : str
        Line images: the attitude jitter (``none``; ``wavelet1d:NAME:LEVEL``, 1-D wavelet scaling functions in
        time, :mod:`selfcal.sensors.pushbroom.jitter`; ``auto`` or ``wavelet1d:NAME`` for the tested workflow, which
        chooses the level; any of them with ``+details``: the scaling functions and wavelets of the level below).
    jitter_sigma_rad : float or (float, float, float), optional
        A-priori sigma of every jitter coefficient (rad), one for all axes or one per axis; default free (the tested
        workflow estimates it: :mod:`selfcal.workflows.jitter`).
    jitter_axes : tuple of str, optional
        The attitude axes that get jitter (the sensor's names: roll, pitch, yaw; ra, dec, twist); default every axis
        whose attitude polynomial is estimated.
    """

    model: str | None = None
    parameter_sigma: dict | None = None
    attitude_telemetry: bool = True
    jitter: str = "none"
    jitter_sigma_rad: float | tuple[float, ...] | None = None
    jitter_axes: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        from ..sensors.pushbroom.jitter import parse_jitter
        parse_jitter(self.jitter)
        sigma = self.jitter_sigma_rad
        if sigma is not None and not (np.ndim(sigma) == 0 or np.shape(sigma) == (3,)) or \
                sigma is not None and not np.all(np.asarray(sigma, float) > 0):
            raise UsageError(f"jitter sigma {sigma} rad: a positive number, or one per attitude axis, expected")
        if sigma is not None and np.ndim(sigma):
            object.__setattr__(self, "jitter_sigma_rad", tuple(float(v) for v in np.asarray(sigma, float)))


@dataclass(frozen=True)
class SolverOptions:
    """How to iterate.

    Attributes
    ----------
    max_iterations : int
    step_tolerance : float
        Converged when every correction is below this share of its conditional
        standard deviation (``|dx_i| · sqrt(N_ii) < tol``, unit variance), ...
    function_tolerance : float
        ... or when an undamped step moves no function of the unknowns by more
        than this share of its a-posteriori standard deviation (sqrt(d^T N d) <
        tol · sigma0). On real blocks a few weakly determined points (short
        bases) can creep along their rays for dozens of iterations, each step
        lowering the cost by ~1e-10 of itself; 1 % of a sigma is far below
        anything a test or a report can see.
    cost_tolerance : float
        ... or when an accepted step lowers the cost by less than this share.
    initial_damping : float
        Levenberg-Marquardt damping of the first step (relative to diag(N)).
        Zero (pure Gauss-Newton) by default: damping slows progress along the
        weakly determined directions a photogrammetric block always has (c
        against Z0, x0 against X0 and phi); it is switched on only when neither
        the step nor a shortened step lowers the cost, and off again once steps succeed.
    line_search : int
        How many times an undamped step that does not lower the cost is halved
        before damping is switched on (0: damping at once).
    point_sigma_ratio : float, optional
        Free networks: stop (``SolverOutcome.undetermined``) as soon as a linearisation has points that their
        rays do not determine (:func:`~selfcal.adjust.datum.points_not_determined_by_rays` with this ratio),
        for the caller to leave them out and go on from the estimate so far. Without a datum nothing holds
        such a point: Gauss-Newton sends it along its ray to infinity, damping only slows that to a creep
        that no convergence test ends (BAL problem-49: 39 points drift beyond 1e10 m in 50 iterations).
    free_network : bool
        The block has no datum (datum = "free"): the normal equations are
        singular by the datum defect (7 for a similarity). Up to
        PSEUDO_INVERSE_LIMIT orientation and camera unknowns the undamped step
        is the minimum-norm Gauss-Newton step (S's pseudo-inverse in the
        Jacobi-scaled metric, :func:`~selfcal.adjust.linalg.pseudo_factorise`):
        it has no component along the datum directions, so the estimate does
        not drift along them and every test above applies unchanged. This is
        the classical free-network adjustment (inner constraints), and it makes
        the convergence tests gauge-invariant: sqrt(d^T N d) does not see the
        datum at all (N is null along it), and a minimum-norm step has no datum
        part for the conditional ``step_sigma`` to be inflated by. Larger free
        networks keep Levenberg-Marquardt damping on (never below 1e-9: below,
        the rounding in g along the datum directions is amplified into steps
        that are rejected) and converge by the function test once the damping
        is at most 1e-6 (the step is the Gauss-Newton step in every direction
        the data determine to better than 1e-6 of the diagonal).
    """

    max_iterations: int = 50
    point_sigma_ratio: float | None = None
    step_tolerance: float = 1e-3
    function_tolerance: float = 1e-2
    cost_tolerance: float = 1e-12
    initial_damping: float = 0.0
    line_search: int = 6
    free_network: bool = False


@dataclass(frozen=True)
class AdjustOptions:
    """What to estimate and how: the four groups of options.

    >>> AdjustOptions(ap=APOptions("wavelet:db4", grid=(5, 4))).ap.grid
    (5, 4)
    """

    ap: APOptions = field(default_factory=APOptions)
    trajectory: TrajectoryOptions = field(default_factory=TrajectoryOptions)
    sensor: SensorOptions = field(default_factory=SensorOptions)
    solver: SolverOptions = field(default_factory=SolverOptions)

    def __post_init__(self) -> None:
        for name, kind in (("ap", APOptions), ("trajectory", TrajectoryOptions), ("sensor", SensorOptions),
                           ("solver", SolverOptions)):
            if not isinstance(getattr(self, name), kind):
                raise TypeError(f"AdjustOptions.{name}: a {kind.__name__} expected, not {getattr(self, name)!r}")
