"""The accuracy statement of the ASPRS Positional Accuracy Standards for Digital Geospatial Data, Edition 2,
Version 1.0 (August 2023).

Edition 2 drops the 95 % measures of Edition 1 (CE90/LE90-like figures are no longer the statement; selfcal keeps
them in summary.json beside this one) and states a product's accuracy as RMSEs at check points in which the check
points' own survey error is included ("Summary of Changes in Edition 2": survey checkpoint accuracy considered
in the product accuracy, at least 30 checkpoints instead of 20, the new three-dimensional positional accuracy):

* RMSE_H,measured = sqrt(RMSE_x² + RMSE_y²), RMSE_x = sqrt(mean(dx²)), likewise y (Edition 1's radial RMSE_r,
  Edition 2's RMSE_H);
* RMSE_V,measured = sqrt(mean(dz²));
* the survey's own: RMSE_H,survey = sqrt(mean(σx² + σy²)), RMSE_V,survey = sqrt(mean(σz²)) from the check points'
  a-priori sigmas (points.csv / the block: their σ_X, σ_Y, σ_Z);
* the product's: RMSE_H = sqrt(RMSE_H,measured² + RMSE_H,survey²), RMSE_V likewise;
* RMSE_3D = sqrt(RMSE_H² + RMSE_V²);
* the class: Edition 2 names a class by the RMSE it allows, "#-cm" (its horizontal and vertical accuracy class
  tables, Tables 7.1 and 7.2 as recalled, not checked against the text here, leave # open); the result meets the smallest class of :data:`CLASSES_CM` at or above
  its RMSE (beyond the list: its RMSE rounded up to a whole centimetre);
* fewer than :data:`MIN_CHECKPOINTS` check points: the figures are given with a warning that they are no
  statement under the standard.

d = estimate − reference along the axes the check-point errors are given in (east, north, up for ECEF). Pure
functions: no I/O.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["MIN_CHECKPOINTS", "CLASSES_CM", "AccuracyStatement", "accuracy_class_cm", "accuracy_statement"]

#: Edition 2's minimum number of check points for an accuracy statement (Edition 1: 20)
MIN_CHECKPOINTS = 30
#: the "#-cm" class values selfcal states a result against (horizontal and vertical alike): common values of the
#: standard's examples from sub-centimetre photogrammetry to satellite products; Edition 2 allows any #
CLASSES_CM = (0.5, 1.0, 1.25, 2.0, 2.5, 5.0, 7.5, 10.0, 12.5, 15.0, 20.0, 25.0, 30.0, 50.0, 75.0, 100.0, 150.0,
              200.0, 250.0, 300.0, 500.0, 1000.0)


@dataclass(frozen=True)
class AccuracyStatement:
    """summary.json ``accuracy``: the Edition 2 figures (m), the classes met (cm) and the warnings."""

    standard: str
    n_checkpoints: int
    n_survey_sigma: int                 # check points with a survey sigma (the others count with none)
    min_checkpoints: int
    rmse_x_m: float | None
    rmse_y_m: float | None
    rmse_h_measured_m: float | None
    rmse_v_measured_m: float | None
    rmse_h_survey_m: float | None
    rmse_v_survey_m: float | None
    rmse_h_m: float | None
    rmse_v_m: float | None
    rmse_3d_m: float | None
    horizontal_class_cm: float | None
    vertical_class_cm: float | None
    enough_checkpoints: bool
    warnings: list[str]

    def as_dict(self) -> dict:
        return asdict(self)


def accuracy_class_cm(rmse_m: float | None, classes_cm: tuple[float, ...] = CLASSES_CM) -> float | None:
    """The smallest "#-cm" class whose RMSE limit is at or above ``rmse_m`` (None without a figure)."""
    if rmse_m is None or not math.isfinite(rmse_m):
        return None
    cm = 100.0 * rmse_m
    for limit in classes_cm:
        if cm <= limit + 1e-9:
            return float(limit)
    return float(math.ceil(cm - 1e-9))


def _rms(values: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(values))) if values.size else None


def _combine(measured: float | None, survey: float | None) -> float | None:
    if measured is None:
        return None
    return float(math.hypot(measured, survey or 0.0))


def accuracy_statement(errors_m: np.ndarray, survey_sigma_m: np.ndarray | None) -> AccuracyStatement:
    """The Edition 2 accuracy of check points with errors ``errors_m`` (n, 3: dx, dy, dz) and survey sigmas
    ``survey_sigma_m`` (n, 3; NaN where a point has none; None: none given). The survey RMSE is over the points
    with a finite sigma on all three axes; without any, the product RMSE is the measured one and a warning says
    so."""
    d = np.asarray(errors_m, float).reshape(-1, 3)
    n = len(d)
    sigma = np.full((n, 3), np.nan) if survey_sigma_m is None else np.asarray(survey_sigma_m, float).reshape(-1, 3)
    known = np.all(np.isfinite(sigma), axis=1)
    warnings = []
    if n == 0:
        warnings.append("no check points: no accuracy statement")
    elif n < MIN_CHECKPOINTS:
        warnings.append(f"{n} check points: ASPRS Edition 2 asks for at least {MIN_CHECKPOINTS} for an accuracy "
                        "statement; the figures are indicative only")
    if n and not known.all():
        warnings.append(f"{int((~known).sum())} of {n} check points have no survey sigma: the survey term is "
                        "the RMS over the others" if known.any() else
                        "the check points have no survey sigma: the product RMSE is the measured one alone")
    rmse_x, rmse_y = _rms(d[:, 0] ** 2), _rms(d[:, 1] ** 2)
    h_measured = _rms(np.sum(d[:, :2] ** 2, axis=1))
    v_measured = _rms(d[:, 2] ** 2)
    h_survey = _rms(np.sum(sigma[known, :2] ** 2, axis=1))
    v_survey = _rms(sigma[known, 2] ** 2)
    h, v = _combine(h_measured, h_survey), _combine(v_measured, v_survey)
    three_d = None if h is None or v is None else float(math.hypot(h, v))
    return AccuracyStatement(
        standard="ASPRS Positional Accuracy Standards for Digital Geospatial Data, Edition 2, Version 1.0 (2023)",
        n_checkpoints=n, n_survey_sigma=int(known.sum()), min_checkpoints=MIN_CHECKPOINTS,
        rmse_x_m=rmse_x, rmse_y_m=rmse_y, rmse_h_measured_m=h_measured, rmse_v_measured_m=v_measured,
        rmse_h_survey_m=h_survey, rmse_v_survey_m=v_survey, rmse_h_m=h, rmse_v_m=v, rmse_3d_m=three_d,
        horizontal_class_cm=accuracy_class_cm(h), vertical_class_cm=accuracy_class_cm(v),
        enough_checkpoints=n >= MIN_CHECKPOINTS, warnings=warnings)
