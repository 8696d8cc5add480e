"""distortion_sigma.csv and summary.json ``distortion_sigma``: the σ of each frame camera's AP correction on the grid
of distortion_grid.csv, the observed area, and the half-block check's difference field
(:mod:`selfcal.stats.field_sigma`, :mod:`selfcal.workflows.half_block`).

Columns, along the pixel axes (col right, row down; Δ_row = −Δ_y): ``col, row`` the node (px);
``sigma_dcol_px, sigma_drow_px`` the σ of the correction's components; ``rho`` their correlation;
``sigma_norm_px`` = sqrt(σ_col² + σ_row²) (the RMS length of its error vector); ``sigma_major_px`` the σ in the worst
direction; ``observed`` 1 where an observation lies within 5 % of the frame's width of the node; then, where the
half-block check was made, ``half_ddcol_px, half_ddrow_px`` the correction of the first half minus the second's and
``half_sigma_dcol_px, half_sigma_drow_px`` its σ (both halves' covariances summed), else empty. With several cameras
a leading ``camera_id`` column.
"""
from __future__ import annotations

import numpy as np

from ..stats.field_sigma import correction_sigma, estimated_frame_cameras

__all__ = ["distortion_sigma_table", "distortion_sigma_summary", "SIGMA_COLUMNS"]

#: the columns of distortion_sigma.csv after the optional camera_id (module docstring)
SIGMA_COLUMNS = ["col", "row", "sigma_dcol_px", "sigma_drow_px", "rho", "sigma_norm_px", "sigma_major_px", "observed",
                 "half_ddcol_px", "half_ddrow_px", "half_sigma_dcol_px", "half_sigma_drow_px"]


def distortion_sigma_table(result, half_block=None):
    """distortion_sigma.csv (module docstring) as (header, columns, formats); None where no camera has estimated
    frame APs. ``half_block``: the :class:`~selfcal.workflows.half_block.HalfBlock` check, if made."""
    cameras = estimated_frame_cameras(result)
    if not cameras:
        return None
    halves = {c.camera_id: c for c in (half_block.cameras if half_block is not None else [])}
    columns: dict[str, list] = {k: [] for k in ["camera_id"] + SIGMA_COLUMNS}
    for k in cameras:
        s = correction_sigma(result, k)
        n = len(s.col_px)
        c = s.covariance
        half = halves.get(s.camera_id)
        if half is not None:
            d = half.difference
            dd = np.column_stack([d.difference[:, 0], -d.difference[:, 1]])
            dsig = np.column_stack([d.covariance.sigma_x, d.covariance.sigma_y])
        else:
            dd = dsig = np.full((n, 2), np.nan)
        values = [np.full(n, s.camera_id, dtype=object), s.col_px, s.row_px, c.sigma_x, c.sigma_y, -c.rho,
                  c.sigma_norm, c.sigma_major, s.observed.astype(int), dd[:, 0], dd[:, 1], dsig[:, 0], dsig[:, 1]]
        for key, v in zip(columns, values):
            columns[key].append(v)
    multi = len(cameras) > 1
    header = (["camera_id"] if multi else []) + SIGMA_COLUMNS
    fmts = ([""] if multi else []) + [".2f", ".2f", ".5f", ".5f", ".4f", ".5f", ".5f", "d", ".5f", ".5f", ".5f", ".5f"]
    return header, [np.concatenate(columns[h]) for h in header], fmts


def distortion_sigma_summary(result) -> dict | None:
    """summary.json ``distortion_sigma``: by camera id, for each camera with estimated frame APs, the number of
    coefficients, the largest and the RMS ``sigma_norm_px`` over the observed nodes, the largest over the whole
    frame, and the share of the frame observed (None where no camera has estimated frame APs)."""
    cameras = estimated_frame_cameras(result)
    if not cameras:
        return None
    out = {}
    for k in cameras:
        s = correction_sigma(result, k)
        norm = s.covariance.sigma_norm
        seen = s.observed
        out[s.camera_id] = {"n_estimated": s.n_estimated,
                            "max_sigma_observed_px": float(norm[seen].max()) if seen.any() else None,
                            "rms_sigma_observed_px": float(np.sqrt(np.mean(norm[seen] ** 2))) if seen.any() else None,
                            "max_sigma_px": float(norm.max()), "observed_share": float(seen.mean())}
    return out
