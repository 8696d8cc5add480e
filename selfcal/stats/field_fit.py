"""The camera field an adjustment sees, and how well an AP basis fits it in image space: a fast pre-filter.

A reference adjustment (a flexible AP model) leaves each image observation's residual; with the reference
model's own displacement added back it is what the camera's images show of a camera-fixed field, plus noise
(``y``, pixels along the photo axes). A candidate AP model's image-space fit of that field is the weighted linear
least-squares fit of ``y`` by its basis together with the six fields the orientation and the interior orientation
take up (:func:`selfcal.ap.absorbed_fields`). The points and orientations are not adjusted again, so the fit leaves
in the residuals what a point would absorb: an approximation of the candidate's adjustment that costs one small
solve and ranks the candidates; the model choice (:mod:`selfcal.workflows.model_choice`) cross-validates the few
it ranks best. The observations are pooled in cells of the frame (:data:`CELLS_ACROSS` across, square cells):
the fit of a cell's mean at the mean position of its observations, weighted by their number, plus the
scatter inside the cells, is the fit of the observations wherever the basis varies little across a cell
(a wavelet grid of 15 x 10 has four cells per grid unit).

    BIC = n ln(Omega / n) + k ln n,   Omega = sum |y - fit|^2 / sigma^2,

n the image coordinates, k the candidate's coefficients, sigma the a-priori sigma of an image coordinate (px).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..ap import APModel, absorbed_fields

__all__ = ["CELLS_ACROSS", "CameraField", "camera_fields", "field_fit"]

#: cells across the frame in which the observations are pooled
CELLS_ACROSS = 60


@dataclass(frozen=True)
class CameraField:
    """The pooled field of one camera: cell means of ``y`` at the mean positions of their observations."""

    camera_id: str
    x_mm: np.ndarray            # (cells,) mean photo coordinates of the cell's observations
    y_mm: np.ndarray
    dx_px: np.ndarray           # (cells,) mean field along the photo axes
    dy_px: np.ndarray
    count: np.ndarray           # (cells,) observations in the cell
    scatter: float              # sum over the cells of the squared deviations from their means, px^2
    observed_xy_mm: np.ndarray  # (n, 2) the camera's measured photo coordinates (to build adaptive bases on)

    @property
    def n_coordinates(self) -> int:
        return 2 * int(self.count.sum())


def camera_fields(result) -> list[CameraField] | None:
    """The field each camera of ``result`` shows (module docstring); None when a camera's AP model does not live
    on an image frame (a detector line)."""
    from ..adjust.residuals.image import ap_displacement, image_residuals
    problem, state = result.problem, result.state
    residual = image_residuals(problem, state)                  # l - f - delta, observation units, problem order
    cam_of = problem.image_camera[problem.obs_image]
    out = []
    for k, cam in enumerate(problem.cameras):
        frame = getattr(cam.ap, "frame", None)
        if frame is None or getattr(cam.ap, "domain", "frame") != "frame":
            return None
        o = np.flatnonzero(cam_of == k)
        if not o.size:
            continue
        xy = problem.obs_value[o]
        y = (residual[o] + ap_displacement(problem, state, o)) / frame.pixel_size_mm
        nx = CELLS_ACROSS
        ny = max(1, int(round(nx * frame.height_mm / frame.width_mm)))
        ix = np.clip(((xy[:, 0] / frame.width_mm + 0.5) * nx).astype(np.int64), 0, nx - 1)
        iy = np.clip(((xy[:, 1] / frame.height_mm + 0.5) * ny).astype(np.int64), 0, ny - 1)
        cell, index = np.unique(iy * nx + ix, return_inverse=True)
        count = np.bincount(index).astype(float)

        def mean(values: np.ndarray) -> np.ndarray:
            return np.bincount(index, weights=values) / count
        dx, dy = mean(y[:, 0]), mean(y[:, 1])
        scatter = float(np.sum((y[:, 0] - dx[index]) ** 2 + (y[:, 1] - dy[index]) ** 2))
        out.append(CameraField(cam.camera_id, mean(xy[:, 0]), mean(xy[:, 1]), dx, dy, count, scatter, xy))
    return out


@dataclass(frozen=True)
class FieldFit:
    omega: float                # sum of squared misfits / sigma^2
    n: int                      # image coordinates
    k: int                      # coefficients of the candidate (all cameras)

    @property
    def bic(self) -> float:
        return float(self.n * np.log(self.omega / self.n) + self.k * np.log(self.n))


def field_fit(fields: list[CameraField], models: dict[str, APModel], sigma_px: float) -> FieldFit:
    """The image-space fit of each camera's field by its model in ``models`` (camera id -> APModel; a camera
    without one: the six absorbed fields alone) with the absorbed fields alongside."""
    omega, n, k = 0.0, 0, 0
    for f in fields:
        model = models.get(f.camera_id)
        fx, fy = absorbed_fields(f.x_mm, f.y_mm)
        if model is not None and model.n_params:
            bx, by = model.basis(f.x_mm, f.y_mm)
            fx, fy = np.hstack([bx, fx]), np.hstack([by, fy])
            k += model.n_params
        w = np.sqrt(f.count)[:, None]
        design = np.vstack([fx * w, fy * w])
        target = np.concatenate([f.dx_px, f.dy_px]) * np.concatenate([w[:, 0], w[:, 0]])
        gram, rhs = design.T @ design, design.T @ target
        scale = 1.0 / np.sqrt(np.clip(np.diag(gram), 1e-300, None))
        values, vectors = np.linalg.eigh(gram * scale[:, None] * scale[None, :])
        keep = values > 1e-10 * values.max()
        projected = (vectors[:, keep].T @ (rhs * scale)) / np.sqrt(values[keep])
        misfit = max(float(target @ target - projected @ projected), 0.0)
        omega += (misfit + f.scatter) / sigma_px ** 2
        n += f.n_coordinates
    return FieldFit(omega, n, k)
