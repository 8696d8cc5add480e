"""ISIS binary (protobuf) control networks read, and networks written back as ISIS reads them (binary or PVL).

**Binary layout** (ISIS ``ControlNetVersioner``): a PVL label ``Object = ProtoBuffer`` with ``Object = Core``
(``HeaderStartByte``, ``HeaderBytes``, ``PointsStartByte``, ``PointsBytes``) and ``Group = ControlNetworkInfo``
(``Version``, informational counts), zero-padded to byte 65536 where ISIS writes it; at ``HeaderStartByte`` the
header message, then the points:

* version 2: header ``ControlNetFileHeaderV0002`` (1 networkId, 2 targetName, 3 created, 4 lastModified,
  5 description, 6 userName, 7 pointMessageSizes: packed int32), then the points back to back, point k being
  ``pointMessageSizes[k]`` bytes (no prefix);
* version 5: header ``ControlNetFileHeaderV0005`` (fields 1-6 as above, 7 numPoints, 10 targetRadii: doubles),
  then each point as a 4-byte **little-endian** unsigned length and the message (ISIS writes the length through
  ``EndianSwapper("LSB")``; measured on ISIS's own test network ``themis_dayir_VO_arcadia_extract_hand.net``:
  ``f8 01 00 00`` = 504 bytes), until ``PointsBytes`` are read.

Points of both versions are ``ControlPointFileEntryV0002``: 1 id, 2 type (enum: 0 obsolete Tie and 2 Free read
as Free, 3 Constrained, 1 obsolete Ground and 4 Fixed as Fixed), 5 editLock, 6 ignore, 7 jigsawRejected,
8 referenceIndex, 9 aprioriSurfPointSource (enum), 13-15 latitude/longitude/radiusConstrained, 16-18 aprioriX/Y/Z
(m), 19 aprioriCovar (packed: XX XY XZ YY YZ ZZ, m²), 20-22 adjustedX/Y/Z, 23 adjustedCovar, 25 measures;
a measure: 1 serialnumber, 2 type (0 Candidate, 1 Manual, 2 RegisteredPixel, 3 RegisteredSubPixel), 3 sample,
4 line, 5/6 sample/lineResidual (px), 9 editLock, 10 ignore, 11 jigsawRejected, 13/14 apriori sample/line,
15/16 sample/lineSigma. Fields selfcal does not keep (chooser names, dates, log data) are skipped.

Read into the :class:`~selfcal.io.isis.ControlNetwork` of the PVL reader; a point's and a measure's
``source_line`` is then the **byte offset** of its message in the file. Errors (a label without Core, a header
or point past the end of the file, a truncated message, a missing required field) are
:class:`~selfcal.errors.BlockError` naming the file and the byte offset.

**Writing** (:func:`network_bytes`, :func:`network_pvl`): binary version 5 exactly as ISIS writes it (the label
padded to 65536 bytes, header, length-prefixed points) and PVL version 5 as ``cnetbin2pvl`` writes it; both
read back by :func:`selfcal.io.isis.read_control_network` to the same network (numbers as ``repr`` in PVL:
exact).
"""
from __future__ import annotations

import math
import os
import re
import struct

import numpy as np

from ..errors import BlockError
from . import protobuf as pb
from .pvl import PvlBlock, parse_pvl
from .text import UTF8_BOM, decode_text

__all__ = ["is_binary_network", "read_binary_network", "network_bytes", "network_pvl", "LABEL_BYTES", "APRIORI_SOURCES"]

#: the bytes ISIS reserves for the label of a binary network (the header starts here)
LABEL_BYTES = 65536
APRIORI_SOURCES = ("", "User", "AverageOfMeasures", "Reference", "Ellipsoid", "DEM", "Basemap", "BundleSolution")
_POINT_TYPES = {0: "Free", 2: "Free", 3: "Constrained", 1: "Fixed", 4: "Fixed"}
_POINT_CODES = {"Free": 2, "Constrained": 3, "Fixed": 4}
_MEASURE_TYPES = ("Candidate", "Manual", "RegisteredPixel", "RegisteredSubPixel")


def _label_integer(block: PvlBlock, key: str, path: str) -> int:
    k = block.keyword(key)
    if k is None:
        raise BlockError(path, f"the label's {block.kind} '{block.name}' has no '{key}'", block.line, key)
    if not re.fullmatch(r"[0-9]{1,15}", k.value.strip()):
        raise BlockError(path, f"'{key}' must be a non-negative integer, found {k.value!r}", k.line, key)
    return int(k.value)


def _strings(fields_, names: dict[int, str]) -> dict[str, str]:
    out = {}
    for number, wire, value, _ in fields_:
        if number in names and wire == pb.LENGTH:
            out[names[number]] = value.decode("utf-8", "replace")
    return out


_HEADER_STRINGS = {1: "network_id", 2: "target_name", 3: "created", 4: "last_modified", 5: "description",
                   6: "user_name"}


def _measure(data: bytes, offset: int, point_id: str, path: str, is_reference: bool):
    from .isis import ControlMeasure
    values: dict[str, object] = {}
    for number, wire, value, at in pb.fields(data, path, base=offset):
        if number == 1:
            if wire != pb.LENGTH:
                raise BlockError(path, f"byte {at}: a measure's serial number must be a string")
            values["serial"] = value.decode("utf-8", "replace")
        elif number == 2:
            code = pb.as_signed(value, wire, path, at, "MeasureType")
            if not 0 <= code < len(_MEASURE_TYPES):
                raise BlockError(path, f"byte {at}: unknown MeasureType {code} of a measure of point '{point_id}' "
                                       f"(known: 0-3, {', '.join(_MEASURE_TYPES)})")
            values["type"] = _MEASURE_TYPES[code]
        elif number in (3, 4, 5, 6, 13, 14, 15, 16):
            name = {3: "sample", 4: "line", 5: "sr", 6: "lr", 13: "as", 14: "al", 15: "ss", 16: "ls"}[number]
            x = pb.as_double(value, wire, path, at, name)
            if not math.isfinite(x):
                raise BlockError(path, f"byte {at}: a measure of point '{point_id}' has a non-finite value {x}")
            values[name] = x
        elif number in (10, 11):
            values[{10: "ignore", 11: "rejected"}[number]] = bool(pb.as_signed(value, wire, path, at, "flag"))
    for required, what in (("serial", "serial number (field 1)"), ("type", "MeasureType (field 2)"),
                           ("sample", "sample (field 3)"), ("line", "line (field 4)")):
        if required not in values:
            raise BlockError(path, f"byte {offset}: a measure of point '{point_id}' has no {what}")
    nan = float("nan")

    def get(name: str) -> float:
        v = values.get(name, nan)
        return float(v) if isinstance(v, float) else nan
    sample, line = get("sample"), get("line")
    return ControlMeasure(
        point_id=point_id, serial_number=str(values["serial"]), measure_type=str(values["type"]), sample=sample,
        line=line, col_px=sample - 0.5, row_px=line - 0.5, ignored=bool(values.get("ignore", False)),
        reference=is_reference, rejected=bool(values.get("rejected", False)), sample_residual_px=get("sr"),
        line_residual_px=get("lr"), sample_sigma_px=get("ss"), line_sigma_px=get("ls"), apriori_sample=get("as"),
        apriori_line=get("al"), source_line=offset)


def _covariance(values: list[float], at: int, path: str, name: str) -> np.ndarray | None:
    if not values:
        return None
    if len(values) != 6:
        raise BlockError(path, f"byte {at}: '{name}' must have 6 values (XX, XY, XZ, YY, YZ, ZZ in m²), found "
                               f"{len(values)}")
    xx, xy, xz, yy, yz, zz = values
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


def _point(data: bytes, offset: int, path: str):
    from .isis import ControlPoint
    parsed = pb.fields(data, path, base=offset)
    point_id = None
    point_type = None
    flags = {"ignore": False, "edit_lock": False, "lat": False, "lon": False, "rad": False}
    reference_index = -1
    source = ""
    xyz: dict[int, float] = {}
    covar: dict[int, list[float]] = {19: [], 23: []}
    covar_at = {19: offset, 23: offset}
    measures: list[tuple[bytes, int]] = []
    for number, wire, value, at in parsed:
        if number == 1:
            if wire != pb.LENGTH:
                raise BlockError(path, f"byte {at}: a point's id must be a string")
            point_id = value.decode("utf-8", "replace")
        elif number == 2:
            code = pb.as_signed(value, wire, path, at, "PointType")
            if code not in _POINT_TYPES:
                raise BlockError(path, f"byte {at}: unknown PointType {code} (known: 0-4; Free 2, Constrained 3, "
                                       "Fixed 4)")
            point_type = _POINT_TYPES[code]
        elif number in (5, 6, 13, 14, 15):
            flags[{5: "edit_lock", 6: "ignore", 13: "lat", 14: "lon", 15: "rad"}[number]] = \
                bool(pb.as_signed(value, wire, path, at, "flag"))
        elif number == 8:
            reference_index = pb.as_signed(value, wire, path, at, "referenceIndex")
        elif number == 9:
            code = pb.as_signed(value, wire, path, at, "aprioriSurfPointSource")
            source = APRIORI_SOURCES[code] if 0 <= code < len(APRIORI_SOURCES) else str(code)
        elif number in (16, 17, 18, 20, 21, 22):
            x = pb.as_double(value, wire, path, at, f"field {number}")
            if not math.isfinite(x):
                raise BlockError(path, f"byte {at}: a point coordinate (field {number}) is {x}")
            xyz[number] = x
        elif number in (19, 23):
            covar[number] += pb.packed_doubles(value, wire, path, at, f"field {number}")
            covar_at[number] = at
        elif number == 25:
            if wire != pb.LENGTH:
                raise BlockError(path, f"byte {at}: a measure (field 25) must be a message")
            measures.append((value, at))
    if point_id is None or point_type is None:
        raise BlockError(path, f"byte {offset}: a point has no {'id (field 1)' if point_id is None else 'type (field 2)'}")

    def triple(first: int, name: str) -> np.ndarray | None:
        present = [k in xyz for k in range(first, first + 3)]
        if not any(present):
            return None
        if not all(present):
            raise BlockError(path, f"byte {offset}: point '{point_id}' has only some of {name}X/Y/Z")
        return np.array([xyz[first], xyz[first + 1], xyz[first + 2]])
    decoded = []
    for k, (body, at) in enumerate(measures):
        # the message body starts after its tag and length varint
        head = len(pb.key(25, pb.LENGTH)) + len(pb.varint(len(body)))
        decoded.append(_measure(body, at + head, point_id, path, k == reference_index))
    seen: dict[str, int] = {}
    for m in decoded:
        if m.serial_number in seen:
            raise BlockError(path, f"byte {m.source_line}: point '{point_id}' is measured twice in "
                                   f"'{m.serial_number}' (also at byte {seen[m.serial_number]})")
        seen[m.serial_number] = m.source_line
    return ControlPoint(
        point_id=point_id, point_type=point_type, ignored=flags["ignore"], edit_lock=flags["edit_lock"],
        apriori_xyz_m=triple(16, "Apriori"), apriori_covariance_m2=_covariance(covar[19], covar_at[19], path,
                                                                              "aprioriCovar"),
        constrained=(flags["lat"], flags["lon"], flags["rad"]), adjusted_xyz_m=triple(20, "Adjusted"),
        apriori_source=source, measures=tuple(decoded), source_line=offset,
        adjusted_covariance_m2=_covariance(covar[23], covar_at[23], path, "adjustedCovar"))


_PROTOBUF_LABEL = re.compile(rb"\s*Object\s*=\s*ProtoBuffer\b", re.IGNORECASE)


def is_binary_network(path: str | os.PathLike) -> bool:
    """Whether the file starts as an ISIS binary network's label (``Object = ProtoBuffer``), whatever its name."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(256)
    except OSError:
        return False
    return _PROTOBUF_LABEL.match(head.removeprefix(UTF8_BOM)) is not None


def _read_label(data: bytes, path: str) -> PvlBlock:
    """The PVL label at the start of a binary network: its text ends at the first NUL (the zero padding ISIS
    and plio write up to the header) or at the 'End' line."""
    nul = data.find(b"\0", 0, LABEL_BYTES)
    head = data[:nul] if nul >= 0 else data[:LABEL_BYTES]
    end = re.search(rb"^[ \t]*End[ \t]*\r?$", head, re.MULTILINE | re.IGNORECASE)
    if end is not None:
        head = head[:end.end()]
    return parse_pvl(decode_text(head, path), path)


def read_binary_network(path: str | os.PathLike):
    """The :class:`~selfcal.io.isis.ControlNetwork` of an ISIS binary network (versions 2 and 5; module
    docstring)."""
    from .isis import ControlNetwork
    path = str(path)
    try:
        with open(path, "rb") as handle:
            data = handle.read()
    except OSError as exc:
        raise BlockError(path, f"cannot read: {exc.strerror}") from None
    root = _read_label(data, path)
    proto = root.find("Object", "ProtoBuffer")
    if proto is None:
        raise BlockError(path, "not an ISIS binary control network (no 'Object = ProtoBuffer')")
    core = proto.find("Object", "Core")
    if core is None:
        raise BlockError(path, "the label's ProtoBuffer has no 'Object = Core'", proto.line, "Core")
    info = proto.find("Group", "ControlNetworkInfo")
    version = _label_integer(info, "Version", path) if info is not None and info.keyword("Version") else 1
    if version not in (2, 5):
        k = info.keyword("Version") if info is not None else None
        raise BlockError(path, f"binary control network version {version} is not read (versions 2 and 5; ISIS "
                               "cnetbin2pvl and cnetpvl2bin rewrite it as the current one)",
                         k.line if k is not None else proto.line, "Version")
    header_start = _label_integer(core, "HeaderStartByte", path)
    header_bytes = _label_integer(core, "HeaderBytes", path)
    points_bytes = _label_integer(core, "PointsBytes", path)
    if header_start + header_bytes > len(data):
        raise BlockError(path, f"byte {header_start}: the header ({header_bytes} bytes from HeaderStartByte "
                               f"{header_start}) runs past the end of the file ({len(data)} bytes): truncated")
    header = pb.fields(data, path, header_start, header_start + header_bytes)
    texts = _strings(header, _HEADER_STRINGS)
    pos = header_start + header_bytes       # ISIS reads the points right after the header
    k = core.keyword("PointsStartByte")
    if k is not None and _label_integer(core, "PointsStartByte", path) != pos:
        raise BlockError(path, f"PointsStartByte {k.value} is not HeaderStartByte + HeaderBytes = {pos}",
                         k.line, "PointsStartByte")
    end = pos + points_bytes
    if end > len(data):
        raise BlockError(path, f"byte {pos}: the points ({points_bytes} bytes from byte {pos}) run past the end of "
                               f"the file ({len(data)} bytes): truncated")
    spans: list[tuple[int, int]] = []
    if version == 2:
        for number, wire, value, at in header:
            if number == 7:
                sizes = [value] if wire == pb.VARINT else _packed_varints(value, wire, path, at)
                for size in sizes:
                    spans.append((pos, pos + size))
                    pos += size
        if pos > end:
            raise BlockError(path, f"byte {header_start}: the header's point sizes add up to {pos - end + points_bytes} "
                                   f"bytes, more than PointsBytes {points_bytes}")
    else:
        while pos < end:
            if pos + 4 > end:
                raise BlockError(path, f"byte {pos}: a point's 4-byte length is cut off by the end of the points "
                                       f"(byte {end})")
            size = struct.unpack("<I", data[pos:pos + 4])[0]
            if pos + 4 + size > end:
                raise BlockError(path, f"byte {pos}: bad point length {size}: past the end of the points (byte "
                                       f"{end}); a truncated or damaged file")
            spans.append((pos + 4, pos + 4 + size))
            pos += 4 + size
    points = []
    seen: dict[str, int] = {}
    for start, stop in spans:
        point = _point(data[start:stop], start, path)
        if point.point_id in seen:
            raise BlockError(path, f"byte {start}: PointId '{point.point_id}' repeats (first at byte "
                                   f"{seen[point.point_id]})")
        seen[point.point_id] = start
        points.append(point)
    return ControlNetwork(path=path, network_id=texts.get("network_id", ""),
                          target_name=texts.get("target_name", ""), version=version, points=tuple(points),
                          created=texts.get("created", ""), last_modified=texts.get("last_modified", ""),
                          description=texts.get("description", ""), user_name=texts.get("user_name", ""),
                          binary=True)


def _packed_varints(value, wire: int, path: str, at: int) -> list[int]:
    if wire != pb.LENGTH:
        raise BlockError(path, f"byte {at}: pointMessageSizes must be packed int32, found wire type {wire}")
    out, pos = [], 0
    while pos < len(value):
        v, pos = pb.read_varint(value, pos, len(value), path, at)
        out.append(v)
    return out


# --- writing ----------------------------------------------------------------------------------------

def _point_message(point) -> bytes:
    out = bytearray()
    pb.put_string(out, 1, point.point_id)
    pb.put_varint(out, 2, _POINT_CODES[point.point_type])
    if point.edit_lock:
        pb.put_bool(out, 5, True)
    if point.ignored:
        pb.put_bool(out, 6, True)
    reference = [k for k, m in enumerate(point.measures) if m.reference]
    if reference:
        pb.put_varint(out, 8, reference[0])
    if point.apriori_source in APRIORI_SOURCES[1:]:
        pb.put_varint(out, 9, APRIORI_SOURCES.index(point.apriori_source))
    for number, flag in zip((13, 14, 15), point.constrained):
        if flag:
            pb.put_bool(out, number, True)
    for first, xyz, cov, cov_field in ((16, point.apriori_xyz_m, point.apriori_covariance_m2, 19),
                                       (20, point.adjusted_xyz_m, point.adjusted_covariance_m2, 23)):
        if xyz is None:
            continue
        for k in range(3):
            pb.put_double(out, first + k, xyz[k])
        if cov is not None:
            pb.put_packed_doubles(out, cov_field, _upper(cov))
    for m in point.measures:
        body = bytearray()
        pb.put_string(body, 1, m.serial_number)
        pb.put_varint(body, 2, _MEASURE_TYPES.index(m.measure_type))
        pb.put_double(body, 3, m.sample)
        pb.put_double(body, 4, m.line)
        for number, value in ((5, m.sample_residual_px), (6, m.line_residual_px)):
            if math.isfinite(value):
                pb.put_double(body, number, value)
        if m.ignored:
            pb.put_bool(body, 10, True)
        if m.rejected:
            pb.put_bool(body, 11, True)
        for number, value in ((13, m.apriori_sample), (14, m.apriori_line), (15, m.sample_sigma_px),
                              (16, m.line_sigma_px)):
            if math.isfinite(value):
                pb.put_double(body, number, value)
        pb.put_bytes(out, 25, bytes(body))
    return bytes(out)


def _upper(cov: np.ndarray) -> list[float]:
    return [float(cov[0, 0]), float(cov[0, 1]), float(cov[0, 2]), float(cov[1, 1]), float(cov[1, 2]),
            float(cov[2, 2])]


def network_bytes(network) -> bytes:
    """``network`` as an ISIS binary control network, version 5 (what ISIS 3.6 and later write)."""
    header = bytearray()
    for number, text in ((1, network.network_id), (2, network.target_name), (3, network.created),
                         (4, network.last_modified), (5, network.description), (6, network.user_name)):
        pb.put_string(header, number, text)
    points = bytearray()
    for point in network.points:
        message = _point_message(point)
        points += struct.pack("<I", len(message)) + message
    n_measures = sum(len(p.measures) for p in network.points)
    label = "\n".join([
        "Object = ProtoBuffer", "  Object = Core", f"    HeaderStartByte = {LABEL_BYTES}",
        f"    HeaderBytes     = {len(header)}", f"    PointsStartByte = {LABEL_BYTES + len(header)}",
        f"    PointsBytes     = {len(points)}", "  End_Object", "",
        "  # This group is for informational purposes only", "  Group = ControlNetworkInfo",
        f"    NetworkId        = {_pvl_value(network.network_id)}",
        f"    TargetName       = {_pvl_value(network.target_name)}",
        f"    UserName         = {_pvl_value(network.user_name)}",
        f"    Created          = {_pvl_value(network.created)}",
        f"    LastModified     = {_pvl_value(network.last_modified)}",
        f"    Description      = {_pvl_value(network.description)}",
        f"    NumberOfPoints   = {len(network.points)}", f"    NumberOfMeasures = {n_measures}",
        "    Version          = 5", "  End_Group", "End_Object", "End", ""]).encode("utf-8")
    if len(label) > LABEL_BYTES:
        raise ValueError(f"the label of the binary network is {len(label)} bytes, more than {LABEL_BYTES}")
    return label + bytes(LABEL_BYTES - len(label)) + bytes(header) + bytes(points)


_BARE = re.compile(r"[^\s=(){},\"'<>#]+")


def _pvl_value(text: str) -> str:
    """A PVL value: bare when it reads back as one word, else double-quoted (ISIS's quoting)."""
    if text and _BARE.fullmatch(text) and not text.endswith("-") and "/*" not in text:
        return text
    if '"' in text:
        raise ValueError(f"a PVL value cannot hold a double quote: {text!r}")
    return f'"{text}"'


def _num(x: float) -> str:
    return repr(float(x))


def network_pvl(network) -> str:
    """``network`` as an ISIS PVL control network, version 5 (``cnetbin2pvl``'s layout)."""
    lines = ["Object = ControlNetwork", f"  NetworkId    = {_pvl_value(network.network_id)}",
             f"  TargetName   = {_pvl_value(network.target_name)}", f"  UserName     = {_pvl_value(network.user_name)}",
             f"  Created      = {_pvl_value(network.created)}",
             f"  LastModified = {_pvl_value(network.last_modified)}",
             f"  Description  = {_pvl_value(network.description)}", "  Version      = 5", ""]
    for point in network.points:
        lines += ["  Object = ControlPoint", f"    PointType   = {point.point_type}",
                  f"    PointId     = {_pvl_value(point.point_id)}"]
        if point.edit_lock:
            lines.append("    EditLock    = True")
        if point.ignored:
            lines.append("    Ignore      = True")
        if point.apriori_source:
            lines.append(f"    AprioriXYZSource = {_pvl_value(point.apriori_source)}")
        for prefix, xyz, cov in (("Apriori", point.apriori_xyz_m, point.apriori_covariance_m2),
                                 ("Adjusted", point.adjusted_xyz_m, point.adjusted_covariance_m2)):
            if xyz is None:
                continue
            lines += [f"    {prefix}{axis} = {_num(xyz[k])} <meters>" for k, axis in enumerate("XYZ")]
            if cov is not None:
                lines.append(f"    {prefix}CovarianceMatrix = ({', '.join(_num(v) for v in _upper(cov))})")
            if prefix == "Apriori":
                for flag, name in zip(point.constrained, ("Latitude", "Longitude", "Radius")):
                    if flag:
                        lines.append(f"    {name}Constrained = True")
        for m in point.measures:
            lines += ["", "    Group = ControlMeasure", f"      SerialNumber   = {_pvl_value(m.serial_number)}",
                      f"      MeasureType    = {m.measure_type}"]
            if m.ignored:
                lines.append("      Ignore         = True")
            lines += [f"      Sample         = {_num(m.sample)}", f"      Line           = {_num(m.line)}"]
            for name, value, unit in (("AprioriSample", m.apriori_sample, ""), ("AprioriLine", m.apriori_line, ""),
                                      ("SampleSigma", m.sample_sigma_px, " <pixels>"),
                                      ("LineSigma", m.line_sigma_px, " <pixels>"),
                                      ("SampleResidual", m.sample_residual_px, " <pixels>"),
                                      ("LineResidual", m.line_residual_px, " <pixels>")):
                if math.isfinite(value):
                    lines.append(f"      {name} = {_num(value)}{unit}")
            if m.rejected:
                lines.append("      JigsawRejected = True")
            if m.reference:
                lines.append("      Reference      = True")
            lines.append("    End_Group")
        lines += ["  End_Object", ""]
    lines += ["End_Object", "End", ""]
    return "\n".join(lines)
