"""Another tool's camera calibration as a block camera's initial (or held) interior orientation and APs."""
from __future__ import annotations

from dataclasses import replace

from ..block import FrameCamera, InitialAP

def camera_from_calibration(calibration, camera: FrameCamera, ap_spec: str = "brown",
                            fixed: bool = False) -> tuple[FrameCamera, float]:
    """A block camera whose initial interior orientation and APs are another tool's calibration.

    ``calibration`` is a :class:`selfcal.io.calibration_files.ToolCalibration` of ``camera``'s image size
    (the caller checks it); its model (:data:`selfcal.calibration_models.MODELS`) gives c, x0, y0 and the
    initial ``ap_spec`` coefficients by :func:`selfcal.calibration_models.initial_from_model`, on ``camera``'s
    pixel size. With ``fixed`` they are held in the adjustment (sigma 0 for c, x0, y0 and the APs). Returns
    the camera and the largest misfit of the AP fit over the image (pixels).
    """
    from ..calibration_models import MODELS, initial_from_model
    model = MODELS[calibration.tool, calibration.model]
    values = [calibration.values.get(name, 0.0) for name in model.parameter_names]
    initial = initial_from_model(model, values, camera.width_px, camera.height_px, camera.pixel_size_mm, ap_spec)
    hold = 0.0 if fixed else None
    return replace(camera, focal_mm=initial.focal_mm, x0_mm=initial.x0_mm, y0_mm=initial.y0_mm,
                   sigma_focal_mm=hold if fixed else camera.sigma_focal_mm,
                   sigma_x0_mm=hold if fixed else camera.sigma_x0_mm,
                   sigma_y0_mm=hold if fixed else camera.sigma_y0_mm,
                   initial_ap=InitialAP(initial.ap_spec, initial.ap_names, initial.ap_values_px, hold)), \
        initial.misfit_max_px


#: the points of a results folder that go into a dense workspace: those the bundle adjusted (check points
#: are left out: they check the block, they do not tie it)
