"""The RPC formats of GDAL's world as :class:`selfcal.sensors.rpc.RpcModel`: DigitalGlobe / GDAL ``.RPB``
keyword files, the RPB block of a DigitalGlobe XML, ``_RPC.TXT`` (GeoEye / GDAL), a GeoTIFF's RPC tags and a
NITF's RPC00B TRE (both through rasterio); writers for ``.RPB`` and ``_RPC.TXT`` (full precision), a GeoTIFF copy
of a raster with the RPC tags, and the rasterio object.

Pixel convention: all five put the centre of the first pixel at (0, 0) (NITF RPC00B; GDAL's RPC transformer
adds 0.5 to reach its own corner-based pixels, ``gdal_rpc.cpp`` ``RPCTransformPoint``: "RPCs are using the
center of upper left pixel = 0,0 convention"): ``pixel_origin`` :data:`GDAL_PIXEL_ORIGIN` = 0, i.e. selfcal's
(row, col) = (line, samp) + 0.5. The DigitalGlobe XML's RPB agrees with its rigorous model to 0.2 px only in
this convention (tests/test_dg.py); 0.5 px off in both coordinates otherwise.

* ``.RPB`` (``BEGIN_GROUP = IMAGE`` ... ``END_GROUP = IMAGE``, ``END;``): ``lineOffset``, ``sampOffset``,
  ``latOffset``, ``longOffset``, ``heightOffset``, the ``...Scale`` keys and ``lineNumCoef`` ... ``sampDenCoef``,
  each ``( c1, ..., c20 );``. Keys are matched without regard to case, as GDAL does.
* DigitalGlobe XML ``isd/RPB/IMAGE``: ``LINEOFFSET`` ... ``HEIGHTSCALE`` and ``LINENUMCOEFList/LINENUMCOEF`` (20
  numbers) and the three other lists.
* ``_RPC.TXT``: ``LINE_OFF: 11469.50 pixels`` lines (a unit may follow the number), ``LINE_NUM_COEFF_1`` ..
  ``_20`` and so on; ``ERR_BIAS``, ``ERR_RAND`` optional.
* GeoTIFF: the ``RPCCoefficientTag`` as rasterio's ``dataset.rpcs`` gives it (GDAL also picks up an ``.RPB`` or
  ``_RPC.TXT`` beside the image); written as a copy of a raster with the tags (:func:`write_geotiff_rpc`).
* NITF (``NITF02.10`` or NSIF header): the ``RPC00B`` image-subheader TRE as rasterio's ``dataset.rpcs`` gives it
  (what GDAL's NITF driver makes of the file's RPC TREs). The TRE's fields are fixed-width text: 7 significant digits for the
  coefficients (``+9.318045E-3``), whole pixels for LINE_OFF / SAMP_OFF, 4 decimals for the latitude and longitude
  offsets, whole metres for the height offset: a NITF carries less than the other formats, so selfcal reads it but
  writes ``.RPB`` / ``_RPC.TXT`` / GeoTIFF.

The coefficient order is RPC00B's. ``SpecId``/``SPECID`` ``RPC00A`` (the older order, with PLH before the
squares) is reordered to RPC00B; any other value is read as RPC00B, as GDAL and ASP do (dg_example1.xml says
RPC00Y and is RPC00B: its rigorous model agrees to 0.2 px).
"""
from __future__ import annotations

import os
import re
from typing import TYPE_CHECKING

import numpy as np

from ..errors import BlockError, UsageError
from .atomic import atomic_write
from .text import read_text
from ..sensors.rpc import RpcModel

if TYPE_CHECKING:
    from rasterio.rpc import RPC

__all__ = ["GDAL_PIXEL_ORIGIN", "read_rpb", "read_dg_xml_rpc", "read_rpc_txt", "read_geotiff_rpc", "write_rpb",
           "write_rpc_txt", "rasterio_rpcs", "RPC00A_TO_RPC00B", "is_rpb", "is_rpc_txt", "is_tiff", "is_nitf",
           "write_rpc_file", "RPC_FILE_SUFFIXES", "write_geotiff_rpc", "raster_size",
           "read_raster_rpc"]

#: image coordinate of the first pixel's centre in .RPB, _RPC.TXT, GeoTIFF RPC tags and DigitalGlobe XML
GDAL_PIXEL_ORIGIN = 0.0
#: RPC00A coefficient k goes to RPC00B position RPC00A_TO_RPC00B[k] (A: 1 L P H LP LH PH PLH L² P² H² ...)
RPC00A_TO_RPC00B = (0, 1, 2, 3, 4, 5, 6, 10, 7, 8, 9, 11, 12, 13, 14, 15, 16, 17, 18, 19)

_POLYNOMIALS = ("line_num", "line_den", "samp_num", "samp_den")
_NORMALISATION = ("line_off", "line_scale", "samp_off", "samp_scale", "lat_off", "lat_scale",
                  "long_off", "long_scale", "height_off", "height_scale")
#: RpcModel field -> .RPB key, DigitalGlobe XML key, _RPC.TXT key
_RPB_KEYS = {"line_off": "lineOffset", "samp_off": "sampOffset", "lat_off": "latOffset", "long_off": "longOffset",
             "height_off": "heightOffset", "line_scale": "lineScale", "samp_scale": "sampScale",
             "lat_scale": "latScale", "long_scale": "longScale", "height_scale": "heightScale",
             "line_num": "lineNumCoef", "line_den": "lineDenCoef", "samp_num": "sampNumCoef", "samp_den": "sampDenCoef"}
_TXT_KEYS = {name: name.upper() for name in _NORMALISATION} | {name: f"{name.upper()}_COEFF" for name in _POLYNOMIALS}


def _model(path: str, fields: dict, spec: str | None = None) -> RpcModel:
    if spec is not None and spec.strip().strip('"').upper() == "RPC00A":
        for name in _POLYNOMIALS:
            values = np.asarray(fields[name], float)
            reordered = np.empty(20)
            reordered[list(RPC00A_TO_RPC00B)] = values
            fields[name] = reordered
    try:
        return RpcModel(**fields, pixel_origin=GDAL_PIXEL_ORIGIN)
    except ValueError as exc:
        raise BlockError(path, str(exc)) from None


def _read_text(path: str, what: str) -> str:
    return read_text(path, what)


def _float(path: str, text: str, key: str, line: int | None) -> float:
    token = text.strip().split()[0] if text.strip() else ""
    try:
        value = float(token)
    except ValueError:
        raise BlockError(path, f"{key} must be a number, found {text.strip()[:40]!r}", line=line, column=key) from None
    if not np.isfinite(value):
        raise BlockError(path, f"{key} must be finite", line=line, column=key)
    return value


# --- detection -------------------------------------------------------------------------------------

def is_rpb(path: str, head: bytes) -> bool:
    return path.lower().endswith(".rpb") or b"BEGIN_GROUP" in head.upper()


def is_rpc_txt(path: str, head: bytes) -> bool:
    return path.lower().endswith("_rpc.txt") or re.search(rb"^\s*LINE_OFF\s*:", head, re.MULTILINE) is not None


def is_tiff(head: bytes) -> bool:
    return head[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")


def is_nitf(head: bytes) -> bool:
    """NITF 2.0 / 2.1 or NSIF 1.0: the file header begins with its profile name and version."""
    return head[:4] in (b"NITF", b"NSIF")


# --- .RPB ------------------------------------------------------------------------------------------

def read_rpb(path: str | os.PathLike) -> RpcModel:
    """The RPC of a DigitalGlobe / GDAL ``.RPB`` keyword file (module docstring)."""
    path = str(path)
    text = _read_text(path, "RPB file")
    entries: dict[str, tuple[str, int]] = {}
    statement, start = "", 0
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not statement and (not stripped or stripped.upper().startswith(("BEGIN_GROUP", "END_GROUP"))
                              or stripped.upper() in ("END;", "END")):
            continue
        if not statement:
            start = number
        statement += " " + stripped
        if not stripped.endswith(";"):
            continue
        key, sep, value = statement.strip()[:-1].partition("=")
        if not sep:
            raise BlockError(path, f"expected 'key = value;', found {statement.strip()[:60]!r}", line=start)
        entries[key.strip().lower()] = (value.strip(), start)
        statement = ""
    if statement:
        raise BlockError(path, f"statement not closed by ';': {statement.strip()[:60]!r}", line=start)

    fields: dict[str, float | np.ndarray] = {}
    for name, key in _RPB_KEYS.items():
        if key.lower() not in entries:
            raise BlockError(path, f"missing key {key}", column=key)
        value, at = entries[key.lower()]
        if name in _POLYNOMIALS:
            inner = value.strip()
            if not (inner.startswith("(") and inner.endswith(")")):
                raise BlockError(path, f"{key} must be a list ( c1, ..., c20 )", line=at, column=key)
            items = [item for item in inner[1:-1].replace("\n", " ").split(",")]
            if len(items) != 20:
                raise BlockError(path, f"{key} must hold 20 coefficients, found {len(items)}", line=at, column=key)
            fields[name] = np.array([_float(path, item, key, at) for item in items])
        else:
            fields[name] = _float(path, value, key, at)
    spec = entries.get("specid", (None, None))[0]
    return _model(path, fields, spec)


def write_rpb(model: RpcModel, path: str | os.PathLike, satellite: str = "unknown", band: str = "P") -> None:
    """Write ``model`` as an ``.RPB`` (GDAL's layout, 17 significant digits, ``pixel_origin`` 0)."""
    values = _file_values(model)
    lines = [f'satId = "{satellite}";', f'bandId = "{band}";', 'SpecId = "RPC00B";', "BEGIN_GROUP = IMAGE",
             "\terrBias = -1.0;", "\terrRand = -1.0;"]
    for name in _NORMALISATION:
        lines.append(f"\t{_RPB_KEYS[name]} = {values[name]!r};")
    for name in _POLYNOMIALS:
        coefficients = ",\n".join(f"\t\t{float(c)!r}" for c in values[name])
        lines.append(f"\t{_RPB_KEYS[name]} = (\n{coefficients});")
    lines += ["END_GROUP = IMAGE", "END;"]
    with atomic_write(path) as handle:
        handle.write("\n".join(lines) + "\n")


def _file_values(model: RpcModel) -> dict:
    """The model's fields in the GDAL convention (offsets moved by the pixel origin)."""
    values: dict[str, float | np.ndarray] = {name: float(getattr(model, name)) for name in _NORMALISATION}
    values["line_off"] -= model.pixel_origin - GDAL_PIXEL_ORIGIN
    values["samp_off"] -= model.pixel_origin - GDAL_PIXEL_ORIGIN
    for name in _POLYNOMIALS:
        values[name] = np.asarray(getattr(model, name), float)
    return values


# --- DigitalGlobe XML RPB block ---------------------------------------------------------------------

#: RpcModel field -> element of isd/RPB/IMAGE
_DG_KEYS = {name: key.upper() for name, key in _RPB_KEYS.items() if name in _NORMALISATION}


def read_dg_xml_rpc(path: str | os.PathLike) -> RpcModel:
    """The RPC00B of a DigitalGlobe / Maxar XML file's ``RPB`` block (``isd/RPB/IMAGE``)."""
    from .xmldoc import XmlDocument
    path = str(path)
    doc = XmlDocument(path, "DigitalGlobe XML file")
    rpb = doc.node(doc.root, "RPB")
    image = doc.node(rpb, "IMAGE")
    fields: dict[str, float | np.ndarray] = {name: doc.number(image, key) for name, key in _DG_KEYS.items()}
    for name in _POLYNOMIALS:
        key = _RPB_KEYS[name].upper()                        # LINENUMCOEF
        fields[name] = doc.numbers(doc.node(image, f"{key}List"), key, 20)
    spec = doc.find(rpb, "SPECID")
    return _model(path, fields, None if spec is None else spec.text)


# --- _RPC.TXT --------------------------------------------------------------------------------------

def read_rpc_txt(path: str | os.PathLike) -> RpcModel:
    """The RPC of a ``_RPC.TXT`` file (``KEY: value [unit]`` lines, module docstring)."""
    path = str(path)
    entries: dict[str, tuple[str, int]] = {}
    for number, line in enumerate(_read_text(path, "RPC text file").splitlines(), start=1):
        if not line.strip():
            continue
        key, sep, value = line.partition(":")
        if not sep:
            raise BlockError(path, f"expected 'KEY: value', found {line.strip()[:60]!r}", line=number)
        entries[key.strip().upper()] = (value, number)

    def number_of(key: str) -> float:
        if key not in entries:
            raise BlockError(path, f"missing key {key}", column=key)
        value, line = entries[key]
        return _float(path, value, key, line)

    fields: dict[str, float | np.ndarray] = {name: number_of(_TXT_KEYS[name]) for name in _NORMALISATION}
    for name in _POLYNOMIALS:
        fields[name] = np.array([number_of(f"{_TXT_KEYS[name]}_{k}") for k in range(1, 21)])
    return _model(path, fields)


def write_rpc_txt(model: RpcModel, path: str | os.PathLike) -> None:
    """Write ``model`` as a ``_RPC.TXT`` (GDAL's keys and units, 17 significant digits, ``pixel_origin`` 0)."""
    values = _file_values(model)
    units = {"line": "pixels", "samp": "pixels", "lat": "degrees", "long": "degrees", "height": "meters"}
    lines = ["ERR_BIAS: -1.0", "ERR_RAND: -1.0"]
    for name in _NORMALISATION:
        lines.append(f"{_TXT_KEYS[name]}: {values[name]!r} {units[name.split('_')[0]]}")
    for name in _POLYNOMIALS:
        lines += [f"{_TXT_KEYS[name]}_{k}: {float(c)!r}" for k, c in enumerate(values[name], start=1)]
    with atomic_write(path) as handle:
        handle.write("\n".join(lines) + "\n")


#: file name ending (any case) -> writer
RPC_FILE_SUFFIXES = {".rpb": write_rpb, "_rpc.txt": write_rpc_txt}


def write_rpc_file(model: RpcModel, path: str | os.PathLike) -> None:
    """Write ``model`` in the format its name ends with: ``.RPB`` or ``_RPC.TXT`` (any case), atomically; another
    name is a UsageError."""
    name = os.path.basename(str(path)).lower()
    for suffix, writer in RPC_FILE_SUFFIXES.items():
        if name.endswith(suffix):
            writer(model, path)
            return
    raise UsageError(f"--out {path}: the format comes from the name, which must end in .RPB or _RPC.TXT "
                     f"(GDAL finds IMAGE.RPB or IMAGE_RPC.TXT beside IMAGE.tif)")


# --- GeoTIFF ---------------------------------------------------------------------------------------

def rasterio_rpcs(model: RpcModel) -> RPC:
    """``rasterio.rpc.RPC`` of ``model`` in the GDAL convention (to write a GeoTIFF with ``rpcs=``)."""
    from rasterio.rpc import RPC
    values = _file_values(model)
    return RPC(height_off=values["height_off"], height_scale=values["height_scale"], lat_off=values["lat_off"],
               lat_scale=values["lat_scale"], line_den_coeff=list(values["line_den"]),
               line_num_coeff=list(values["line_num"]), line_off=values["line_off"],
               line_scale=values["line_scale"], long_off=values["long_off"], long_scale=values["long_scale"],
               samp_den_coeff=list(values["samp_den"]), samp_num_coeff=list(values["samp_num"]),
               samp_off=values["samp_off"], samp_scale=values["samp_scale"])


def read_raster_rpc(path: str | os.PathLike, what: str = "GeoTIFF") -> RpcModel:
    """The RPC of a raster that GDAL opens, read by rasterio (``dataset.rpcs``): a GeoTIFF's RPC tags (or GDAL's
    .RPB / _RPC.TXT beside it), a NITF's RPC00B TRE. ``what`` names the format in errors."""
    path = str(path)
    try:
        import rasterio
        from rasterio.errors import RasterioIOError
    except ImportError:                                   # pragma: no cover - rasterio is a dependency
        raise BlockError(path, f"reading a {what}'s RPC needs rasterio") from None
    try:
        with rasterio.open(path) as dataset:
            rpcs = dataset.rpcs
    except RasterioIOError as exc:
        raise BlockError(path, f"cannot read the {what}: {exc}") from None
    if rpcs is None:
        where = "no RPC00B TRE" if what == "NITF" else "no RPCCoefficientTag, .RPB or _RPC.TXT"
        raise BlockError(path, f"the {what} has no RPC ({where})")
    fields: dict[str, float | np.ndarray] = {name: float(getattr(rpcs, name)) for name in _NORMALISATION}
    for name in _POLYNOMIALS:
        values = np.asarray(getattr(rpcs, f"{name}_coeff"), float)
        if values.shape != (20,):
            raise BlockError(path, f"RPC {name.upper()}_COEFF must hold 20 coefficients, found {values.size}",
                             column=f"{name.upper()}_COEFF")
        fields[name] = values
    return _model(path, fields)


def _open_raster(raster: str):
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioIOError
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        try:
            return rasterio.open(raster)
        except RasterioIOError as exc:
            raise BlockError(raster, f"cannot read the raster: {exc}") from None


def raster_size(raster: str | os.PathLike) -> tuple[int, int]:
    """(rows, cols) of a raster GDAL reads."""
    with _open_raster(str(raster)) as source:
        return source.height, source.width


def write_geotiff_rpc(model: RpcModel, path: str | os.PathLike, raster: str | os.PathLike) -> tuple[int, int]:
    """Write a GeoTIFF copy of ``raster`` (any raster GDAL reads: every band's pixels, its data type, no-data value
    and georeferencing if any; tiled, deflate) whose RPC tags hold ``model`` (GDAL's convention, ``pixel_origin`` 0;
    any RPC of the source is replaced), atomically: written under a temporary name beside ``path``, then renamed.
    GDAL reads the tags' doubles back to 15 significant digits. Returns the raster's (rows, cols)."""
    import tempfile

    import rasterio

    path, raster = str(path), str(raster)
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    handle, tmp = tempfile.mkstemp(prefix=".tmp-", suffix="-" + os.path.basename(path), dir=directory)
    os.close(handle)
    try:
        with _open_raster(raster) as source:
            profile = dict(driver="GTiff", width=source.width, height=source.height, count=source.count,
                           dtype=source.dtypes[0], nodata=source.nodata, tiled=True, blockxsize=256,
                           blockysize=256, compress="deflate", BIGTIFF="IF_SAFER")
            if source.crs is not None:
                profile.update(crs=source.crs, transform=source.transform)
            with rasterio.open(tmp, "w", rpcs=rasterio_rpcs(model), **profile) as target:
                for _, window in target.block_windows(1):
                    target.write(source.read(window=window), window=window)
            shape = (source.height, source.width)
        os.replace(tmp, path)
    except BaseException:
        for name in (tmp, tmp + ".aux.xml"):
            if os.path.exists(name):
                os.unlink(name)
        raise
    return shape


def read_geotiff_rpc(path: str | os.PathLike) -> RpcModel:
    """The RPC of a GeoTIFF (its RPC tags, or GDAL's .RPB / _RPC.TXT beside it), read by rasterio."""
    return read_raster_rpc(path, "GeoTIFF")
