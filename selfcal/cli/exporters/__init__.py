"""``selfcal export FORMAT``: one module per format, each with ``add_arguments(parser)`` and ``run(args) -> int``,
and its line here (the module's name and the one-line help): a new format is one module and one line. Only the
format a command line names is imported (``selfcal export --help`` loads none of them)."""
from __future__ import annotations

import importlib

#: format -> (module in selfcal.cli.exporters, help)
EXPORTERS = {
    "opencv": ("opencv",
        ("cv::FileStorage file of one camera (.yaml, .xml or .json: camera matrix, distortion coefficients, their "
         "sigma)")),
    "colmap": ("colmap", "cameras.txt of COLMAP (OPENCV or FULL_OPENCV); all cameras unless --camera"),
    "colmap-workspace": ("colmap_workspace",
        ("COLMAP dense workspace (images/ undistorted exactly for every AP model, sparse/ PINHOLE cameras, "
         "adjusted poses and tie points, stereo/ configuration) for patch_match_stereo, OpenMVS or Gaussian "
         "splatting")),
    "undistort-map": ("undistort_map",
        (".npz with map_x, map_y for cv2.remap and the ideal camera matrix (exact for every AP model)")),
    "rpc": ("rpc",
        ("the RPC of an adjusted image for GDAL (.RPB, _RPC.TXT or a GeoTIFF copy of --raster, by the name of "
         "--out): the vendor RPC with its shift bias folded in, or an RPC fitted to the adjusted model (affine "
         "bias; pushbroom, dimap, dg) with its misfit")),
    "metashape": ("metashape",
        ("Metashape calibration XML of one camera (f, cx, cy, b1, b2, k1-k4, p1, p2 and their covariance)")),
    "opensfm": ("opensfm", "OpenSfM / OpenDroneMap cameras.json of one camera (perspective, brown or fisheye)"),
    "kalibr": ("kalibr", "Kalibr camchain.yaml of one camera (pinhole, radtan or equidistant)"),
    "isis-cnet": ("isis_cnet", "the imported ISIS control network with the adjusted points and residuals (PVL or --binary)"),
}


def module(name: str):
    """The module of format ``name`` (imported now)."""
    return importlib.import_module(f"{__name__}.{EXPORTERS[name][0]}")
