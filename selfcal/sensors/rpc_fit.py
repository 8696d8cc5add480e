"""An RPC fitted to a sensor model by least squares: the terrain-independent approach of Tao & Hu (2001).

Tao, C. V. and Hu, Y. (2001), *A comprehensive study of the rational function model for photogrammetric
processing*, PE&RS 67(12), 1347-1357, §"terrain-independent scenario": the physical model itself supplies the
control. A grid over the image (``n_rows`` x ``n_cols`` nodes from edge to edge) is carried to the ground at
``n_heights`` layers spanning the height range (the model's image-to-ground at each layer's height); the RPC's
offsets and scales normalise that cube to [-1, 1] (image: the image's centre and half its size; ground: the
middle and half the extent of the grid's latitudes, longitudes and heights). For each image coordinate the
20 numerator and 19 denominator coefficients (the denominator's constant is 1; 78 in all) solve the linearised
equations

    T(P, L, H) · a - r · T'(P, L, H) · b = r        (r the normalised line or sample, T the 20 RPC00B terms,
                                                     T' the 19 without the constant)

by weighted least squares, iterated with the weights 1 / Den² of the previous solution, so that the minimised
residual is the image misfit r - Num/Den rather than Den times it (Tao & Hu's iterative least squares), and
regularised by a ridge (Tikhonov) term ``ridge`` times the mean diagonal of the column-scaled normal matrix, as Tao &
Hu regularise it: the denominator's coefficients are nearly undetermined where a sensor is close to a cubic
polynomial (a line scanner over a short arc), which is when the unregularised system is ill-conditioned. The fixed
relative ridge replaces their L-curve choice: of 0, 1e-14 ... 1e-8 it gave the smallest check-grid misfit on an
affinely corrected Pleiades RPC (2e-6 px max, against 4e-6 px unregularised and 1.4e-3 px at 1e-8); on the Pleiades
and DigitalGlobe physical models 1e-14 and 1e-12 differ by 1e-4 px (1e-10 costs 0.004 px on Pleiades).
The fit error is then measured on an independent *check grid* (:func:`check_grid`: the centres of the fit grid's
cells at heights half-way between its layers), which :func:`fit_rpc` reports with the misfit on the fit grid.

Pixels are selfcal's (DESIGN.md §2: (0, 0) the upper-left corner of the image): the fitted
:class:`~selfcal.sensors.rpc.RpcModel` has ``pixel_origin`` 0.5, i.e. its line and sample *are* selfcal's row and
column; a writer moves its offsets to its format's convention. Ground coordinates are longitude and latitude
(degrees) and height (m) on the model's ellipsoid (WGS 84 for the Earth's sensors).
"""
from __future__ import annotations

from dataclasses import dataclass
from collections.abc import Sequence
from typing import Callable

import numpy as np
from numpy.typing import ArrayLike

from .rpc import RpcModel, rpc00b_terms

__all__ = ["RpcFit", "fit_rpc", "fit_grid", "check_grid", "misfit_px", "FIT_GRID", "RIDGE", "ITERATIONS",
           "SELFCAL_PIXEL_ORIGIN"]

#: nodes of the fit grid: rows, columns, height layers (Tao & Hu use 10 x 10 x 5 and more; 2 x 39 unknowns)
FIT_GRID = (21, 21, 7)
#: ridge (Tikhonov) weight relative to the mean diagonal of the (column-scaled) normal matrix
RIDGE = 1e-12
#: reweighting iterations (1 / Den^2) at most; they stop when the misfit changes by less than 1e-6 px
ITERATIONS = 10
#: pixel_origin of the fitted model: its line, samp are selfcal's row, col
SELFCAL_PIXEL_ORIGIN = 0.5


@dataclass(frozen=True)
class RpcFit:
    """A fitted RPC and its misfit to the model, in px (2-D distance in the image): on the fit grid and on the
    independent check grid (:func:`check_grid`)."""

    model: RpcModel
    fit_rms_px: float
    fit_max_px: float
    check_rms_px: float
    check_max_px: float
    n_fit_points: int
    n_check_points: int


def _nodes(extent: float, n: int, centres: bool) -> np.ndarray:
    edges = np.linspace(0.0, float(extent), n)
    return 0.5 * (edges[1:] + edges[:-1]) if centres else edges


def fit_grid(rows_px: float, cols_px: float, heights_m: Sequence[float], grid: Sequence[int] = FIT_GRID
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(row, col, h) of the fit grid: ``grid`` = (rows, columns, layers) nodes from image edge to edge and from the
    lowest to the highest height, flattened."""
    lo, hi = (float(v) for v in heights_m)
    row, col, h = np.meshgrid(_nodes(rows_px, grid[0], False), _nodes(cols_px, grid[1], False),
                              np.linspace(lo, hi, grid[2]), indexing="ij")
    return row.ravel(), col.ravel(), h.ravel()


def check_grid(rows_px: float, cols_px: float, heights_m: Sequence[float], grid: Sequence[int] = FIT_GRID
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(row, col, h) of the check grid: the centres of the fit grid's cells, at the heights half-way between its
    layers (none of its points is a fit point), flattened."""
    lo, hi = (float(v) for v in heights_m)
    layers = np.linspace(lo, hi, grid[2])
    row, col, h = np.meshgrid(_nodes(rows_px, grid[0], True), _nodes(cols_px, grid[1], True),
                              0.5 * (layers[1:] + layers[:-1]), indexing="ij")
    return row.ravel(), col.ravel(), h.ravel()


def misfit_px(model: RpcModel, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike, row_px: ArrayLike,
              col_px: ArrayLike) -> tuple[float, float]:
    """(rms, max) of the 2-D distance (px) between ``model``'s projection of ground points and (row, col)."""
    row, col = model.project(lon_deg, lat_deg, h_m)
    d = np.hypot(row - np.asarray(row_px, float), col - np.asarray(col_px, float))
    return float(np.sqrt(np.mean(d ** 2))), float(np.max(d))


def _ground(localize, row, col, h):
    lon, lat = localize(row, col, h)
    lon, lat = np.asarray(lon, float), np.asarray(lat, float)
    keep = np.isfinite(lon) & np.isfinite(lat)
    return keep, lon, lat


def _solve(terms: np.ndarray, r: np.ndarray, ridge: float, iterations: int):
    """Numerator (20) and denominator (20, constant 1) of r = Num/Den by reweighted, regularised least squares."""
    A = np.hstack([terms, -r[:, None] * terms[:, 1:]])
    weight = np.ones(len(r))
    previous = np.inf
    best = None
    for _ in range(iterations):
        Aw = A * weight[:, None]
        scale = np.linalg.norm(Aw, axis=0)
        scale[scale == 0] = 1.0
        As = Aw / scale
        N = As.T @ As
        N[np.diag_indices_from(N)] += ridge * np.trace(N) / len(N)
        x = np.linalg.solve(N, As.T @ (r * weight)) / scale
        num, den = x[:20], np.concatenate([[1.0], x[20:]])
        d = terms @ den
        misfit = np.sqrt(np.mean((r - (terms @ num) / d) ** 2))
        if best is None or misfit < best[0]:
            best = (misfit, num, den)
        if not np.all(np.isfinite(d)) or abs(previous - misfit) <= 1e-9 * max(misfit, 1e-300) or misfit == 0.0:
            break
        previous = misfit
        weight = 1.0 / np.abs(d)
    if best is None:
        raise ValueError(f"the fit needs at least one reweighting iteration, found iterations={iterations}")
    return best[1], best[2]


def fit_rpc(project: Callable, localize: Callable, rows_px: float, cols_px: float, heights_m: Sequence[float],
            grid: Sequence[int] = FIT_GRID, ridge: float = RIDGE, iterations: int = ITERATIONS) -> RpcFit:
    """The RPC00B of a sensor model, fitted on a 3-D grid (module docstring: Tao & Hu 2001).

    Parameters
    ----------
    project : callable
        ``project(lon_deg, lat_deg, h_m) -> (row_px, col_px)``: the model's ground to image (selfcal pixels); the
        check grid's misfit is measured against it.
    localize : callable
        ``localize(row_px, col_px, h_m) -> (lon_deg, lat_deg)``: its image to ground at given heights (NaN where
        it has none; such nodes are left out).
    rows_px, cols_px : float
        The image's size: the grid spans 0 .. rows_px and 0 .. cols_px.
    heights_m : (min, max)
        The height range (m above the ellipsoid) of the layers; max > min.
    grid : (int, int, int)
        Nodes of the fit grid along rows, columns and heights (at least 4 x 4 x 4: a cubic in each).

    Returns
    -------
    RpcFit
        The model (``pixel_origin`` 0.5: selfcal's pixels) and its misfit (px) on the fit and check grids.
    """
    lo, hi = (float(v) for v in heights_m)
    if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
        raise ValueError(f"the height range needs min < max, found {lo} .. {hi}")
    if not (rows_px > 0 and cols_px > 0):
        raise ValueError(f"the image size must be positive, found {rows_px} x {cols_px}")
    if min(grid) < 4:
        raise ValueError(f"the fit grid needs at least 4 nodes in each direction, found {grid}")
    row, col, h = fit_grid(rows_px, cols_px, (lo, hi), grid)
    keep, lon, lat = _ground(localize, row, col, h)
    if keep.sum() < 0.9 * len(row):
        raise ValueError(f"the model localises only {int(keep.sum())} of the {len(row)} grid points on the ground")
    row, col, h, lon, lat = row[keep], col[keep], h[keep], lon[keep], lat[keep]

    def centre_and_half(values):
        a, b = float(np.min(values)), float(np.max(values))
        return 0.5 * (a + b), max(0.5 * (b - a), 1e-12)

    lat_off, lat_scale = centre_and_half(lat)
    lon_off, lon_scale = centre_and_half(lon)
    h_off, h_scale = 0.5 * (lo + hi), 0.5 * (hi - lo)
    line_off, line_scale = 0.5 * rows_px, 0.5 * rows_px
    samp_off, samp_scale = 0.5 * cols_px, 0.5 * cols_px
    terms = rpc00b_terms((lon - lon_off) / lon_scale, (lat - lat_off) / lat_scale, (h - h_off) / h_scale)
    line_num, line_den = _solve(terms, (row - line_off) / line_scale, ridge, iterations)
    samp_num, samp_den = _solve(terms, (col - samp_off) / samp_scale, ridge, iterations)
    model = RpcModel(line_off=line_off, line_scale=line_scale, samp_off=samp_off, samp_scale=samp_scale,
                     lat_off=lat_off, lat_scale=lat_scale, long_off=lon_off, long_scale=lon_scale,
                     height_off=h_off, height_scale=h_scale, line_num=line_num, line_den=line_den,
                     samp_num=samp_num, samp_den=samp_den, pixel_origin=SELFCAL_PIXEL_ORIGIN)
    fit_rms, fit_max = misfit_px(model, lon, lat, h, row, col)
    c_row, c_col, c_h = check_grid(rows_px, cols_px, (lo, hi), grid)
    c_keep, c_lon, c_lat = _ground(localize, c_row, c_col, c_h)
    c_lon, c_lat, c_h = c_lon[c_keep], c_lat[c_keep], c_h[c_keep]
    check_rms, check_max = misfit_px(model, c_lon, c_lat, c_h, *project(c_lon, c_lat, c_h))
    return RpcFit(model, fit_rms, fit_max, check_rms, check_max, int(keep.sum()), int(c_keep.sum()))
