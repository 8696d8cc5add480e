"""``selfcal export FORMAT``: one module per format, each with ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``. A new format is one module and one line here."""
from . import colmap, colmap_workspace, kalibr, metashape, opencv, opensfm, rpc, undistort_map

#: format -> module
EXPORTERS = {
    "opencv": opencv,
    "colmap": colmap,
    "colmap-workspace": colmap_workspace,
    "undistort-map": undistort_map,
    "rpc": rpc,
    "metashape": metashape,
    "opensfm": opensfm,
    "kalibr": kalibr,
}
