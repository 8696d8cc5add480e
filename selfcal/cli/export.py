"""Export the calibration of a results folder: OpenCV camera YAML, COLMAP cameras.txt, undistortion maps."""
from __future__ import annotations

import argparse
import os
import sys

from ..calibration import COLMAP_MODELS, OPENCV_MODELS, Calibration, colmap_parameters, fit_opencv, undistortion_maps
from ..errors import BlockError, UsageError
from ..io.colmap import write_cameras_txt
from ..io.opencv import write_opencv_yaml, write_undistortion_maps
from ..io.output import output_file
from ..io.results import read_camera_json
from .options import number as _number

FORMATS = ("opencv", "colmap", "undistort-map")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("format", choices=FORMATS,
                        help="opencv: cv::FileStorage YAML (camera matrix, distortion coefficients); colmap: "
                             "cameras.txt (OPENCV or FULL_OPENCV); undistort-map: .npz with map_x, map_y for "
                             "cv2.remap and the ideal camera matrix")
    parser.add_argument("results", metavar="RESULTS", help="results folder written by selfcal adjust")
    parser.add_argument("--out", required=True, metavar="FILE",
                        help="file to write (replaced; never inside RESULTS; missing folders are created)")
    parser.add_argument("--camera", metavar="ID", help="camera to export (needed when the block has several; "
                                                       "colmap exports all)")
    parser.add_argument("--opencv-model", default="auto", metavar="MODEL",
                        help=f"OpenCV distortion model: auto (the first of {', '.join(OPENCV_MODELS)} within "
                             f"--tolerance-px, else the closest) or one of them")
    parser.add_argument("--tolerance-px", type=_number(0.0, low_open=True), default=0.01,
                        help="largest misfit of the OpenCV model accepted by 'auto' (default 0.01 px)")


def calibrations(results: str) -> dict[str, Calibration]:
    """The frame cameras of a results folder's camera.json, by id."""
    cameras = read_camera_json(results).get("cameras", {})
    path = os.path.join(results, "camera.json")
    out = {}
    for camera_id, entry in cameras.items():
        if entry.get("model") != "frame":
            continue
        try:
            out[camera_id] = Calibration.from_camera_json(camera_id, entry)
        except (KeyError, TypeError, ValueError) as exc:
            raise BlockError(path, f"camera {camera_id}: cannot read its calibration ({exc})") from None
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
    """:func:`undistortion_maps`, saying that it is under way (half a minute for WAPs on 12 MP)."""
    print(f"camera {cal.camera_id}: inverting its {cal.ap.spec} distortion on nodes every 4 px "
          f"(about half a minute for a WAP model on a 12-megapixel frame) ...", file=sys.stderr)
    return undistortion_maps(cal)


def _models(option: str, allowed) -> tuple[str, ...]:
    if option == "auto":
        return tuple(allowed)
    if option not in allowed:
        raise UsageError(f"--opencv-model {option}: not one of auto, {', '.join(allowed)}")
    return (option,)


def _report(camera_id, fitted, tolerance_px) -> None:
    print(f"camera {camera_id}: OpenCV {fitted.model}, misfit to selfcal's model {fitted.misfit_rms_px:.4f} px "
          f"rms, {fitted.misfit_max_px:.4f} px max over the image", file=sys.stderr)
    if fitted.misfit_max_px > tolerance_px:
        print(f"warning: camera {camera_id}: no OpenCV model reproduces selfcal's within {tolerance_px:g} px; "
              f"'selfcal export undistort-map' or 'selfcal undistort' are exact", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    args.out = output_file(args.out, (args.results,))
    cameras = calibrations(args.results)
    if args.format == "opencv":
        cal = pick_camera(cameras, args.camera)
        fitted = fit_opencv(cal, _models(args.opencv_model, OPENCV_MODELS), args.tolerance_px)
        _report(cal.camera_id, fitted, args.tolerance_px)
        write_opencv_yaml(fitted, args.out, source=f"selfcal {cal.ap.spec} calibration of camera {cal.camera_id}")
    elif args.format == "colmap":
        chosen = cameras if args.camera is None else {args.camera: pick_camera(cameras, args.camera)}
        rows = []
        for number, (camera_id, cal) in enumerate(chosen.items(), start=1):
            fitted = fit_opencv(cal, _models(args.opencv_model, COLMAP_MODELS), args.tolerance_px)
            _report(camera_id, fitted, args.tolerance_px)
            model, params = colmap_parameters(fitted)
            rows.append((number, model, cal.width_px, cal.height_px, params))
            print(f"camera {camera_id} is COLMAP camera {number} ({model})", file=sys.stderr)
        write_cameras_txt(args.out, rows)
    else:
        cal = pick_camera(cameras, args.camera)
        map_x, map_y, camera_matrix = maps_of(cal)
        write_undistortion_maps(args.out, map_x, map_y, camera_matrix, cal.camera_id)
        print(f"camera {cal.camera_id}: undistortion maps {cal.width_px} x {cal.height_px} for cv2.remap; ideal "
              f"camera fx = fy = {camera_matrix[0, 0]:.3f} px, principal point ({camera_matrix[0, 2]:.3f}, "
              f"{camera_matrix[1, 2]:.3f}) (OpenCV convention)", file=sys.stderr)
    print(f"wrote {args.out}", file=sys.stderr)
    return 0
