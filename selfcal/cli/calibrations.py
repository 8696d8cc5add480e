"""The frame calibrations of a results folder, for the verbs that hand them to other programs (export,
undistort): read, pick one, fit an OpenCV model and say its misfit."""
from __future__ import annotations

import os
import sys

from ..calibration import OPENCV_MODELS, Calibration, undistortion_maps
from ..calibration_models import (FAMILIES, FISHEYE_FIELD_DEG, FRAME_MODEL_FAILS_PX, LENS_MODELS, MODELS, LensChoice,
                                  fit_best, fit_for_lens, propagate)
from ..errors import BlockError, UsageError
from ..io.camera_json import frame_camera_entries
from .options import number
from .outcome import progress

__all__ = ["calibrations", "pick_camera", "maps_of", "models", "report_fit", "camera_options", "tool_options",
           "fit_tool", "lens_reason", "fitted_covariance", "tool_calibration", "warn_extrapolated"]


def camera_options(parser) -> None:
    """--camera, --opencv-model, --tolerance-px: the options of every export that fits an OpenCV model."""
    parser.add_argument("--camera", metavar="ID", help="camera to export (needed when the block has several)")
    parser.add_argument("--opencv-model", default="auto", metavar="MODEL",
                        help=f"OpenCV distortion model: auto (the first of {', '.join(OPENCV_MODELS)} within "
                             f"--tolerance-px, else the closest) or one of them")
    parser.add_argument("--tolerance-px", type=number(0.0, low_open=True), default=0.01,
                        help="largest misfit of the OpenCV model accepted by 'auto' (default 0.01 px)")


def calibrations(results: str) -> dict[str, Calibration]:
    """The frame cameras of a results folder's camera.json, by id."""
    path = os.path.join(results, "camera.json")
    out = {}
    for camera_id, entry in frame_camera_entries(results).items():
        try:
            out[camera_id] = Calibration.from_camera_json(camera_id, entry)
        except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:   # the AP family's own keys
            raise BlockError(path, f"camera {camera_id}: cannot read its calibration ({exc})") from None
        if entry.get("shutter") == "rolling":
            readout = entry.get("readout_ms") or {}
            value = readout.get("value")
            sigma = readout.get("sigma")
            said = f"{value:.2f} ms" + (f" +- {sigma:.2f}" if sigma is not None else " (held)") \
                if isinstance(value, (int, float)) else "not in camera.json"
            print(f"warning: camera {camera_id} has a rolling shutter (readout {said}): what is exported of it is "
                  f"its lens; its images' poses are those of their middle lines, and a line read dt = (line - "
                  f"middle) / lines x readout later saw the scene from X0 + v dt (the velocities v: "
                  f"rolling_shutter.csv)", file=sys.stderr)
    if not out:
        raise BlockError(path, "no frame camera to export")
    return out


def pick_camera(cameras: dict[str, Calibration], camera_id: str | None) -> Calibration:
    if camera_id is None:
        if len(cameras) > 1:
            raise UsageError(f"the block has {len(cameras)} cameras ({', '.join(cameras)}): choose one with --camera")
        return next(iter(cameras.values()))
    if camera_id not in cameras:
        raise UsageError(f"--camera {camera_id}: no such camera (the block has: {', '.join(cameras)})")
    return cameras[camera_id]


def maps_of(cal: Calibration):
    """:func:`undistortion_maps`, saying how far it is: a line at least every 2 s with the share done and the
    time left, measured as it goes (a WAP model on a 12-megapixel frame takes from half a minute to minutes)."""
    import time
    if cal.ap.spec == "none":
        progress(f"camera {cal.camera_id}: AP model none, no distortion to invert; mapping the image to the ideal "
                 f"camera ...")
    else:
        progress(f"camera {cal.camera_id}: inverting its {cal.ap.spec} distortion on nodes every 4 px ...")
    start = time.perf_counter()
    printed = [start]               # when the last line was printed
    stage_began: dict[str, float] = {}
    called = [start]                # when the last band ended: the next stage begins there

    def advance(stage: str, share: float) -> None:
        now = time.perf_counter()
        began = stage_began.setdefault(stage, called[0])
        called[0] = now
        if now - printed[0] >= 1.5 and share < 1.0:
            left = (now - began) * (1.0 - share) / share
            progress(f"camera {cal.camera_id}: {100 * share:.0f} % of the {stage} in {now - began:.0f} s, "
                     f"about {left:.0f} s left")
            printed[0] = now

    maps = undistortion_maps(cal, progress=advance)
    progress(f"camera {cal.camera_id}: undistortion maps in {time.perf_counter() - start:.1f} s")
    return maps


def models(option: str, allowed) -> tuple[str, ...]:
    if option == "auto":
        return tuple(allowed)
    if option not in allowed:
        raise UsageError(f"--opencv-model {option}: not one of auto, {', '.join(allowed)}")
    return (option,)


def warn_extrapolated(cal: Calibration) -> str:
    """Print the camera's extrapolation warning (camera.json ``extrapolation``) and return it for the export to
    write ("" when its correction is not extrapolated)."""
    if cal.extrapolation_warning:
        print(f"warning: {cal.extrapolation_warning}", file=sys.stderr)
    return cal.extrapolation_warning


def report_fit(camera_id, fitted, tolerance_px) -> None:
    progress(f"camera {camera_id}: OpenCV {fitted.model}, misfit to selfcal's model {fitted.misfit_rms_px:.4f} px "
             f"rms, {fitted.misfit_max_px:.4f} px max over the image")
    if fitted.misfit_max_px > tolerance_px:
        print(f"warning: camera {camera_id}: no OpenCV model reproduces selfcal's within {tolerance_px:g} px; "
              f"'selfcal export undistort-map' or 'selfcal undistort' are exact", file=sys.stderr)


#: how each tool is named in messages
TOOL_NAMES = {"opencv": "OpenCV", "metashape": "Metashape", "opensfm": "OpenSfM", "kalibr": "Kalibr"}


def tool_options(parser, tool: str, option: str = "--model") -> None:
    """--camera, the tool's model (auto or a name) and --tolerance-px: every export that fits a tool's model."""
    known = [m for t, m in MODELS if t == tool]
    if tool in LENS_MODELS:
        frame, fisheye = LENS_MODELS[tool]
        auto = (f"auto (chosen from the lens: {frame} for a frame lens; {fisheye} for a fisheye, that is a field "
                f"of view of {FISHEYE_FIELD_DEG:g} deg or more across the diagonal, or {frame} missing selfcal's "
                f"model by more than {FRAME_MODEL_FAILS_PX:g} px where {fisheye} misses by at most half as much)")
    else:
        auto = f"auto (the first of {', '.join(FAMILIES[tool])} within --tolerance-px, else the closest)"
    parser.add_argument("--camera", metavar="ID", help="camera to export (needed when the block has several)")
    parser.add_argument(option, default="auto", metavar="MODEL", dest="tool_model",
                        help=f"{TOOL_NAMES[tool]} camera model: {auto} or one of {', '.join(known)}")
    parser.add_argument("--tolerance-px", type=number(0.0, low_open=True), default=0.01,
                        help=f"largest misfit of the {TOOL_NAMES[tool]} model accepted by 'auto' and without a "
                             f"warning (default 0.01 px)")
    parser.set_defaults(tool_model_option=option)


def fit_tool(cal: Calibration, tool: str, option: str, tolerance_px: float, option_name: str = "--model"):
    """The tool's model fitted to ``cal`` (``option``: auto or a model name), its misfit printed and warned."""
    known = [m for t, m in MODELS if t == tool]
    if option != "auto" and option not in known:
        raise UsageError(f"{option_name} {option}: {TOOL_NAMES[tool]} has no such camera model (known: auto, "
                         f"{', '.join(known)})")
    if option == "auto" and tool in LENS_MODELS:
        choice = fit_for_lens(cal, tool)
        progress(f"camera {cal.camera_id}: {TOOL_NAMES[tool]} {choice.fitted.model.name}, {lens_reason(tool, choice)}; "
                 f"{option_name} NAME forces one")
        fitted = choice.fitted
    else:
        fitted = fit_best(cal, tool, None if option == "auto" else (option,), tolerance_px)
    progress(f"camera {cal.camera_id}: {TOOL_NAMES[tool]} {fitted.model.name}, misfit to selfcal's model "
             f"{fitted.misfit_rms_px:.4f} px rms, {fitted.misfit_max_px:.4f} px max over the image")
    if fitted.misfit_max_px > tolerance_px:
        print(f"warning: camera {cal.camera_id}: {TOOL_NAMES[tool]}'s {fitted.model.name} model does not reproduce "
              f"selfcal's within {tolerance_px:g} px; 'selfcal export undistort-map' or 'selfcal undistort' are "
              f"exact", file=sys.stderr)
    return fitted


def lens_reason(tool: str, choice: LensChoice) -> str:
    """Why :func:`fit_for_lens` chose its model, in words."""
    frame, fisheye = LENS_MODELS[tool]
    field = f"{choice.field_of_view_deg:.1f} deg across the diagonal"
    if choice.lens == "fisheye" and choice.by == "field":
        return f"chosen from the lens: a fisheye ({field}, {FISHEYE_FIELD_DEG:g} deg or more)"
    if choice.lens == "fisheye":
        return (f"chosen from the lens: a fisheye ({field}, but {frame} misses selfcal's model by "
                f"{choice.frame_misfit_max_px:.3f} px, more than {FRAME_MODEL_FAILS_PX:g} px, and {fisheye} by "
                f"{choice.fisheye_misfit_max_px:.3f} px)")
    why = f"chosen from the lens: a frame lens ({field}, below the {FISHEYE_FIELD_DEG:g} deg of a fisheye"
    if choice.fisheye_misfit_max_px is not None:
        why += (f"; {fisheye} misses selfcal's model by {choice.fisheye_misfit_max_px:.3f} px, not half of "
                f"{frame}'s {choice.frame_misfit_max_px:.3f} px")
    return why + ")"


def fitted_covariance(cal: Calibration, fitted):
    """Covariance of the fitted parameters (propagated from camera.json's), or None with a note when the
    results folder has none (written by a selfcal without it)."""
    if cal.covariance is None:
        print(f"camera {cal.camera_id}: camera.json has no covariance; the export carries no sigma",
              file=sys.stderr)
        return None
    return propagate(fitted, cal.covariance)


def tool_calibration(args, tool: str, with_covariance: bool = False):
    """The steps every export of a camera to another tool shares: the camera of ``--camera``, the tool's model
    fitted to it (misfit printed and warned, :func:`fit_tool`) and, ``with_covariance``, the fitted parameters'
    covariance (:func:`fitted_covariance`); as the :class:`~selfcal.io.calibration_files.ToolCalibration` its
    writer takes."""
    from ..io.calibration_files import ToolCalibration
    cal = pick_camera(calibrations(args.results), args.camera)
    fitted = fit_tool(cal, tool, args.tool_model, args.tolerance_px, args.tool_model_option)
    covariance = fitted_covariance(cal, fitted) if with_covariance else None
    return ToolCalibration(tool, fitted.model.name, fitted.as_dict(), cal.width_px, cal.height_px,
                           fitted.names if covariance is not None else (), covariance, cal.camera_id,
                           warn_extrapolated(cal))
