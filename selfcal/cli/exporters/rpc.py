"""``selfcal export rpc``: the RPC of one adjusted image as GDAL reads it (.RPB or _RPC.TXT beside the image)."""
from __future__ import annotations

import argparse
import os

import numpy as np

from ...errors import UsageError
from ...io import read_block
from ...io.output import output_file
from ...io.results import read_camera_json, read_results_table
from ...io.rpc_gdal import raster_size, write_geotiff_rpc, write_rpc_file
from ...workflows.export_rpc import adjusted_rpc, points_height_range
from ..outcome import finish, progress

#: --out name endings (any case) and what they write
_TIFF = (".tif", ".tiff")


def _heights(text: str):
    try:
        low, high = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected MIN,MAX in metres, found {text!r}") from None
    if not low < high:
        raise argparse.ArgumentTypeError(f"MIN must be below MAX, found {text!r}")
    return low, high


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--block", required=True, metavar="BLOCK",
                        help="the block folder RESULTS was adjusted from (its images' RPCs, vendor metadata or "
                             "telemetry; read, never modified)")
    parser.add_argument("--image", required=True, metavar="ID",
                        help="the image to export; several as ID,ID,... or all (the results' images), with {image} "
                             "in --out")
    parser.add_argument("--out", required=True, metavar="FILE",
                        help="file to write: NAME.RPB or NAME_RPC.TXT (0-based pixel centres, as GDAL reads them "
                             "beside NAME.tif), or NAME.tif: a GeoTIFF copy of --raster with the RPC in its tags "
                             "(replaced; never inside RESULTS or BLOCK); {image} in it is the image's id "
                             "(rpcs/{image}.RPB)")
    parser.add_argument("--raster", metavar="IMAGE",
                        help="with --out NAME.tif: the image's pixels (any raster GDAL reads; the full image, of the "
                             "image's size within 1 px: the RPC is in its pixels), copied with the RPC in its tags")
    parser.add_argument("--heights", type=_heights, metavar="MIN,MAX",
                        help="height range (m above the WGS 84 ellipsoid) of a fitted RPC; default: the image's own "
                             "RPC's, else the adjusted points' heights widened by 10%% (at least 100 m) each side")


def _images(option: str, owners: set, results: str) -> list[str]:
    """The image ids of --image (ID, ID,ID,... or all), each one of the results'."""
    ids = sorted(owners) if option == "all" else [i.strip() for i in option.split(",") if i.strip()]
    missing = [i for i in ids if i not in owners]
    if missing or not ids:
        which = "" if ids == missing[:1] and len(ids) == 1 else f" {', '.join(missing) or 'no image'}:"
        raise UsageError(f"--image {option}:{which} not an image of {results} (images.csv has: "
                         f"{', '.join(sorted(owners)[:20])})")
    return ids


def _report(result) -> str:
    if result.exact:
        return (f"image {result.image_id} ({result.sensor}): its RPC with the adjusted shift folded into LINE_OFF and "
                f"SAMP_OFF (exact)")
    fit, (lo, hi) = result.fit, result.heights_m
    return (f"image {result.image_id} ({result.sensor}): RPC fitted to the adjusted model on a "
            f"{'x'.join(map(str, result.grid))} grid over the image and {lo:.0f} .. {hi:.0f} m (Tao & Hu 2001): "
            f"misfit {fit.check_rms_px:.3g} px rms, {fit.check_max_px:.3g} px max on the check grid "
            f"({fit.n_check_points} points; {fit.fit_rms_px:.3g} / {fit.fit_max_px:.3g} px on the fit grid)")


def run(args: argparse.Namespace) -> int:
    output_file(args.out, (args.results, args.block, args.raster))
    name = os.path.basename(args.out).lower()
    if not name.endswith((".rpb", "_rpc.txt") + _TIFF):
        raise UsageError(f"--out {args.out}: the name must end in .RPB or _RPC.TXT, or .tif with --raster (the "
                         f"format comes from it)")
    if name.endswith(_TIFF) != (args.raster is not None):
        raise UsageError("--raster goes with --out NAME.tif (a GeoTIFF copy of the raster), and only with it")
    parameters = read_results_table(args.results, "parameters.csv")
    images = _images(args.image, {str(i) for i in read_results_table(args.results, "images.csv")["image_id"]},
                     args.results)
    if len(images) > 1 and ("{image}" not in args.out or args.raster is not None):
        raise UsageError(f"--image {args.image} names {len(images)} images: --out needs {{image}} in its name "
                         f"(e.g. rpcs/{{image}}.RPB), and --raster takes one image")
    if any(os.sep in i or i in (".", "..") for i in images):
        raise UsageError(f"--image {args.image}: an image id with {os.sep} cannot name a file")
    outs = {i: output_file(args.out.replace("{image}", i), (args.results, args.block, args.raster)) for i in images}
    block = read_block(args.block)
    cameras = read_camera_json(args.results).get("cameras", {})
    points = read_results_table(args.results, "points.csv")
    xyz = np.column_stack([points[c] for c in ("X", "Y", "Z")]) if {"X", "Y", "Z"} <= set(points) else np.zeros((0, 3))
    fallback = points_height_range(xyz)
    results = [adjusted_rpc(block, parameters, i, args.heights, fallback, cameras=cameras) for i in images]
    if args.raster is not None:
        rows, cols = raster_size(args.raster)
        result = results[0]
        if abs(rows - result.rows_px) > 1 or abs(cols - result.cols_px) > 1:
            raise UsageError(f"--raster {args.raster} is {cols} x {rows} px, image {result.image_id} "
                             f"{result.cols_px:.0f} x {result.rows_px:.0f} px: the RPC is in the full image's pixels "
                             f"(a crop would carry it wrongly; an rpc camera without width_px, height_px takes its "
                             f"size from its RPC)")
    for result in results:                       # every image computed before any file is written
        progress(_report(result))
    written = []
    for result in results:
        out = outs[result.image_id]
        if args.raster is None:
            write_rpc_file(result.model, out)
        else:
            write_geotiff_rpc(result.model, out, args.raster)
        written.append(os.path.abspath(out))
    return finish(args, f"wrote {', '.join(outs[r.image_id] for r in results)}",
                  {"images": [r.image_id for r in results]}, written)
