"""Vendor RPC files as :class:`selfcal.sensors.rpc.RpcModel` (the ground-to-image model only).

Formats, found by :func:`read_rpc` from the content:

* **DIMAP v2 RPC** (Pleiades, SPOT 6/7: ``RPC_*.XML``, root ``Dimap_Document``):
  ``Rational_Function_Model/Global_RFM``; the coefficients ``LINE_NUM_COEFF_1`` .. ``_20``,
  ``LINE_DEN_COEFF_*``, ``SAMP_NUM_COEFF_*``, ``SAMP_DEN_COEFF_*`` of ``Inverse_Model`` (ground to
  image; the ``Direct_Model`` is ignored), offsets and scales (``LONG_OFF``, ``LONG_SCALE``, ``LAT_OFF``,
  ..., ``LINE_OFF``, ``SAMP_SCALE``) in ``RFM_Validity``. Image coordinates are 1-based at pixel
  centres (the validity domain starts at row 1, col 1): ``pixel_origin`` 1.
* **DIMAP v1 product** (``PHRDIMAP_*.XML``, root ``PHR_Dimap_Document``): ``Global_RFM`` with
  ``Inverse_Model/F_ROW`` and ``F_COL``, each 40 numbers (20 numerator then 20 denominator
  coefficients, RPC00B order), and ``RFM_Validity/{Lon,Lat,Alt,Row,Col}`` with ``A`` the scale and ``B``
  the offset. ``pixel_origin`` is ``Product_Frame/PIXEL_ORIGIN`` (1 when absent), plus 0.5 when
  ``RASTER_CS_TYPE`` is ``CELL`` (coordinates of pixel corners).
* **OSSIM keyword list** (``*.geom``): ``line_off:``, ``samp_off:``, ``lat_off:``, ``long_off:``,
  ``height_off:``, the same ``_scale`` keys, ``line_num_coeff_00`` .. ``_19``, ``line_den_coeff_*``,
  ``samp_num_coeff_*``, ``samp_den_coeff_*``; ``polynomial_format`` must be ``B`` (RPC00B) when
  given. OSSIM's image coordinates are 0-based at pixel centres: ``pixel_origin`` 0.
* **GDAL's formats** (:mod:`selfcal.io.rpc_gdal`): a DigitalGlobe / GDAL ``.RPB``, the ``RPB`` block of a
  DigitalGlobe / Maxar XML (root ``isd``), a ``_RPC.TXT``, a GeoTIFF's RPC tags and a NITF's RPC00B TRE (both
  through rasterio). All five are 0-based at pixel centres: ``pixel_origin`` 0.

:func:`read_rpc` is the one entry point: a block's ``sensor_file`` of an ``rpc`` camera, and every other reader of
an RPC in selfcal, go through it.

Errors are :class:`~selfcal.errors.BlockError` naming the file and the missing or invalid key.
"""
from __future__ import annotations

import os

import numpy as np

from ..errors import BlockError
from .text import read_text
from ..sensors.rpc import RpcModel
from .xmlfile import xml_root

__all__ = ["read_rpc", "read_dimap_rpc", "read_ossim_geom_rpc", "DIMAP_PIXEL_ORIGIN", "OSSIM_PIXEL_ORIGIN"]

#: image coordinate of the first pixel's centre in DIMAP RPC files and in OSSIM keyword lists
DIMAP_PIXEL_ORIGIN = 1.0
OSSIM_PIXEL_ORIGIN = 0.0

_POLYNOMIALS = ("line_num", "line_den", "samp_num", "samp_den")
_NORMALISATION = ("line_off", "line_scale", "samp_off", "samp_scale", "lat_off", "lat_scale",
                  "long_off", "long_scale", "height_off", "height_scale")


def read_rpc(path: str | os.PathLike) -> RpcModel:
    """The RPC of a DIMAP XML file (v2 ``RPC_*.XML`` or v1 ``PHRDIMAP_*.XML``), an OSSIM ``.geom``, a ``.RPB``,
    a DigitalGlobe XML's RPB block, a ``_RPC.TXT``, a GeoTIFF's RPC tags or a NITF's RPC00B TRE, found from the
    content."""
    from . import rpc_gdal
    path = str(path)
    try:
        with open(path, "rb") as handle:
            head = handle.read(512).removeprefix(b"\xef\xbb\xbf").lstrip()
    except OSError as exc:
        raise BlockError(path, f"cannot read the RPC file: {exc.strerror}") from None
    if rpc_gdal.is_tiff(head):
        return rpc_gdal.read_raster_rpc(path, "GeoTIFF")
    if rpc_gdal.is_nitf(head):
        return rpc_gdal.read_raster_rpc(path, "NITF")
    if head.startswith(b"<"):
        if b"<isd>" in head or b"<isd " in head:
            return rpc_gdal.read_dg_xml_rpc(path)
        return read_dimap_rpc(path)
    if rpc_gdal.is_rpb(path, head):
        return rpc_gdal.read_rpb(path)
    if rpc_gdal.is_rpc_txt(path, head):
        return rpc_gdal.read_rpc_txt(path)
    if path.lower().endswith(".geom") or b":" in head.split(b"\n", 1)[0]:
        return read_ossim_geom_rpc(path)
    raise BlockError(path, "not an RPC file: neither DIMAP XML, DigitalGlobe XML, .RPB, _RPC.TXT, GeoTIFF, NITF "
                           "nor an OSSIM .geom keyword list")


# --- DIMAP -----------------------------------------------------------------------------------------

def read_dimap_rpc(path: str | os.PathLike) -> RpcModel:
    """The inverse (ground-to-image) RPC of a DIMAP v2 RPC file or of a DIMAP v1 product file."""
    path = str(path)
    root = xml_root(path, "RPC file")
    rfm = root.find(".//Global_RFM")
    if rfm is None:
        raise BlockError(path, "no Global_RFM element: not a DIMAP file with a rational function model")
    if rfm.find("Inverse_Model/F_ROW") is not None or rfm.find("Inverse_Model/F_COL") is not None:
        fields = _dimap_v1_fields(path, rfm)
        pixel_origin = _dimap_pixel_origin(path, root)
    else:
        fields = _dimap_v2_fields(path, rfm)
        pixel_origin = DIMAP_PIXEL_ORIGIN
    return _model(path, fields, pixel_origin)


def _text(path: str, node, key: str, where: str) -> str:
    found = node.find(key)
    if found is None or found.text is None or not found.text.strip():
        raise BlockError(path, f"missing element {where}/{key}")
    return found.text


def _numbers(path: str, node, key: str, where: str, count: int | None = None) -> np.ndarray:
    try:
        values = np.array(_text(path, node, key, where).split(), float)
    except ValueError:
        raise BlockError(path, f"{where}/{key} must be numbers") from None
    if count is not None and len(values) != count:
        raise BlockError(path, f"{where}/{key} must hold {count} numbers, found {len(values)}")
    if not np.all(np.isfinite(values)):
        raise BlockError(path, f"{where}/{key} must be finite")
    return values


def _dimap_v2_fields(path: str, rfm) -> dict:
    inverse = rfm.find("Inverse_Model")
    if inverse is None:
        raise BlockError(path, "missing element Global_RFM/Inverse_Model (the ground-to-image coefficients)")
    fields = {}
    for name in _POLYNOMIALS:
        fields[name] = np.array([_numbers(path, inverse, f"{name.upper()}_COEFF_{k}", "Global_RFM/Inverse_Model", 1)[0]
                                 for k in range(1, 21)])
    validity = rfm.find("RFM_Validity")
    if validity is None:
        raise BlockError(path, "missing element Global_RFM/RFM_Validity (offsets and scales)")
    for name in _NORMALISATION:
        fields[name] = _numbers(path, validity, name.upper(), "Global_RFM/RFM_Validity", 1)[0]
    return fields


#: DIMAP v1 RFM_Validity element of each normalised coordinate (A scale, B offset)
_V1_NORMALISATION = {"long": "Lon", "lat": "Lat", "height": "Alt", "line": "Row", "samp": "Col"}


def _dimap_v1_fields(path: str, rfm) -> dict:
    fields = {}
    for name, key in (("line", "F_ROW"), ("samp", "F_COL")):
        values = _numbers(path, rfm, f"Inverse_Model/{key}", "Global_RFM", 40)
        fields[f"{name}_num"], fields[f"{name}_den"] = values[:20], values[20:]
    for name, key in _V1_NORMALISATION.items():
        fields[f"{name}_scale"] = _numbers(path, rfm, f"RFM_Validity/{key}/A", "Global_RFM", 1)[0]
        fields[f"{name}_off"] = _numbers(path, rfm, f"RFM_Validity/{key}/B", "Global_RFM", 1)[0]
    return fields


def _dimap_pixel_origin(path: str, root) -> float:
    """Product_Frame/PIXEL_ORIGIN (1 when absent), + 0.5 for RASTER_CS_TYPE CELL (pixel corners)."""
    frame = root.find(".//Product_Frame")
    origin, cs_type = DIMAP_PIXEL_ORIGIN, "POINT"
    if frame is not None:
        if frame.find("PIXEL_ORIGIN") is not None:
            origin = _numbers(path, frame, "PIXEL_ORIGIN", "Product_Frame", 1)[0]
        if frame.find("RASTER_CS_TYPE") is not None:
            cs_type = _text(path, frame, "RASTER_CS_TYPE", "Product_Frame").strip().upper()
    if cs_type not in ("POINT", "CELL"):
        raise BlockError(path, f"Product_Frame/RASTER_CS_TYPE must be POINT or CELL, not {cs_type!r}")
    return float(origin) + (0.5 if cs_type == "CELL" else 0.0)


# --- OSSIM keyword lists ---------------------------------------------------------------------------

def read_ossim_geom_rpc(path: str | os.PathLike) -> RpcModel:
    """The RPC of an OSSIM keyword list (``key:  value`` lines, as ossim writes ``*.geom``)."""
    path = str(path)
    lines = read_text(path, "keyword list").splitlines()
    entries: dict[str, tuple[str, int]] = {}
    for number, line in enumerate(lines, start=1):
        if not line.strip() or line.lstrip().startswith("//"):
            continue
        key, sep, value = line.partition(":")
        if not sep:
            raise BlockError(path, f"expected 'key: value', found {line.strip()[:60]!r}", line=number)
        entries[key.strip()] = (value.strip(), number)
    if "polynomial_format" in entries and entries["polynomial_format"][0].upper() != "B":
        value, number = entries["polynomial_format"]
        raise BlockError(path, f"polynomial_format must be B (RPC00B), not {value!r}", line=number)

    def number_of(key: str) -> float:
        if key not in entries:
            raise BlockError(path, f"missing key {key}")
        value, number = entries[key]
        try:
            result = float(value)
        except ValueError:
            raise BlockError(path, f"key {key} must be a number, not {value!r}", line=number) from None
        if not np.isfinite(result):
            raise BlockError(path, f"key {key} must be finite", line=number)
        return result

    fields: dict[str, float | np.ndarray] = {name: number_of(name) for name in _NORMALISATION}
    for name in _POLYNOMIALS:
        fields[name] = np.array([number_of(f"{name}_coeff_{k:02d}") for k in range(20)])
    return _model(path, fields, OSSIM_PIXEL_ORIGIN)


def _model(path: str, fields: dict, pixel_origin: float) -> RpcModel:
    try:
        return RpcModel(**fields, pixel_origin=pixel_origin)
    except ValueError as exc:          # a zero scale: the model's own check, located in the file
        raise BlockError(path, str(exc)) from None
