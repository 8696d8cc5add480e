"""``selfcal import FORMAT``: one module per format, each with ``add_arguments(parser)`` and ``run(args) -> int``,
and its line here (the module's name and the one-line help): a new format is one module and one line. Only the
format a command line names is imported (``selfcal import --help`` loads none of them)."""
from __future__ import annotations

import importlib

#: format -> (module in selfcal.cli.importers, help)
IMPORTERS = {
    "colmap": ("colmap",
        ("a COLMAP sparse model folder (text or binary), ground control from OpenDroneMap's gcp_list.txt")),
    "bal": ("bal", "a Bundle Adjustment in the Large problem file (one camera per image, no datum)"),
    "isis": ("isis",
        ("an ISIS PVL control network (--images: the folder of the cube labels and their usgscsm/ALE ISDs)")),
    "patb": ("patb",
        ("PAT-B files as Metashape exports them (SRC: the .im, its stem or its folder; .con and .ori beside it): "
         "image coordinates in mm (x right, y up, from the principal point), control, orientations")),
    "opensfm": ("opensfm",
        ("an OpenSfM / OpenDroneMap reconstruction.json (SRC: the file or its folder) with its tracks.csv (a free "
         "network)")),
    "pix4d": ("pix4d",
        ("Pix4D's params folder (SRC: PROJECT/1_initial/params or the project): the BINGO tie points "
         "(*_tp_bingo.txt), calibrated internal (.cam) and external parameters; ground control from --gcp")),
    "metashape-markers": ("metashape_markers",
        ("Metashape markers XML (SRC: exported markers or a chunk's doc.xml; projections in px) with the reference"
         " CSV of their coordinates, added as control to the images of --block")),
    "gnss": ("gnss",
        ("camera GNSS positions from a folder of JPEGs (EXIF GPS, DJI XMP with RtkStd sigmas) or an ODM geo.txt, "
         "added to --block as [gnss] observations")),
    "calibration": ("calibration",
        ("a camera calibration (Metashape XML, OpenSfM cameras.json, OpenCV YAML/XML/JSON, Kalibr camchain.yaml) "
         "as a block camera's initial or fixed values")),
}


def module(name: str):
    """The module of format ``name`` (imported now)."""
    return importlib.import_module(f"{__name__}.{IMPORTERS[name][0]}")
