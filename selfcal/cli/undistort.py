"""Resample images to the ideal (distortion-free) camera of a results folder, with OpenCV's remap."""
from __future__ import annotations

import argparse
import os

import numpy as np

from ..calibration import OpenCVCamera, undistort_image
from ..errors import BlockError
from ..io.atomic import atomic_folder
from ..io.images import check_file_name, read_image, write_image
from ..io.opencv import write_opencv_file
from ..io.output import output_folder
from .outcome import finish, progress
from .options import force_option
from .calibrations import calibrations, maps_of, pick_camera


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("results", metavar="RESULTS", help="results folder written by selfcal adjust")
    parser.add_argument("images", nargs="+", metavar="IMAGE", help="images taken with the camera")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="folder for the undistorted images (same names) and ideal_camera.yaml (replaced if "
                             "selfcal wrote it)")
    force_option(parser)
    parser.add_argument("--camera", metavar="ID", help="camera of the images (needed when the block has several)")


def run(args: argparse.Namespace) -> int:
    args.out = output_folder(args.out, (args.results, *args.images), args.force)
    for path in args.images:            # before any work: OpenCV never sees a name that is not UTF-8
        check_file_name(path)
    cal = pick_camera(calibrations(args.results), args.camera)
    names = [os.path.basename(p) for p in args.images]
    if len(set(names)) < len(names):
        raise BlockError(args.images[0], "two images have the same file name; they would overwrite each other")
    maps = None
    # one image in memory at a time; a bad one anywhere leaves no output folder (atomic). The maps are made once
    # the first image is read and of the camera's size: a file that is not an image, or an image of another
    # camera, is refused at once, not after the maps' work (seconds to minutes for a WAP model)
    with atomic_folder(args.out) as tmp:
        for k, (path, name) in enumerate(zip(args.images, names), start=1):
            image = read_image(path)
            if image.shape[:2] != (cal.height_px, cal.width_px):
                raise BlockError(path, f"is {image.shape[1]} x {image.shape[0]} px, camera {cal.camera_id} is "
                                       f"{cal.width_px} x {cal.height_px} px")
            if maps is None:
                maps = maps_of(cal)
            map_x, map_y, camera_matrix = maps
            write_image(os.path.join(tmp, name), undistort_image(image, map_x, map_y))
            progress(f"[{k}/{len(names)}] {name}")
        assert maps is not None                 # (argparse: one image at least)
        ideal = OpenCVCamera("none", maps[2], np.zeros(4), 0.0, 0.0, cal.width_px, cal.height_px)
        write_opencv_file(ideal, os.path.join(tmp, "ideal_camera.yaml"),
                          source=f"ideal camera of the undistorted images of camera {cal.camera_id}")
    return finish(args, f"{len(names)} images undistorted into {args.out} (camera {cal.camera_id}, {cal.ap.spec})",
                  {"n_images": len(names), "camera_id": cal.camera_id, "ap_model": cal.ap.spec},
                  [os.path.abspath(os.path.join(args.out, n)) for n in (*names, "ideal_camera.yaml")])
