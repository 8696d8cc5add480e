"""Camera positions written into the images: EXIF GPS tags and DJI's XMP (``drone-dji``), read with Pillow.

What is read, per image (plain numbers; geodesy is done by :mod:`selfcal.geometry.geodesy`):

* **EXIF GPS IFD** (tag 0x8825; EXIF 2.32 section 4.6.6): ``GPSLatitude``/``GPSLatitudeRef`` (degrees, minutes,
  seconds as rationals; ``S`` negative), ``GPSLongitude``/``GPSLongitudeRef`` (``W`` negative), ``GPSAltitude``
  with ``GPSAltitudeRef`` (1: below the reference, negative), ``GPSDateStamp`` + ``GPSTimeStamp`` (UTC).
* **EXIF IFD** (0x8769): ``DateTimeOriginal`` with ``SubSecTimeOriginal`` and ``OffsetTimeOriginal`` (the camera
  clock; used for the time only when an image has no GPS time stamp).
* **IFD0**: ``Make`` and ``Model`` (the camera: its rolling shutter's readout, :mod:`selfcal.convert.rolling`) and
  the image's size.
* **DJI XMP** (the ``drone-dji`` namespace; DJI's Zenmuse P1 / Matrice 4 manuals, "XMP Data List", and
  OpenDroneMap's ``opendm/photo.py``): ``Latitude``/``GpsLatitude``, ``Longitude``/``GpsLongitude`` (decimal
  degrees; they replace the EXIF rationals, as in ODM), ``AbsoluteAltitude`` ("geodetic height": WGS 84
  ellipsoidal on DJI's RTK aircraft, a barometric height on the others, as DJI support states),
  ``RtkStdLon``, ``RtkStdLat``, ``RtkStdHgt`` (standard deviations of the RTK position in metres: east, north, up),
  ``RtkFlag`` (50: fixed), ``FlightYawDegree``/``FlightPitchDegree``/``FlightRollDegree`` and
  ``GimbalYawDegree``/``GimbalPitchDegree``/``GimbalRollDegree`` (degrees). The XMP packet is found in the JPEG's
  bytes (``<x:xmpmeta`` ... ``</x:xmpmeta>``) and parsed with :mod:`xml.etree`; a tag may be an attribute or an
  element of any ``rdf:Description``.

The EXIF altitude's reference is "sea level" by the standard; DJI's RTK aircraft write the ellipsoidal height
there too. Which one the numbers are is the caller's decision (``selfcal import gnss --heights``).
"""
from __future__ import annotations

import math
import os
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone

import numpy as np

from ..errors import BlockError

__all__ = ["ImageGnss", "read_image_gnss", "read_xmp", "image_files", "positions_array", "JPEG_SUFFIXES"]

JPEG_SUFFIXES = (".jpg", ".jpeg")
GPS_IFD, EXIF_IFD = 0x8825, 0x8769
#: EXIF GPS tags (EXIF 2.32, Table 16)
GPS_LATITUDE_REF, GPS_LATITUDE, GPS_LONGITUDE_REF, GPS_LONGITUDE = 1, 2, 3, 4
GPS_ALTITUDE_REF, GPS_ALTITUDE, GPS_TIME_STAMP, GPS_DATE_STAMP = 5, 6, 7, 29
#: EXIF IFD tags
DATE_TIME_ORIGINAL, SUBSEC_TIME_ORIGINAL, OFFSET_TIME_ORIGINAL = 0x9003, 0x9291, 0x9011
#: TIFF IFD0 tags of the camera (EXIF 2.32, Table 4)
MAKE, MODEL = 0x010F, 0x0110


@dataclass(frozen=True)
class ImageGnss:
    """What one image says about where it was taken (NaN: not in the image).

    ``time_s`` counts seconds since 1970-01-01 UTC (GPS time stamp) or, with ``time_source`` ``"camera"``, on the
    camera clock (DateTimeOriginal, its offset applied when given): only differences are used.
    ``sigma_enu_m`` are DJI's RtkStdLon, RtkStdLat, RtkStdHgt (east, north, up); ``flight_ypr_deg`` and
    ``gimbal_ypr_deg`` yaw, pitch, roll in degrees as DJI writes them.
    """

    path: str
    latitude_deg: float = math.nan
    longitude_deg: float = math.nan
    height_m: float = math.nan
    time_s: float = math.nan
    time_source: str = ""
    sigma_enu_m: tuple = (math.nan, math.nan, math.nan)
    rtk_flag: float = math.nan
    flight_ypr_deg: tuple = (math.nan, math.nan, math.nan)
    gimbal_ypr_deg: tuple = (math.nan, math.nan, math.nan)
    sources: tuple = field(default=())        # "exif", "xmp"
    #: the camera (EXIF Make, Model: "" where not written) and the image's size in pixels (0: unknown)
    camera_make: str = ""
    camera_model: str = ""
    width_px: int = 0
    height_px: int = 0

    @property
    def name(self) -> str:
        return os.path.basename(self.path)

    @property
    def has_position(self) -> bool:
        return math.isfinite(self.latitude_deg) and math.isfinite(self.longitude_deg)


def _rational(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return math.nan


def _dms(values, ref, positive: str, negative: str, path: str, tag: str) -> float:
    try:
        d, m, s = (_rational(v) for v in values)
    except (TypeError, ValueError):
        raise BlockError(path, f"EXIF {tag} is not three rationals (degrees, minutes, seconds): {values!r}") from None
    ref = (ref or positive).strip().upper()[:1] if isinstance(ref, str) else positive
    if ref not in (positive, negative):
        raise BlockError(path, f"EXIF {tag}Ref must be {positive} or {negative}, found {ref!r}")
    value = d + m / 60.0 + s / 3600.0
    return -value if ref == negative else value


def _gps_time(gps: dict) -> float:
    date, stamp = gps.get(GPS_DATE_STAMP), gps.get(GPS_TIME_STAMP)
    if not date or not stamp:
        return math.nan
    try:
        day = datetime.strptime(str(date).strip("\0 "), "%Y:%m:%d").replace(tzinfo=timezone.utc)
        h, m, s = (_rational(v) for v in stamp)
    except (TypeError, ValueError):
        return math.nan
    return (day - datetime(1970, 1, 1, tzinfo=timezone.utc)).total_seconds() + 3600 * h + 60 * m + s


def _camera_time(exif: dict) -> float:
    text = exif.get(DATE_TIME_ORIGINAL)
    if not text:
        return math.nan
    try:
        moment = datetime.strptime(str(text).strip("\0 "), "%Y:%m:%d %H:%M:%S")
    except ValueError:
        return math.nan
    sub = str(exif.get(SUBSEC_TIME_ORIGINAL, "") or "").strip("\0 ")
    if sub.isdigit():
        moment += timedelta(seconds=float("0." + sub))
    offset = re.fullmatch(r"([+-])(\d\d):(\d\d)", str(exif.get(OFFSET_TIME_ORIGINAL, "") or "").strip("\0 "))
    moment = moment.replace(tzinfo=timezone.utc)
    if offset:
        sign = 1 if offset.group(1) == "+" else -1
        moment -= sign * timedelta(hours=int(offset.group(2)), minutes=int(offset.group(3)))
    return (moment - datetime(1970, 1, 1, tzinfo=timezone.utc)).total_seconds()


def read_xmp(data: bytes, path: str) -> dict[str, str]:
    """The ``drone-dji`` tags of the XMP packet in a file's bytes (local name -> text); {} without a packet.

    A packet that is not XML is a BlockError naming the file."""
    start = data.find(b"<x:xmpmeta")
    end = data.find(b"</x:xmpmeta>", start)
    if start < 0 or end < 0:
        return {}
    try:
        root = ET.fromstring(data[start:end + len(b"</x:xmpmeta>")].decode("utf-8"))
    except (ET.ParseError, UnicodeDecodeError) as exc:
        raise BlockError(path, f"the XMP packet is not well-formed XML: {exc}") from None
    tags: dict[str, str] = {}

    def dji(name: str) -> str | None:
        match = re.fullmatch(r"\{([^}]*)\}(.+)", name)
        return match.group(2) if match and "drone-dji" in match.group(1) else None

    for element in root.iter():
        for key, value in element.attrib.items():
            local = dji(key)
            if local:
                tags[local] = value.strip()
        local = dji(element.tag)
        if local and element.text and element.text.strip():
            tags[local] = element.text.strip()
    return tags


def _xmp_number(tags: dict, names, path: str) -> float:
    for name in names:
        if name in tags:
            text = tags[name]
            try:
                if "/" in text:
                    num, den = text.split("/")
                    return float(num) / float(den)
                return float(text)
            except (ValueError, ZeroDivisionError):
                raise BlockError(path, f"XMP drone-dji:{name} is not a number: {text!r}") from None
    return math.nan


def read_image_gnss(path: str | os.PathLike) -> ImageGnss:
    """The GNSS position, its sigma, time and attitude written in one JPEG (see the module docstring).

    A file Pillow cannot open, or tags that are not what EXIF/XMP define, is a BlockError naming the file; an
    image without any of the tags is returned with NaNs (the caller counts it)."""
    from PIL import Image, UnidentifiedImageError

    path = os.fspath(path)
    try:
        with open(path, "rb") as handle:
            data = handle.read()
        with Image.open(path) as image:
            exif = image.getexif()
            gps = dict(exif.get_ifd(GPS_IFD))
            camera = dict(exif.get_ifd(EXIF_IFD))
            make, model = _text(exif.get(MAKE)), _text(exif.get(MODEL))
            size_px = image.size
    except FileNotFoundError:
        raise BlockError(path, "file not found") from None
    except (UnidentifiedImageError, OSError, SyntaxError) as exc:
        raise BlockError(path, f"not an image Pillow can read: {exc}") from None
    values = dict(latitude_deg=math.nan, longitude_deg=math.nan, height_m=math.nan)
    sources = []
    if GPS_LATITUDE in gps and GPS_LONGITUDE in gps:
        values["latitude_deg"] = _dms(gps[GPS_LATITUDE], gps.get(GPS_LATITUDE_REF), "N", "S", path, "GPSLatitude")
        values["longitude_deg"] = _dms(gps[GPS_LONGITUDE], gps.get(GPS_LONGITUDE_REF), "E", "W", path,
                                       "GPSLongitude")
        sources.append("exif")
    if GPS_ALTITUDE in gps:
        height = _rational(gps[GPS_ALTITUDE])
        ref = gps.get(GPS_ALTITUDE_REF, 0)
        ref = ref[0] if isinstance(ref, (bytes, bytearray)) and ref else ref
        values["height_m"] = -height if ref == 1 else height
    xmp = read_xmp(data, path)
    lat = _xmp_number(xmp, ("Latitude", "GpsLatitude"), path)
    lon = _xmp_number(xmp, ("Longitude", "GpsLongitude", "GpsLongtitude"), path)    # DJI's spelling on some models
    if math.isfinite(lat) and math.isfinite(lon):
        values["latitude_deg"], values["longitude_deg"] = lat, lon
        sources.append("xmp")
    height = _xmp_number(xmp, ("AbsoluteAltitude",), path)
    if math.isfinite(height):
        values["height_m"] = height
    time_s, source = _gps_time(gps), "gps"
    if not math.isfinite(time_s):
        time_s, source = _camera_time(camera), "camera"
    return ImageGnss(
        path=path, **values,
        time_s=time_s, time_source=source if math.isfinite(time_s) else "",
        sigma_enu_m=tuple(_xmp_number(xmp, (k,), path) for k in ("RtkStdLon", "RtkStdLat", "RtkStdHgt")),
        rtk_flag=_xmp_number(xmp, ("RtkFlag",), path),
        flight_ypr_deg=tuple(_xmp_number(xmp, (f"Flight{a}Degree",), path) for a in ("Yaw", "Pitch", "Roll")),
        gimbal_ypr_deg=tuple(_xmp_number(xmp, (f"Gimbal{a}Degree",), path) for a in ("Yaw", "Pitch", "Roll")),
        sources=tuple(sources), camera_make=make, camera_model=model, width_px=int(size_px[0]),
        height_px=int(size_px[1]),
    )


def _text(value) -> str:
    """An EXIF ASCII tag as text ("" where absent), its NUL padding removed."""
    if value is None:
        return ""
    if isinstance(value, (bytes, bytearray)):
        value = value.decode("latin-1")
    return str(value).strip("\0 ")


def image_files(folder: str) -> list[str]:
    """The JPEG files of a folder (not its subfolders), sorted by name."""
    return sorted(os.path.join(folder, f) for f in os.listdir(folder)
                  if f.lower().endswith(JPEG_SUFFIXES) and os.path.isfile(os.path.join(folder, f)))


def positions_array(records: list[ImageGnss]) -> np.ndarray:
    """(n, 3) longitude, latitude (degrees), height (m) of the records (NaN where missing)."""
    return np.array([[r.longitude_deg, r.latitude_deg, r.height_m] for r in records], float).reshape(-1, 3)
