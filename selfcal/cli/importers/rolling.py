"""The importers' options of a rolling shutter (``import gnss|colmap|pix4d --rolling-shutter``): the readout's prior
from the camera model, and for the tools whose files hold no exposure times (COLMAP, Pix4D) the times from the
images' EXIF (``--images``)."""
from __future__ import annotations

import argparse
import os

from ...errors import BlockError, UsageError
from ..options import number
from ..outcome import progress


def add_arguments(parser: argparse.ArgumentParser, images: bool) -> None:
    """``--rolling-shutter`` and ``--readout-ms``; with ``images`` also ``--images DIR``."""
    parser.add_argument("--rolling-shutter", action="store_true",
                        help="the cameras read their sensors line by line: block.toml gets shutter = \"rolling\" "
                             "with the readout of the images' camera model (EXIF Make and Model in OpenDroneMap's "
                             "table) as its prior, or 30 +- 30 ms for a model the table does not know")
    parser.add_argument("--readout-ms", type=number(0.0, 1000.0), metavar="MS",
                        help="with --rolling-shutter: this readout as every camera's prior (sigma 5 ms) instead of "
                             "the table's")
    if images:
        parser.add_argument("--images", metavar="DIR",
                            help="with --rolling-shutter: the folder of the images (JPEG): their EXIF exposure "
                                 "times (the rolling-shutter model needs them) and camera model (the readout's "
                                 "prior)")


def check(args: argparse.Namespace, tool: str | None = None) -> None:
    """The options that only a rolling shutter takes are errors without ``--rolling-shutter``; ``tool``: the files
    being imported hold no exposure times, so ``--rolling-shutter`` needs ``--images``."""
    from ...convert.rolling import NEEDS_TIMES
    for given, name in ((args.readout_ms is not None, "--readout-ms"),
                        (getattr(args, "images", None) is not None, "--images")):
        if given and not args.rolling_shutter:
            raise UsageError(f"{name} is for a rolling shutter: give --rolling-shutter with it")
    images = getattr(args, "images", None)
    if images is not None and not os.path.isdir(images):      # before the import's work, with exit code 2
        raise BlockError(images, "not a folder (--images: the folder of the images' JPEGs)")
    if tool is not None and args.rolling_shutter and args.images is None:
        raise UsageError(f"--rolling-shutter: {NEEDS_TIMES}, and {tool}'s files hold none: give --images DIR (the "
                         f"images' folder: their EXIF times and camera model), or import without --rolling-shutter "
                         f"and then the images' GNSS and times with 'selfcal import gnss DIR --block BLOCK "
                         f"--rolling-shutter --out BLOCK2'")


def rolling_block(args: argparse.Namespace, block, camera_names: dict | None = None):
    """``block`` (imported from files that hold no exposure times; :func:`check` saw ``--images``) with
    rolling-shutter cameras, the images' times and strips from ``--images``; ``camera_names``: image id -> the tool's name of its camera
    (Pix4D's ``FC6310_8.8_5472x3648``), the model where the images' EXIF names none."""
    from ...convert.gnss import exif_cameras
    from ...convert.rolling import pix4d_camera_model, with_exposure_times, with_rolling_shutter
    from ...io.exif import image_files, read_image_gnss
    if not args.rolling_shutter:
        return block
    files = image_files(args.images)
    if not files:
        raise BlockError(args.images, "no JPEG (.jpg, .jpeg) in the folder")
    records = [read_image_gnss(f) for f in files]
    try:
        block, notes = with_exposure_times(block, records)
    except ValueError as exc:
        raise BlockError(args.images, str(exc)) from None
    cameras = exif_cameras(block, records)
    for image_id, name in (camera_names or {}).items():
        if image_id not in cameras:
            model, width, height = pix4d_camera_model(name)
            cameras[image_id] = (None, model, width, height)
    block, more = with_rolling_shutter(block, cameras, args.readout_ms)
    for note in notes + more:
        progress(note)
    return block
