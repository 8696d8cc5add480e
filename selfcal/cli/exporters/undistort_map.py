"""``selfcal export undistort-map``: map_x, map_y for cv2.remap and the ideal camera matrix (.npz)."""
from __future__ import annotations

import argparse
import os

from ...io.opencv import write_undistortion_maps
from ...io.output import output_file
from ..calibrations import calibrations, maps_of, pick_camera
from ..outcome import finish, progress


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, metavar="FILE",
                        help="file to write (replaced; never inside RESULTS; missing folders are created)")
    parser.add_argument("--camera", metavar="ID", help="camera to export (needed when the block has several)")


def run(args: argparse.Namespace) -> int:
    args.out = output_file(args.out, (args.results,))
    cal = pick_camera(calibrations(args.results), args.camera)
    map_x, map_y, camera_matrix = maps_of(cal)
    progress(f"writing {args.out} ({(map_x.nbytes + map_y.nbytes) / 1e6:.0f} MB of maps) ...")
    write_undistortion_maps(args.out, map_x, map_y, camera_matrix, cal.camera_id)
    progress(f"camera {cal.camera_id}: undistortion maps {cal.width_px} x {cal.height_px} for cv2.remap; ideal "
             f"camera fx = fy = {camera_matrix[0, 0]:.3f} px, principal point ({camera_matrix[0, 2]:.3f}, "
             f"{camera_matrix[1, 2]:.3f}) (OpenCV convention)")
    line = f"wrote {args.out}"
    return finish(args, line, {"camera_id": cal.camera_id}, [os.path.abspath(args.out)])
