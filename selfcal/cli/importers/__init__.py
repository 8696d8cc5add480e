"""``selfcal import FORMAT``: one module per format, each with ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``. A new format is one module and one line here."""
from . import bal, calibration, colmap, gnss, isis, metashape_markers, opensfm, patb, pix4d

#: format -> module
IMPORTERS = {
    "colmap": colmap,
    "bal": bal,
    "isis": isis,
    "patb": patb,
    "opensfm": opensfm,
    "pix4d": pix4d,
    "metashape-markers": metashape_markers,
    "gnss": gnss,
    "calibration": calibration,
}
