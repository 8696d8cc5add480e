"""Pieces shared by the vendor line cameras (DigitalGlobe/Maxar XML, SPOT 5 DIMAP) and the one entry point
that turns a vendor sensor file into a selfcal :class:`~selfcal.sensors.pushbroom.LineImage`.

The generic pushbroom model (:mod:`selfcal.sensors.pushbroom`) takes its trajectory as callables of time:
position, velocity (Earth-fixed here) and the attitude as roll, pitch, yaw of the body (selfcal's telescope
frame T: x along track, z towards the scene) in the orbit frame of that position and velocity. A vendor model
gives the rotation T -> ECEF instead; :class:`OrbitAttitude` turns one into the other at every call (no fit),
so the lines of sight are the vendor's and seed 001's attitude corrections (Eq. 6) apply unchanged.

A vendor's line times need not be one straight line in the row (DigitalGlobe's TLC list may change the line
rate): :class:`LineTimes` is the row -> time table, and the image runs on a *pseudo time* linear in the row,
tau = tau0 + row * period, which every callable maps to the true time before it evaluates (:class:`OnLineTime`).
With one line rate tau is the true time.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..geometry.earth import orbit_frame
from .pushbroom import angles_from_body_to_orbit

__all__ = ["LineTimes", "OnLineTime", "OrbitAttitude", "line_image_from_file"]


@dataclass(frozen=True)
class LineTimes:
    """Piecewise-linear time of selfcal rows (the table's rows and times, rows increasing); linear
    extrapolation beyond the first and last entry with their intervals' rates."""

    rows: np.ndarray
    times_s: np.ndarray

    def __post_init__(self):
        if len(self.rows) < 2 or np.any(np.diff(self.rows) <= 0):
            raise ValueError("LineTimes needs two or more increasing rows")
        if np.any(np.diff(self.times_s) == 0) or len(set(np.sign(np.diff(self.times_s)))) != 1:
            raise ValueError("the times of the line table must be strictly monotonic")

    @property
    def period_s(self) -> float:
        """|mean seconds per row| over the table: the pseudo time's line period."""
        return float(abs((self.times_s[-1] - self.times_s[0]) / (self.rows[-1] - self.rows[0])))

    @property
    def linear(self) -> bool:
        """One increasing line rate (to 1e-12 s over the table): the pseudo time is the time."""
        fit = self.times_s[0] + (self.rows - self.rows[0]) * self.period_s
        return bool(np.all(np.abs(fit - self.times_s) < 1e-12) and self.times_s[-1] > self.times_s[0])

    def time(self, row) -> np.ndarray:
        row = np.asarray(row, float)
        k = np.clip(np.searchsorted(self.rows, row, side="right") - 1, 0, len(self.rows) - 2)
        slope = (self.times_s[k + 1] - self.times_s[k]) / (self.rows[k + 1] - self.rows[k])
        return self.times_s[k] + slope * (row - self.rows[k])

    def row(self, time_s) -> np.ndarray:
        """Inverse of :meth:`time`."""
        order = np.argsort(self.times_s)
        return LineTimes(self.times_s[order], self.rows[order]).time(time_s)


@dataclass(frozen=True)
class OnLineTime:
    """A callable of true time evaluated at the true time of a pseudo time (module docstring)."""

    function: object
    line_times: LineTimes
    tau0_s: float

    def __call__(self, tau):
        row = (np.asarray(tau, float) - self.tau0_s) / self.line_times.period_s
        return self.function(self.line_times.time(row))


@dataclass(frozen=True)
class OrbitAttitude:
    """Roll, pitch, yaw (n, 3) of the telescope frame in the orbit frame, evaluated from callables of time:
    ``position`` and ``velocity`` (Earth-fixed), ``rotation`` (n, 3, 3) telescope -> Earth-fixed."""

    position: object
    velocity: object
    rotation: object

    def __call__(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, float))
        R_FO = orbit_frame(np.atleast_2d(self.position(t)), np.atleast_2d(self.velocity(t)))
        return angles_from_body_to_orbit(np.swapaxes(R_FO, -1, -2) @ self.rotation(t))


def line_image_from_file(path: str | os.PathLike, image_id: str | None = None):
    """The selfcal line camera of a vendor sensor file, the format found from the content: a DigitalGlobe /
    Maxar XML (root ``isd``), a SPOT 5 DIMAP (root ``Dimap_Document`` with ``Data_Strip``) or a Pleiades DIMAP
    (root ``PHR_Dimap_Document``). Reader errors are :class:`~selfcal.errors.BlockError`."""
    from ..errors import BlockError
    path = str(path)
    try:
        with open(path, "rb") as handle:
            head = handle.read(4096)
    except OSError as exc:
        raise BlockError(path, f"cannot read the sensor file: {exc.strerror}") from None
    if b"<isd>" in head or b"<isd " in head:
        from ..io.dg import read_dg
        from .dg import line_image_from_dg
        return line_image_from_dg(read_dg(path), image_id)
    if b"PHR_Dimap_Document" in head:
        from ..io.dimap import read_dimap_sensor
        from .dimap import line_image_from_dimap
        return line_image_from_dimap(read_dimap_sensor(path), image_id or "PHR")
    if b"Dimap_Document" in head:
        from ..io.spot import read_spot5
        from .spot import line_image_from_spot5
        return line_image_from_spot5(read_spot5(path), image_id)
    raise BlockError(path, "not a vendor sensor file: neither DigitalGlobe/Maxar XML (root isd) nor DIMAP "
                           "(PHR_Dimap_Document or SPOT Dimap_Document)")
