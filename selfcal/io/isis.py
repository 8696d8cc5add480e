"""ISIS control networks (PVL) and cube labels, read into plain data.

**Control network** (``Object = ControlNetwork``, PVL versions 3-5 as ISIS's ``cnetbin2pvl`` writes them):
per point its ``PointId``, ``PointType`` (``Free`` / ``Constrained`` / ``Fixed``; the old names ``Tie`` and
``Ground`` read as Free and Fixed, as ISIS's versioner does), ``Ignore``, the a-priori body-fixed
``AprioriX/Y/Z`` in metres (``<meters>``; another unit is an error) and ``AprioriCovarianceMatrix``: six
numbers, the upper triangle XX, XY, XZ, YY, YZ, ZZ of the body-fixed covariance in m² (ISIS
``SurfacePoint::GetRectangularMatrix``; the comment above it in the file states the same as latitude,
longitude and radius sigmas in metres, see :mod:`selfcal.geometry.body`). Per measure the cube
``SerialNumber``, ``MeasureType``, ``Sample``/``Line`` and ``SampleResidual``/``LineResidual`` (pixels, of
the adjustment that last wrote the file), ``Ignore``, ``Reference`` and ``JigsawRejected``.

Pixel convention: ISIS's ``Sample``/``Line`` are 1-based with the *centre* of the first pixel at 1.0; selfcal's
(DESIGN.md §2) put the upper-left *corner* of the first pixel at (0, 0), so the reader converts once:
``col_px = Sample - 0.5``, ``row_px = Line - 0.5``, and keeps the original numbers too. Both are pixels of
the cube the network was measured on (for a reduced cube, not of the full detector: see the label's
:class:`AlphaCube`).

**Serial numbers**: ISIS names an image in a network by a serial number composed from its label by a
translation table of the mission and instrument (``$ISISROOT/appdata/serialnumbers/<Mission><Instrument>
SerialNumber.trn``): the values of some ``Instrument`` keywords joined by ``/``. The rules for the
instruments selfcal reads are in :data:`SERIAL_RULES`: Apollo 15/16/17 Metric and Panoramic are
``APOLLO15/METRIC/<StartTime>`` (the spacecraft name is replaced by ``APOLLO15`` whatever its spelling),
the LRO NACs ``LRO/<SpacecraftClockStartCount>/<InstrumentId>`` (``LRO/1/269182000:51104/NACL``). The label's
text is used as it is written (no time parsing).

Errors are :class:`~selfcal.errors.BlockError` naming the file, the line and the keyword.
"""
from __future__ import annotations

import glob
import math
import os
import re
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import BlockError
from .pvl import PvlBlock, PvlKeyword, read_pvl

__all__ = ["ControlMeasure", "ControlPoint", "ControlNetwork", "AlphaCube", "CubeLabel", "read_control_network",
           "read_cube_label", "serial_number", "match_serials", "read_image_folder", "SERIAL_RULES", "POINT_TYPES",
           "MEASURE_TYPES"]

POINT_TYPES = ("Free", "Constrained", "Fixed")
MEASURE_TYPES = ("Candidate", "Manual", "RegisteredPixel", "RegisteredSubPixel")
_POINT_TYPE = {"free": "Free", "tie": "Free", "constrained": "Constrained", "fixed": "Fixed", "ground": "Fixed"}
_MEASURE_TYPE = {t.lower(): t for t in MEASURE_TYPES}
_TRUE, _FALSE = ("true", "yes"), ("false", "no")
_METRES = {None: 1.0, "meters": 1.0, "meter": 1.0, "m": 1.0}
_PIXELS = (None, "pixels", "pixel")

# Serial numbers: (mission, instrument) -> ((keyword, {input: output} or None = as written), ...).
# "*" as input translates any value. Missions from the label's SpacecraftName, instruments from its
# InstrumentId, as ISIS's MissionName2DataDir.trn and Instruments.trn name them.
_MISSION = {"APOLLO 15": "Apollo15", "APOLLO15": "Apollo15", "APOLLO 16": "Apollo16", "APOLLO16": "Apollo16",
            "APOLLO 17": "Apollo17", "APOLLO17": "Apollo17", "LUNAR RECONNAISSANCE ORBITER": "Lro"}
_INSTRUMENT = {"METRIC": "Metric", "PAN": "Panoramic", "NACL": "Nac", "NACR": "Nac"}
SERIAL_RULES: dict[tuple[str, str], tuple[tuple[str, dict | None], ...]] = {
    **{(f"Apollo{n}", inst): (("SpacecraftName", {"*": f"APOLLO{n}"}), ("InstrumentId", None), ("StartTime", None))
       for n in (15, 16, 17) for inst in ("Metric", "Panoramic")},
    ("Lro", "Nac"): (("SpacecraftName", {"LUNAR RECONNAISSANCE ORBITER": "LRO"}),
                     ("SpacecraftClockStartCount", None), ("InstrumentId", None)),
}


@dataclass(frozen=True)
class ControlMeasure:
    """One measure of a point in one image. ``col_px``/``row_px`` are selfcal's (corner origin), ``sample``/
    ``line`` ISIS's (centre of the first pixel at 1.0); NaN where the file gives no value."""

    point_id: str
    serial_number: str
    measure_type: str                       # one of MEASURE_TYPES
    sample: float
    line: float
    col_px: float
    row_px: float
    ignored: bool
    reference: bool
    rejected: bool                          # JigsawRejected
    sample_residual_px: float
    line_residual_px: float
    sample_sigma_px: float
    line_sigma_px: float
    apriori_sample: float
    apriori_line: float
    source_line: int                        # line of 'Group = ControlMeasure' in the file


@dataclass(frozen=True)
class ControlPoint:
    """A control point; a-priori coordinates and covariance are body-fixed (m, m²), None when absent."""

    point_id: str
    point_type: str                         # one of POINT_TYPES
    ignored: bool
    edit_lock: bool
    apriori_xyz_m: np.ndarray | None        # (3,)
    apriori_covariance_m2: np.ndarray | None  # (3, 3) symmetric
    constrained: tuple[bool, bool, bool]    # LatitudeConstrained, LongitudeConstrained, RadiusConstrained
    adjusted_xyz_m: np.ndarray | None
    apriori_source: str                     # AprioriXYZSource ('' if absent)
    measures: tuple[ControlMeasure, ...]
    source_line: int                        # line of 'Object = ControlPoint' (binary network: byte offset)
    adjusted_covariance_m2: np.ndarray | None = None  # (3, 3) symmetric, the adjustment's (jigsaw's)


@dataclass(frozen=True)
class ControlNetwork:
    path: str
    network_id: str
    target_name: str
    version: int
    points: tuple[ControlPoint, ...]
    created: str = ""
    last_modified: str = ""
    description: str = ""
    user_name: str = ""
    binary: bool = False                    # read from a binary (protobuf) network

    @property
    def measures(self) -> list[ControlMeasure]:
        """Every measure of every point (ignored ones included), in file order."""
        return [m for p in self.points for m in p.measures]

    def counts(self) -> dict:
        """Points and measures by type, and what an adjustment leaves out: ignored points, ignored measures
        of points that are not ignored, the measures of ignored points, and measures jigsaw rejected."""
        return {
            "points": len(self.points),
            "measures": sum(len(p.measures) for p in self.points),
            "points_by_type": dict(Counter(p.point_type for p in self.points)),
            "measures_by_type": dict(Counter(m.measure_type for m in self.measures)),
            "ignored_points": sum(p.ignored for p in self.points),
            "ignored_measures": sum(m.ignored for p in self.points if not p.ignored for m in p.measures),
            "measures_of_ignored_points": sum(len(p.measures) for p in self.points if p.ignored),
            "rejected_measures": sum(m.rejected for m in self.measures),
        }


@dataclass(frozen=True)
class AlphaCube:
    """ISIS's ``AlphaCube`` group: how the pixels of this (beta) cube sit in the cube the camera was defined
    on (alpha: the full detector). ``alpha = (alpha_end - alpha_start) / beta_count · (beta - 0.5) +
    alpha_start`` in ISIS pixel numbers (1-based, pixel centres); a cube without the group is its own alpha."""

    alpha_samples: int
    alpha_lines: int
    alpha_starting_sample: float
    alpha_starting_line: float
    alpha_ending_sample: float
    alpha_ending_line: float
    beta_samples: int
    beta_lines: int

    @classmethod
    def identity(cls, samples: int, lines: int) -> "AlphaCube":
        return cls(samples, lines, 0.5, 0.5, samples + 0.5, lines + 0.5, samples, lines)


@dataclass(frozen=True)
class CubeLabel:
    path: str
    serial_number: str
    spacecraft_name: str
    instrument_id: str
    target_name: str
    start_time: str                         # the label's text
    samples: int
    lines: int
    alpha_cube: AlphaCube
    naif_frame_code: int | None


# --- reading helpers ------------------------------------------------------------------------------

def _text(block: PvlBlock, key: str, path: str, required: bool = True, default: str = "") -> str:
    k = block.keyword(key)
    if k is None or not k.values:
        if required:
            raise BlockError(path, f"{block.kind} '{block.name}' (line {block.line}) has no '{key}'", block.line, key)
        return default
    return k.value


def _number(k: PvlKeyword, path: str, index: int = 0, units=None, unit_name: str = "") -> float:
    try:
        value = float(k.values[index])
    except (ValueError, IndexError):
        raise BlockError(path, f"'{k.name}' must be a number, found {k.values!r}", k.line, k.name) from None
    if not math.isfinite(value):
        raise BlockError(path, f"'{k.name}' must be finite, found {k.values[index]!r}", k.line, k.name)
    if units is not None:
        given = k.units[index] if index < len(k.units) else None
        unit = given.lower() if given else None
        if unit not in units:
            raise BlockError(path, f"'{k.name}' is in <{k.units[index]}>; expected {unit_name}", k.line, k.name)
    return value


def _optional_number(block: PvlBlock, key: str, path: str, units=None, unit_name: str = "") -> float:
    k = block.keyword(key)
    return float("nan") if k is None else _number(k, path, 0, units, unit_name)


def _flag(block: PvlBlock, key: str, path: str) -> bool:
    k = block.keyword(key)
    if k is None:
        return False
    value = k.value.lower()
    if value not in _TRUE + _FALSE:
        raise BlockError(path, f"'{key}' must be True or False, found {k.value!r}", k.line, key)
    return value in _TRUE


#: no cube has a side of more pixels than this; a larger Samples or Lines is a broken label
MAX_CUBE_SIDE = 10**7


def _integer(block: PvlBlock, key: str, path: str, low: int | None = None) -> int:
    """An integer keyword (``low``: at least ``low`` and at most MAX_CUBE_SIDE, a size in pixels)."""
    k = block.keyword(key)
    if k is None:
        raise BlockError(path, f"{block.kind} '{block.name}' has no '{key}'", block.line, key)
    if len(k.values) != 1 or not re.fullmatch(r"[+-]?[0-9]{1,18}", k.value.strip()):
        raise BlockError(path, f"'{key}' must be an integer, found {k.values!r}"[:200], k.line, key)
    value = int(k.value)
    if low is not None and not low <= value <= MAX_CUBE_SIDE:
        raise BlockError(path, f"'{key}' must be an integer {low}..{MAX_CUBE_SIDE}, found {value}", k.line, key)
    return value


# --- control network ------------------------------------------------------------------------------

def _kind(block: PvlBlock, key: str, table: dict, known, what: str, path: str) -> str:
    """The type keyword ``key`` of a point or measure, read through ``table``; missing or unknown: an error."""
    kind = block.keyword(key)
    if kind is None:
        raise BlockError(path, f"{what} has no '{key}'", block.line, key)
    value = table.get(kind.value.lower())
    if value is None:
        raise BlockError(path, f"unknown {key} {kind.value!r} (known: {', '.join(known)})", kind.line, key)
    return value


def _measure(group: PvlBlock, point_id: str, path: str) -> ControlMeasure:
    serial = _text(group, "SerialNumber", path)
    measure_type = _kind(group, "MeasureType", _MEASURE_TYPE, MEASURE_TYPES, f"measure of point '{point_id}'", path)
    coords = []
    for key in ("Sample", "Line"):
        k = group.keyword(key)
        if k is None:
            raise BlockError(path, f"measure of point '{point_id}' in '{serial}' has no '{key}'", group.line, key)
        coords.append(_number(k, path, 0, _PIXELS, "<pixels>"))
    sample, line = coords
    return ControlMeasure(
        point_id=point_id, serial_number=serial, measure_type=measure_type, sample=sample, line=line,
        col_px=sample - 0.5, row_px=line - 0.5, ignored=_flag(group, "Ignore", path),
        reference=_flag(group, "Reference", path), rejected=_flag(group, "JigsawRejected", path),
        sample_residual_px=_optional_number(group, "SampleResidual", path, _PIXELS, "<pixels>"),
        line_residual_px=_optional_number(group, "LineResidual", path, _PIXELS, "<pixels>"),
        sample_sigma_px=_optional_number(group, "SampleSigma", path, _PIXELS, "<pixels>"),
        line_sigma_px=_optional_number(group, "LineSigma", path, _PIXELS, "<pixels>"),
        apriori_sample=_optional_number(group, "AprioriSample", path, _PIXELS, "<pixels>"),
        apriori_line=_optional_number(group, "AprioriLine", path, _PIXELS, "<pixels>"),
        source_line=group.line)


def _xyz(block: PvlBlock, prefix: str, path: str) -> np.ndarray | None:
    keys = [block.keyword(prefix + axis) for axis in "XYZ"]
    present = [k is not None for k in keys]
    if not any(present):
        return None
    if not all(present):
        missing = prefix + "XYZ"[present.index(False)]
        raise BlockError(path, f"point '{block.name}' has only some of {prefix}X/Y/Z (no '{missing}')",
                         block.line, missing)
    return np.array([_number(k, path, 0, _METRES, "<meters>") for k in keys if k is not None])


def _covariance(block: PvlBlock, key: str, path: str) -> np.ndarray | None:
    k = block.keyword(key)
    if k is None:
        return None
    if len(k.values) != 6:
        raise BlockError(path, f"'{key}' must have 6 values (XX, XY, XZ, YY, YZ, ZZ in m²), found {len(k.values)}",
                         k.line, key)
    xx, xy, xz, yy, yz, zz = (_number(k, path, i) for i in range(6))
    cov = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    if np.any(np.linalg.eigvalsh(cov) < -1e-9 * max(abs(xx), abs(yy), abs(zz), 1.0)):
        raise BlockError(path, f"'{key}' is not a covariance (not positive semi-definite)", k.line, key)
    return cov


def _point(obj: PvlBlock, path: str) -> ControlPoint:
    point_id = _text(obj, "PointId", path)
    point_type = _kind(obj, "PointType", _POINT_TYPE, POINT_TYPES, f"point '{point_id}'", path)
    for block in obj.blocks:
        if block.kind != "Group" or block.name.lower() != "controlmeasure":
            raise BlockError(path, f"point '{point_id}' holds {block.kind} '{block.name}'; only ControlMeasure groups "
                                   "are read", block.line, block.name)
    named = PvlBlock(obj.kind, point_id, obj.line, obj.keywords)
    measures = tuple(_measure(g, point_id, path) for g in obj.blocks)
    seen: dict[str, int] = {}
    for m in measures:
        if m.serial_number in seen:
            raise BlockError(path, f"point '{point_id}' is measured twice in '{m.serial_number}' (also at line "
                                   f"{seen[m.serial_number]})", m.source_line, "SerialNumber")
        seen[m.serial_number] = m.source_line
    return ControlPoint(
        point_id=point_id, point_type=point_type, ignored=_flag(obj, "Ignore", path),
        edit_lock=_flag(obj, "EditLock", path), apriori_xyz_m=_xyz(named, "Apriori", path),
        apriori_covariance_m2=_covariance(obj, "AprioriCovarianceMatrix", path),
        constrained=(_flag(obj, "LatitudeConstrained", path), _flag(obj, "LongitudeConstrained", path),
                     _flag(obj, "RadiusConstrained", path)),
        adjusted_xyz_m=_xyz(named, "Adjusted", path), apriori_source=_text(obj, "AprioriXYZSource", path, False),
        measures=measures, source_line=obj.line,
        adjusted_covariance_m2=_covariance(obj, "AdjustedCovarianceMatrix", path))


def read_control_network(path: str | os.PathLike) -> ControlNetwork:
    """Read an ISIS control network: PVL (module docstring) or binary (protobuf, versions 2 and 5:
    :mod:`selfcal.io.isis_cnet`), told apart by the content (a label ``Object = ProtoBuffer``), not the name."""
    path = str(path)
    from .isis_cnet import is_binary_network, read_binary_network
    if is_binary_network(path):
        return read_binary_network(path)
    root = read_pvl(path)
    nets = root.children("Object", "ControlNetwork")
    if len(nets) != 1:
        raise BlockError(path, f"expected one 'Object = ControlNetwork', found {len(nets)}")
    net = nets[0]
    version = _integer(net, "Version", path) if net.keyword("Version") is not None else 1
    if version not in (3, 4, 5):
        k = net.keyword("Version")
        raise BlockError(path, f"control network version {version} is not read (versions 3-5: run ISIS cnetbin2pvl "
                               "on it to write the current one)", k.line if k else net.line, "Version")
    points: list[ControlPoint] = []
    seen: dict[str, int] = {}
    for obj in net.blocks:
        if obj.kind != "Object" or obj.name.lower() != "controlpoint":
            raise BlockError(path, f"unexpected {obj.kind} '{obj.name}' in the ControlNetwork", obj.line, obj.name)
        point = _point(obj, path)
        if point.point_id in seen:
            raise BlockError(path, f"PointId '{point.point_id}' repeats (first at line {seen[point.point_id]})",
                             obj.line, "PointId")
        seen[point.point_id] = obj.line
        points.append(point)
    return ControlNetwork(path=path, network_id=_text(net, "NetworkId", path, False),
                          target_name=_text(net, "TargetName", path, False), version=version, points=tuple(points),
                          created=_text(net, "Created", path, False), last_modified=_text(net, "LastModified", path, False),
                          description=_text(net, "Description", path, False),
                          user_name=_text(net, "UserName", path, False))


# --- cube labels and serial numbers ---------------------------------------------------------------

def serial_number(label: PvlBlock, path: str) -> str:
    """ISIS's serial number of a cube label (:data:`SERIAL_RULES`)."""
    instrument = label.find("Group", "Instrument")
    if instrument is None:
        raise BlockError(path, "the label has no 'Group = Instrument' to compose the serial number from")
    craft = instrument.keyword("SpacecraftName")
    inst = instrument.keyword("InstrumentId")
    mission = _MISSION.get(craft.value.upper()) if craft else None
    instrument_name = _INSTRUMENT.get(inst.value.upper()) if inst else None
    rule = SERIAL_RULES.get((mission, instrument_name)) if mission and instrument_name else None
    if rule is None:
        known = ", ".join(f"{m} {i}" for m, i in SERIAL_RULES)
        raise BlockError(path, f"no ISIS serial-number rule for SpacecraftName {craft.value if craft else None!r}, "
                               f"InstrumentId {inst.value if inst else None!r} (known: {known})",
                         craft.line if craft else instrument.line, "SpacecraftName")
    parts = []
    for key, translation in rule:
        value = _text(instrument, key, path)
        if translation is not None:
            value = translation.get(value.upper(), translation.get("*", value))
        parts.append(value)
    return "/".join(parts)


def _alpha_cube(label: PvlBlock, samples: int, lines: int, path: str) -> AlphaCube:
    group = label.find("Group", "AlphaCube")
    if group is None:
        return AlphaCube.identity(samples, lines)
    ints = {k: _integer(group, k, path, 1) for k in ("AlphaSamples", "AlphaLines", "BetaSamples", "BetaLines")}
    floats = {}
    for k in ("AlphaStartingSample", "AlphaStartingLine", "AlphaEndingSample", "AlphaEndingLine"):
        kw = group.keyword(k)
        if kw is None:
            raise BlockError(path, f"AlphaCube has no '{k}'", group.line, k)
        floats[k] = _number(kw, path)
    if not (floats["AlphaStartingSample"] < floats["AlphaEndingSample"]
            and floats["AlphaStartingLine"] < floats["AlphaEndingLine"]):
        raise BlockError(path, "AlphaCube's starting sample and line must be below its ending ones", group.line,
                         "AlphaStartingSample")
    if (ints["BetaSamples"], ints["BetaLines"]) != (samples, lines):
        raise BlockError(path, f"AlphaCube BetaSamples x BetaLines {ints['BetaSamples']} x {ints['BetaLines']} is not "
                               f"the cube's {samples} x {lines}", group.line, "BetaSamples")
    return AlphaCube(ints["AlphaSamples"], ints["AlphaLines"], floats["AlphaStartingSample"],
                     floats["AlphaStartingLine"], floats["AlphaEndingSample"], floats["AlphaEndingLine"],
                     ints["BetaSamples"], ints["BetaLines"])


def read_cube_label(path: str | os.PathLike) -> CubeLabel:
    """Read an ISIS cube label (a detached ``.pvl`` or the label of a ``.cub``): serial number, size,
    AlphaCube, instrument keywords."""
    path = str(path)
    root = read_pvl(path)
    cube = root.find("Object", "IsisCube")
    if cube is None:
        raise BlockError(path, "not an ISIS cube label (no 'Object = IsisCube')")
    dims = cube.find("Group", "Dimensions")
    if dims is None:
        raise BlockError(path, "the label has no 'Group = Dimensions'", cube.line, "Dimensions")
    samples, lines = _integer(dims, "Samples", path, 1), _integer(dims, "Lines", path, 1)
    instrument = cube.find("Group", "Instrument")
    kernels = cube.find("Group", "Kernels")
    code_value = None
    if kernels is not None and kernels.keyword("NaifFrameCode") is not None:
        code_value = _integer(kernels, "NaifFrameCode", path)
    text = (lambda key: _text(instrument, key, path, False)) if instrument is not None else (lambda key: "")
    return CubeLabel(path=path, serial_number=serial_number(root, path), spacecraft_name=text("SpacecraftName"),
                     instrument_id=text("InstrumentId"), target_name=text("TargetName"),
                     start_time=text("StartTime"), samples=samples, lines=lines,
                     alpha_cube=_alpha_cube(cube, samples, lines, path), naif_frame_code=code_value)


def match_serials(network: ControlNetwork, labels: Iterable[CubeLabel]) -> dict[str, CubeLabel]:
    """The label of every serial number the network measures (ignored measures included). Two labels with
    one serial number, and a measured serial number no label has, are errors (the latter names the
    network's line)."""
    by_serial: dict[str, CubeLabel] = {}
    for label in labels:
        if label.serial_number in by_serial:
            raise BlockError(label.path, f"serial number '{label.serial_number}' is also that of "
                                         f"{by_serial[label.serial_number].path}")
        by_serial[label.serial_number] = label
    for m in network.measures:
        if m.serial_number not in by_serial:
            raise BlockError(network.path, f"measure of point '{m.point_id}': serial number '{m.serial_number}' is "
                                           f"none of the images ({', '.join(sorted(by_serial)) or 'none'})",
                             m.source_line, "SerialNumber")
    used = {m.serial_number for m in network.measures}
    return {s: by_serial[s] for s in sorted(used)}


#: the starts of PVL files that are not cube labels and are passed over without a word
_NOT_IMAGES = (rb"\s*Object\s*=\s*ControlNetwork\b", rb"\s*PDS_VERSION_ID\b")


def _why_not_a_label(path: str) -> str | None:
    """None if ``path`` starts as an ISIS cube label; "" if it is another known kind of PVL file (a control
    network, a PDS label); otherwise why it is not read as an image."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(4096)
    except OSError as exc:
        return f"cannot be read: {exc.strerror}"
    if re.match(rb"\s*Object\s*=\s*IsisCube\b", head, re.IGNORECASE):
        return None
    if any(re.match(pattern, head, re.IGNORECASE) for pattern in _NOT_IMAGES):
        return ""
    try:
        read_pvl(path)
    except BlockError as exc:
        return f"not an ISIS cube label: {exc.reason}" + (f" (line {exc.line})" if exc.line else "")
    return "not an ISIS cube label: it does not start with 'Object = IsisCube'"


def read_image_folder(folder: str | os.PathLike, sensor_extensions: Sequence[str] = (".isd", ".json"),
                      left_out: list[tuple[str, str]] | None = None) -> dict[str, tuple[CubeLabel, str]]:
    """Serial number -> (label, sensor file) of the ISIS cube labels in a folder: every ``*.pvl`` with an
    ``IsisCube`` object, each with the file of the same name and one of ``sensor_extensions`` (the usgscsm/ALE
    ISD). A label without one is an error naming it. Control networks and PDS labels beside them are passed
    over; any other ``*.pvl`` is left out and, when ``left_out`` is a list, added to it as (path, why)."""
    folder = str(folder)
    out: dict[str, tuple[CubeLabel, str]] = {}
    for path in sorted(glob.glob(os.path.join(folder, "*.pvl"))):
        why = _why_not_a_label(path)
        if why is not None:
            if why and left_out is not None:
                left_out.append((path, why))
            continue
        label = read_cube_label(path)
        stem = os.path.splitext(path)[0]
        sensor = next((stem + ext for ext in sensor_extensions if os.path.isfile(stem + ext)), None)
        if sensor is None:
            names = " or ".join(os.path.basename(stem) + ext for ext in sensor_extensions)
            raise BlockError(path, f"no sensor file beside the label ({names})")
        if label.serial_number in out:
            raise BlockError(path, f"serial number '{label.serial_number}' is also that of "
                                   f"{out[label.serial_number][0].path}")
        out[label.serial_number] = (label, sensor)
    return out
