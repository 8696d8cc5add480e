"""Metashape markers (the ``<markers>`` of a chunk's ``doc.xml``, or File > Export > Export Markers) and reference
CSV files of control coordinates, as plain data.

Markers XML: ``<cameras>`` names each camera (``<camera id="0" label="DSC00001"/>``), ``<markers>`` each marker
(``<marker id="0" label="GCP1">`` with an optional ``<reference x= y= z= sx= sy= sz= enabled=/>``), and the
projections sit in ``<frames><frame><markers><marker marker_id="0"><location camera_id="0" x= y= pinned=
valid=/>``. Projections are pixels with Metashape's convention: the image centre is (w/2, h/2) (its
calibration's u = w/2 + cx + x' f), the upper-left corner of the upper-left pixel (0, 0): selfcal's, taken as
they are. A location with ``valid="false"`` is left out. A marker whose reference is not ``enabled`` is a check
point in Metashape's terms.

Reference CSV (Metashape's Import Reference, PIX4D's GCP import: "label, X, Y, Z" or "label, X, Y, Z, horizontal
accuracy, vertical accuracy"): ``label X Y Z`` then 0, 1 (one accuracy for X, Y and Z), 2 (plan, height) or 3
(X, Y, Z) accuracy columns in metres; separated by commas, semicolons, tabs or blanks; ``#`` comments; a first
line whose coordinates are not numbers is a header.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass

import numpy as np

from ..errors import BlockError
from .patb import ControlPoints, numbers
from .text import is_number, read_text
from .xmlfile import xml_root

__all__ = ["Markers", "read_markers_xml", "read_reference_csv"]


@dataclass(frozen=True)
class Markers:
    path: str
    marker: np.ndarray            # (m,) marker label of each projection
    camera: np.ndarray            # (m,) camera label
    pixel: np.ndarray             # (m, 2) col, row (selfcal's convention)
    line: np.ndarray              # (m,) line of the location element in the file (0 where not found)
    marker_line: dict             # label -> line of its definition
    reference: ControlPoints | None   # the markers' reference coordinates in the file, if any


def _line_finder(text: str):
    starts = [m.start() for m in re.finditer(r"\n", text)]

    def line_of(pattern: str, start: int = 0) -> tuple[int, int]:
        match = re.search(pattern, text[start:])
        if not match:
            return 0, start
        pos = start + match.start()
        return int(np.searchsorted(starts, pos)) + 1, pos + 1
    return line_of


def _float(path, line, element, name) -> float | None:
    value = element.get(name)
    return None if value is None else numbers(path, line, [value], [f"{element.tag} {name}"])[0]


def _flag(path, line, element, name) -> bool:
    """A Metashape true/false attribute (absent: true); any other value is an error."""
    value = element.get(name, "true").strip().lower()
    if value not in ("true", "false", "1", "0"):
        raise BlockError(path, f"<{element.tag} {name}=...> must be true or false, found {element.get(name)!r}"[:200],
                         line)
    return value in ("true", "1")


def read_markers_xml(path: str | os.PathLike) -> Markers:
    """Marker projections (and references) of a Metashape markers XML or chunk document."""
    path = os.fspath(path)
    text = read_text(path, "Metashape markers XML")
    root = xml_root(path, "Metashape markers XML")
    line_of = _line_finder(text)
    cameras: dict[str, str] = {}          # camera id -> label
    for cams in root.iter("cameras"):
        for element in cams.iter("camera"):
            camera_id = element.get("id")
            if camera_id is not None:
                cameras[camera_id] = element.get("label") or camera_id
    labels: dict[str, str] = {}           # marker id -> label
    marker_line: dict[str, int] = {}
    ref_ids, ref_xyz, ref_sigma, ref_line, ref_enabled = [], [], [], [], []
    cursor = 0
    for markers in root.iter("markers"):
        for definition in markers.findall("marker"):
            marker_id = definition.get("id")
            if marker_id is None or definition.get("marker_id") is not None:
                continue
            label = definition.get("label") or f"marker{marker_id}"
            line, cursor = line_of(r'<marker\b[^>]*\bid="' + re.escape(marker_id) + '"', cursor)
            if label in marker_line:
                raise BlockError(path, f"two markers are labelled '{label}' (first on line {marker_line[label]})", line)
            labels[marker_id] = label
            marker_line[label] = line
            ref = definition.find("reference")
            if ref is not None and ref.get("x") is not None:
                line = line_of(r"<reference\b", cursor)[0] or line
                xyz = [_float(path, line, ref, k) for k in ("x", "y", "z")]
                if None in xyz:
                    raise BlockError(path, f"marker '{label}': the reference lacks a coordinate", line)
                sigma = [_float(path, line, ref, k) for k in ("sx", "sy", "sz")]
                if any(v is not None and not v > 0 for v in sigma):
                    raise BlockError(path, f"marker '{label}': the reference accuracies sx, sy, sz must be positive, "
                                           f"found {[ref.get(k) for k in ('sx', 'sy', 'sz')]}", line)
                ref_ids.append(label)
                ref_xyz.append(xyz)
                ref_sigma.append([np.nan if s is None else s for s in sigma])
                ref_line.append(line)
                ref_enabled.append(_flag(path, line, ref, "enabled"))
    marker: list[str] = []
    camera: list[str] = []
    pixel: list[tuple[float, float]] = []
    lines: list[int] = []
    cursor = 0
    seen: dict[tuple[str, str], int] = {}
    for element in root.iter("marker"):
        mid = element.get("marker_id")
        if mid is None and element.find("location") is None:
            continue
        mid = mid if mid is not None else element.get("id")
        for location in element.findall("location"):
            cid = location.get("camera_id")
            line, cursor = line_of(r'<location\b[^>]*\bcamera_id="' + re.escape(str(cid)) + '"', cursor)
            if mid not in labels:
                raise BlockError(path, f"a projection of marker id {mid}, which <markers> does not define", line or None)
            if cid not in cameras:
                raise BlockError(path, f"marker '{labels[mid]}': camera id {cid} is not among the file's <cameras>",
                                 line or None)
            if not _flag(path, line or None, location, "valid"):
                continue
            x, y = _float(path, line, location, "x"), _float(path, line, location, "y")
            if x is None or y is None:
                raise BlockError(path, f"marker '{labels[mid]}' in camera '{cameras[cid]}': the location has no x "
                                       f"or y", line or None)
            key = (labels[mid], cameras[cid])
            if key in seen:
                raise BlockError(path, f"marker '{key[0]}' is measured twice in camera '{key[1]}' (first on line "
                                       f"{seen[key]})", line or None)
            seen[key] = line
            marker.append(labels[mid])
            camera.append(cameras[cid])
            pixel.append((x, y))
            lines.append(line)
    if not marker:
        raise BlockError(path, "no marker projection in the file (<frames><frame><markers><marker "
                               "marker_id=..><location camera_id=.. x=.. y=../>)")
    reference = None
    if ref_ids:
        reference = ControlPoints(path, np.array(ref_ids, object), np.array(ref_xyz, float), np.array(ref_sigma, float),
                                  np.array(ref_line, np.int64), np.array(ref_enabled, bool))
    return Markers(path, np.array(marker, object), np.array(camera, object), np.array(pixel, float),
                   np.array(lines, np.int64), marker_line, reference)


def read_reference_csv(path: str | os.PathLike) -> ControlPoints:
    """Control coordinates ``label X Y Z [accuracies]`` (see the module's docstring)."""
    path = os.fspath(path)
    ids, xyz, sigma, lines = [], [], [], []
    first: dict[str, int] = {}
    data_seen = False
    for number, line in enumerate(read_text(path, "reference CSV").splitlines(), start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        fields = [f.strip() for f in re.split(r"[,;\t]" if re.search(r"[,;\t]", text) else r"\s+", text)]
        if len(fields) < 4:
            raise BlockError(path, f"expected 'label, X, Y, Z[, accuracy...]', found {len(fields)} field(s)", number)
        if not data_seen and not is_number(fields[1]):
            data_seen = True            # a header line
            continue
        data_seen = True
        if len(fields) > 7:
            raise BlockError(path, f"expected at most 7 fields (label, X, Y, Z and up to 3 accuracies), found "
                                   f"{len(fields)}", number)
        label = fields[0]
        if label in first:
            raise BlockError(path, f"point '{label}' is given twice (first on line {first[label]})", number)
        first[label] = number
        coords = numbers(path, number, fields[1:4], ("X", "Y", "Z"))
        acc = numbers(path, number, fields[4:], ("accuracy",) * 3)
        if any(a <= 0 for a in acc):
            raise BlockError(path, "an accuracy must be positive", number)
        if len(acc) == 0:
            s = [np.nan] * 3
        elif len(acc) == 1:
            s = acc * 3
        elif len(acc) == 2:
            s = [acc[0], acc[0], acc[1]]
        else:
            s = acc
        ids.append(label)
        xyz.append(coords)
        sigma.append(s)
        lines.append(number)
    if not ids:
        raise BlockError(path, "no point in the file")
    k = len(ids)
    return ControlPoints(path, np.array(ids, object), np.array(xyz, float), np.array(sigma, float),
                         np.array(lines, np.int64), np.ones(k, bool))
