"""Accuracy figures at check points: CE90 and LE90.

CE90 is the radius that contains 90 % of the horizontal errors, LE90 the
half-width that contains 90 % of the vertical errors (the ASPRS 2014 and
NSSDA terms). Both are the empirical 90th percentiles of the check-point
errors (linear interpolation between order statistics), so they make no
assumption about the error distribution; for a circular normal error with
sigma s per axis they tend to s·sqrt(-2 ln 0.1) = 2.146 s and 1.645 s.
"""
from __future__ import annotations

import numpy as np

__all__ = ["ce90", "le90"]


def ce90(d_xy: np.ndarray) -> float | None:
    """90th percentile of the horizontal error lengths; d_xy (n, 2). None without points."""
    d_xy = np.asarray(d_xy, float).reshape(-1, 2)
    if len(d_xy) == 0:
        return None
    return float(np.percentile(np.hypot(d_xy[:, 0], d_xy[:, 1]), 90.0))


def le90(d_z: np.ndarray) -> float | None:
    """90th percentile of the absolute vertical errors. None without points."""
    d_z = np.asarray(d_z, float).ravel()
    if len(d_z) == 0:
        return None
    return float(np.percentile(np.abs(d_z), 90.0))
