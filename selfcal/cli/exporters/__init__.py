"""``selfcal export FORMAT``: one module per format, each with ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``. A new format is one module and one line here."""
from . import colmap, colmap_workspace, opencv, rpc, undistort_map

#: format -> module
EXPORTERS = {
    "opencv": opencv,
    "colmap": colmap,
    "undistort-map": undistort_map,
    "rpc": rpc,
    "colmap-workspace": colmap_workspace,
}
