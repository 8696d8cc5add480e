"""Readers of the sensor descriptions that images name in images.csv (``sensor_file``, DESIGN.md §3a), by
camera model: one line per format family; the reader returns what the model's sensor binds (an RPC, an
image support data file)."""
from __future__ import annotations

import os
from typing import TYPE_CHECKING

from ..errors import BlockError
from .text import read_json
from .rpc import read_rpc

if TYPE_CHECKING:
    from .dg import DgSensor
    from .dimap import DimapSensor
    from .spot import Spot5Sensor
    from .usgscsm import LineScanIsd
    from .usgscsm_frame import FrameIsd

__all__ = ["SENSOR_FILE_READERS", "read_usgscsm", "read_vendor_line"]


def read_usgscsm(path: str) -> FrameIsd | LineScanIsd:
    """A usgscsm / ALE ISD, frame or line scanner by its ``name_model``. A frame ISD of a reduced ISIS cube
    takes the cube's AlphaCube from the ISIS label beside it (same name, ``.pvl``), as ISIS pairs them."""
    from .usgscsm import LINE_SCANNER_MODEL, read_usgscsm_isd
    from .usgscsm_frame import FRAME_MODEL, read_frame_isd
    isd = read_json(path, "ISD")
    if not isinstance(isd, dict):
        raise BlockError(path, "not a usgscsm ISD (a JSON object is expected)")
    model = isd.get("name_model")
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


def _sniff(path: str) -> str:
    """The vendor format of a line camera's metadata file from its first 4 kB: "dg", "dimap" (Pleiades) or "spot5"."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(4096)
    except OSError as exc:
        raise BlockError(path, f"cannot read the sensor file: {exc.strerror}") from None
    if b"<isd>" in head or b"<isd " in head:
        return "dg"
    if b"PHR_Dimap_Document" in head:
        return "dimap"
    if b"Dimap_Document" in head:
        return "spot5"
    raise BlockError(path, "not a vendor sensor file: neither DigitalGlobe/Maxar XML (root isd) nor DIMAP "
                           "(PHR_Dimap_Document or SPOT Dimap_Document)")


def read_vendor_line(path: str) -> DgSensor | DimapSensor | Spot5Sensor:
    """The physical model of a vendor line camera, the format found from the content: a DigitalGlobe / Maxar XML
    (:class:`~selfcal.io.dg.DgSensor`), a Pleiades DIMAP (:class:`~selfcal.io.dimap.DimapSensor`) or a SPOT 5
    DIMAP (:class:`~selfcal.io.spot.Spot5Sensor`)."""
    kind = _sniff(str(path))
    if kind == "dg":
        from .dg import read_dg
        return read_dg(path)
    if kind == "dimap":
        from .dimap import read_dimap_sensor
        return read_dimap_sensor(path)
    from .spot import read_spot5
    return read_spot5(path)


_NAMES = {"dg": 'a DigitalGlobe/Maxar XML (model = "dg")', "dimap": 'a Pleiades DIMAP (model = "dimap")',
          "spot5": 'a SPOT 5 DIMAP (model = "dimap")'}


def _read_as(expected: tuple[str, ...], model: str, hint: str):
    def read(path: str):
        kind = _sniff(str(path))
        if kind not in expected:
            raise BlockError(path, f"a {model} camera's sensor_file is {hint}; this is {_NAMES[kind]}")
        return read_vendor_line(path)
    read.__doc__ = f"{hint} (:func:`read_vendor_line`); another vendor's file is an error naming its model."
    return read


#: camera model -> reader of an image's sensor_file
SENSOR_FILE_READERS = {
    "rpc": read_rpc,
    "usgscsm": read_usgscsm,
    "dimap": _read_as(("dimap", "spot5"), "dimap", "a Pleiades or SPOT 5 DIMAP file"),
    "dg": _read_as(("dg",), "dg", "a DigitalGlobe / Maxar XML file"),
}
