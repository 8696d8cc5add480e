"""The fitted correction where no observation lies: how far a camera's calibration is extrapolated.

A camera's correction field Delta is determined where its images have points; beyond, it is whatever the basis
does there: Brown's polynomials grow towards the corners, a wavelet whose support holds a handful of rays can put
tens of pixels in a corner without tie points (a real block: 167 px). The frame is cut into :data:`AREA_CELLS`
cells across (square cells); a cell that holds an image observation of the camera is observed. |Delta| is
evaluated on the nodes of distortion_grid.csv (61 across, :func:`selfcal.ap.frame_nodes_mm`); its largest value
at the nodes of observed cells and at the others is reported, and a largest value outside the observed area that
exceeds the largest inside by more than :data:`EXTRAPOLATION_MARGIN_PX` is a warning: in summary.json, the report
and every calibration export.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..ap import APModel, frame_nodes_mm

__all__ = ["AREA_CELLS", "EXTRAPOLATION_MARGIN_PX", "Extrapolation", "extrapolation"]

#: cells across the frame that map the observed area (250 px on seed 000's 6000 px frame)
AREA_CELLS = 24
#: a correction outside the observed area more than this above the largest inside it is a warning (px): a lens
#: field continues smoothly by a fraction of a pixel over a cell or two; beyond, the export hands another program
#: a correction no observation supports
EXTRAPOLATION_MARGIN_PX = 1.0


@dataclass(frozen=True)
class Extrapolation:
    camera_id: str
    max_inside_px: float            # largest |Delta| at the nodes of observed cells
    max_outside_px: float           # ... of the cells without observations (0 when every cell is observed)
    observed_share: float           # share of the frame's cells with observations
    margin_px: float = EXTRAPOLATION_MARGIN_PX

    @property
    def warning(self) -> str | None:
        if self.max_outside_px <= self.max_inside_px + self.margin_px:
            return None
        return (f"camera {self.camera_id}: the calibration is extrapolated: where no observation lies "
                f"({100 * (1 - self.observed_share):.0f} % of the frame) its correction reaches "
                f"{self.max_outside_px:.2f} px, against {self.max_inside_px:.2f} px at most over the observed area; "
                f"it is not supported there (use the calibration only within the observed area)")

    def as_dict(self) -> dict:
        return asdict(self) | {"warning": self.warning}


def extrapolation(camera_id: str, model: APModel, coefficients_px: np.ndarray, observed_xy_mm: np.ndarray,
                  margin_px: float = EXTRAPOLATION_MARGIN_PX) -> Extrapolation:
    """The extrapolation of one camera's correction (``model`` with ``coefficients_px``, the inactive ones zero)
    beyond its observations (photo coordinates, mm)."""
    frame = model.frame
    nx = AREA_CELLS
    ny = max(1, int(round(nx * frame.height_mm / frame.width_mm)))

    def cell(x, y):
        ix = np.clip(((np.asarray(x) / frame.width_mm + 0.5) * nx).astype(np.int64), 0, nx - 1)
        iy = np.clip(((np.asarray(y) / frame.height_mm + 0.5) * ny).astype(np.int64), 0, ny - 1)
        return iy * nx + ix
    observed = np.zeros(nx * ny, bool)
    if len(observed_xy_mm):
        observed[cell(observed_xy_mm[:, 0], observed_xy_mm[:, 1])] = True
    x, y = frame_nodes_mm(frame)
    dx, dy = model.displacement_px(x, y, coefficients_px) if model.n_params else (np.zeros_like(x),) * 2
    size = np.hypot(dx, dy)
    inside = observed[cell(x, y)]
    return Extrapolation(camera_id, float(size[inside].max(initial=0.0)), float(size[~inside].max(initial=0.0)),
                         float(observed.mean()), margin_px)
