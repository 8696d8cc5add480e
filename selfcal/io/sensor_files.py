"""Readers of the sensor descriptions that images name in images.csv (``sensor_file``, DESIGN.md §3a), by
camera model: one line per format family; the reader returns what the model's sensor binds (an RPC, an
image support data file)."""
from __future__ import annotations

import json
import os

from ..errors import BlockError
from .rpc import read_rpc

__all__ = ["SENSOR_FILE_READERS", "read_usgscsm"]


def read_usgscsm(path: str):
    """A usgscsm / ALE ISD, frame or line scanner by its ``name_model``. A frame ISD of a reduced ISIS cube
    takes the cube's AlphaCube from the ISIS label beside it (same name, ``.pvl``), as ISIS pairs them."""
    from .usgscsm import LINE_SCANNER_MODEL, read_usgscsm_isd
    from .usgscsm_frame import FRAME_MODEL, read_frame_isd
    try:
        with open(path, encoding="utf-8") as handle:
            model = json.load(handle).get("name_model")
    except (OSError, json.JSONDecodeError, AttributeError) as exc:
        raise BlockError(path, f"not a usgscsm ISD: {exc}") from None
    if model == LINE_SCANNER_MODEL:
        return read_usgscsm_isd(path)
    if model == FRAME_MODEL:
        label = os.path.splitext(path)[0] + ".pvl"
        alpha = None
        if os.path.isfile(label):
            from .isis import read_cube_label
            alpha = read_cube_label(label).alpha_cube
        return read_frame_isd(path, alpha)
    raise BlockError(path, f"name_model {model!r} is neither {FRAME_MODEL} nor {LINE_SCANNER_MODEL}", None,
                     "name_model")


#: camera model -> reader of an image's sensor_file
SENSOR_FILE_READERS = {
    "rpc": read_rpc,
    "usgscsm": read_usgscsm,
}
