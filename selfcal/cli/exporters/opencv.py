"""``selfcal export opencv``: one camera as an OpenCV cv::FileStorage file (YAML, XML or JSON by extension)."""
from __future__ import annotations

import argparse
import os

import numpy as np

from ...calibration import OpenCVCamera
from ...io.opencv import write_opencv_file
from ...io.output import output_file
from ..calibrations import calibrations, fit_tool, fitted_covariance, pick_camera, tool_options, warn_extrapolated
from ..outcome import finish


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, metavar="FILE",
                        help="file to write: .yaml, .yml, .xml or .json selects the FileStorage format (replaced; "
                             "never inside RESULTS; missing folders are created)")
    tool_options(parser, "opencv", "--opencv-model")


def run(args: argparse.Namespace) -> int:
    args.out = output_file(args.out, (args.results,))
    cal = pick_camera(calibrations(args.results), args.camera)
    fitted = fit_tool(cal, "opencv", args.tool_model, args.tolerance_px,
                      args.tool_model_option)
    q = fitted.values
    camera = OpenCVCamera(fitted.model.name, np.array([[q[0], 0, q[2]], [0, q[1], q[3]], [0, 0, 1]]), q[4:].copy(),
                          fitted.misfit_rms_px, fitted.misfit_max_px, cal.width_px, cal.height_px)
    write_opencv_file(camera, args.out, source=f"selfcal {cal.ap.spec} calibration of camera {cal.camera_id}",
                      camera_id=cal.camera_id, covariance=fitted_covariance(cal, fitted),
                      warning=warn_extrapolated(cal))
    line = f"wrote {args.out}"
    return finish(args, line, {"camera_id": cal.camera_id, "model": fitted.model.name,
                               "misfit_rms_px": fitted.misfit_rms_px},
                  [os.path.abspath(args.out)])
