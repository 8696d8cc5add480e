"""PAT-B files as Metashape exports them (File > Export Cameras > PAT-B), and the photo blocks of BINGO.

PAT-B (the Stuttgart block adjustment program) exchanges free-format text records separated by blanks:

* ``.im`` image coordinates, one block per photo: a header record with the photo number (Metashape writes the
  camera label when "Use item labels" is on) and optionally the camera constant, then one record per
  measured point ``point_id x y``, the block closed by a record ``-99``. Metashape's export writes x to
  the right and y up ("the direction of the X-axes is to the right, Y-up", Agisoft's article "Export cameras
  in PAT-B format"), in the unit the export's ``.pro`` file states (millimetres or microns), relative to the
  principal point.
  BINGO's tie-point file (Pix4D's ``*_tp_bingo.txt``, :mod:`selfcal.io.pix4d`) has the same layout.
* ``.con`` control points: ``point_id X Y Z`` per record, the file closed by ``-99``.
* ``.ori`` exterior orientations (PAT-B's output), three records per photo: ``photo_id X0 Y0 Z0``, then the
  rotation matrix row by row, ``a11 a12 a13 a21 a22`` and ``a23 a31 a32 a33`` (PCI's "Using PAT-B in
  OrthoEngine": I16,16x,3F16.5 / 5F16.12 / 4F16.12). The matrix A rotates image vectors into object space
  (X - X0 = lambda A x, with x = (x, y, -c) in the image frame, x right, y up): the transpose of selfcal's
  M = R3(kappa) R2(phi) R1(omega). Read here as written; :mod:`selfcal.convert.uav` turns it into M.

Every defect (a short record, a non-number, a block without ``-99``, a photo or point given twice) is a
:class:`~selfcal.errors.BlockError` naming the file and the line. Nothing here converts units.
"""
from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TypedDict

import numpy as np

from ..errors import BlockError
from .text import read_text

__all__ = ["PhotoMeasurements", "ControlPoints", "Orientations", "read_photo_blocks", "read_con", "read_ori",
           "find_patb", "PatbFiles", "numbers"]

END = "-99"


@dataclass(frozen=True)
class PhotoMeasurements:
    """Image coordinates of a ``.im`` or BINGO file, as written (in the file's unit: mm, or microns for a
    PAT-B export that says so)."""

    path: str
    image: np.ndarray            # (m,) photo id of each measurement
    point: np.ndarray            # (m,) point id
    xy_mm: np.ndarray            # (m, 2) x right, y up (the file's unit)
    line: np.ndarray             # (m,) line of the file
    photos: tuple[str, ...]      # photo ids in the file's order
    header: dict                 # photo id -> the header record's other tokens (camera constant, camera name)
    header_line: dict            # photo id -> line of its header record


@dataclass(frozen=True)
class ControlPoints:
    """Control point coordinates (m) with their a-priori sigmas where the file gives them (NaN otherwise)."""

    path: str
    point_id: np.ndarray         # (k,)
    xyz_m: np.ndarray            # (k, 3)
    sigma_m: np.ndarray          # (k, 3) sigma X, Y, Z
    line: np.ndarray             # (k,)
    enabled: np.ndarray          # (k,) bool: False = a check point in the file's own terms


@dataclass(frozen=True)
class Orientations:
    """Exterior orientations as written: perspective centres and image-to-object rotation matrices."""

    path: str
    image: np.ndarray            # (n,)
    position_m: np.ndarray       # (n, 3)
    rotation: np.ndarray         # (n, 3, 3) A: object vector = A @ image vector
    line: np.ndarray             # (n,)


def numbers(path: str, number: int, tokens: Sequence[str], names: Sequence[str]) -> list[float]:
    """``tokens`` as finite floats; a token that is not one is a BlockError naming the line and field."""
    values = []
    for token, name in zip(tokens, names):
        try:
            value = float(token)
        except ValueError:
            raise BlockError(path, f"{name}: '{token}' is not a number", number) from None
        if not math.isfinite(value):
            raise BlockError(path, f"{name}: '{token}' is not a finite number", number)
        values.append(value)
    return values


def _records(path: str, what: str):
    """(line number, tokens) of the non-blank, non-comment lines."""
    for number, line in enumerate(read_text(path, what).splitlines(), start=1):
        tokens = line.split()
        if tokens and not tokens[0].startswith("#"):
            yield number, tokens


def _is_number(token: str) -> bool:
    try:
        return math.isfinite(float(token))
    except ValueError:
        return False


def read_photo_blocks(path: str | os.PathLike, what: str = "PAT-B image coordinate file",
                      end_optional: bool = False) -> PhotoMeasurements:
    """Photo blocks: a header record (photo id [more tokens]), ``point_id x y`` records, ``-99``.

    ``end_optional`` (BINGO as Pix4D's "What is the bingo file" shows it: ``P1060498 H_8.07_6.0525`` then
    ``1006 -1.90643 1.83493`` records, blocks apart by a blank line and no ``-99``): in a file without any ``-99``
    record a header is a record of two fields whose second is not a number (``image camera``), or of one field
    that is not a number; the next header closes the block (a record of three fields is a measurement, its x and
    y checked as numbers). A file with a ``-99`` is read in the closed layout.
    """
    path = os.fspath(path)
    records = list(_records(path, what))
    if end_optional and not any(tokens[0] == END for _, tokens in records):
        return _photo_blocks(path, records, closed=False)
    return _photo_blocks(path, records, closed=True)


def _open_layout_header(tokens: Sequence[str]) -> bool:
    """A header of the layout without ``-99``: ``image camera`` (the camera not a number) or a lone image name."""
    if len(tokens) == 1:
        return not _is_number(tokens[0])
    return len(tokens) == 2 and not _is_number(tokens[1])


def _photo_blocks(path: str, records, closed: bool) -> PhotoMeasurements:
    image, point, xy, lines = [], [], [], []
    photos: list[str] = []
    header: dict[str, tuple[str, ...]] = {}
    header_line: dict[str, int] = {}
    current = None
    seen: set = set()
    last = 0
    for number, tokens in records:
        last = number
        starts = current is None if closed else _open_layout_header(tokens)
        if starts:
            if tokens[0] == END:
                raise BlockError(path, "-99 closes a photo block, but no photo block is open", number)
            current = tokens[0]
            if current in header:
                raise BlockError(path, f"photo '{current}' has a second block (first on line "
                                       f"{header_line[current]})", number)
            photos.append(current)
            header[current] = tuple(tokens[1:])
            header_line[current] = number
            seen = set()
            continue
        if closed and tokens[0] == END:
            current = None
            continue
        if current is None:
            raise BlockError(path, "a 'point_id x y' record before the first image header ('image camera')",
                             number)
        if len(tokens) < 3:
            closing = "or -99 to close" if closed else "or a header 'image camera' after"
            raise BlockError(path, f"expected 'point_id x y' ({closing} photo '{current}'), found "
                                   f"{len(tokens)} field(s)", number)
        x, y = numbers(path, number, tokens[1:3], ("x", "y"))
        if tokens[0] in seen:
            raise BlockError(path, f"point '{tokens[0]}' is measured twice in photo '{current}'", number)
        seen.add(tokens[0])
        image.append(current)
        point.append(tokens[0])
        xy.append((x, y))
        lines.append(number)
    if closed and current is not None:
        raise BlockError(path, f"the block of photo '{current}' (line {header_line[current]}) is not closed by "
                               f"-99: a truncated file?", last)
    if not image:
        raise BlockError(path, "no image measurement in the file")
    return PhotoMeasurements(path, np.array(image, object), np.array(point, object), np.array(xy, float).reshape(-1, 2),
                             np.array(lines, np.int64), tuple(photos), header, header_line)


def read_con(path: str | os.PathLike) -> ControlPoints:
    """A ``.con`` file: ``point_id X Y Z`` records, closed by ``-99`` (records after it are ignored)."""
    path = os.fspath(path)
    ids, xyz, lines = [], [], []
    first: dict[str, int] = {}
    closed = False
    for number, tokens in _records(path, "PAT-B control file"):
        if tokens[0] == END:
            closed = True
            break
        if len(tokens) < 4:
            raise BlockError(path, f"expected 'point_id X Y Z', found {len(tokens)} field(s)", number)
        if tokens[0] in first:
            raise BlockError(path, f"control point '{tokens[0]}' is given twice (first on line {first[tokens[0]]})",
                             number)
        first[tokens[0]] = number
        ids.append(tokens[0])
        xyz.append(numbers(path, number, tokens[1:4], ("X", "Y", "Z")))
        lines.append(number)
    if not closed:
        raise BlockError(path, "the control file is not closed by -99: a truncated file?")
    if not ids:
        raise BlockError(path, "no control point in the file")
    k = len(ids)
    return ControlPoints(path, np.array(ids, object), np.array(xyz, float), np.full((k, 3), np.nan),
                         np.array(lines, np.int64), np.ones(k, bool))


def read_ori(path: str | os.PathLike) -> Orientations:
    """A PAT-B ``.ori`` file: per photo ``id X0 Y0 Z0`` / ``a11 a12 a13 a21 a22`` / ``a23 a31 a32 a33``."""
    path = os.fspath(path)
    records = [(n, t) for n, t in _records(path, "PAT-B orientation file") if t[0] != END]
    image, position, rotation, lines = [], [], [], []
    first: dict[str, int] = {}
    for k in range(0, len(records), 3):
        group = records[k:k + 3]
        number, head = group[0]
        if len(group) < 3:
            raise BlockError(path, f"photo '{head[0]}' has {len(group)} of its 3 records: a truncated file?",
                             group[-1][0])
        if len(head) < 4:
            raise BlockError(path, f"expected 'photo_id X0 Y0 Z0', found {len(head)} field(s)", number)
        (n2, row2), (n3, row3) = group[1], group[2]
        if len(row2) != 5:
            raise BlockError(path, f"expected the 5 elements a11 a12 a13 a21 a22 of photo '{head[0]}'s rotation "
                                   f"matrix, found {len(row2)}", n2)
        if len(row3) != 4:
            raise BlockError(path, f"expected the 4 elements a23 a31 a32 a33 of photo '{head[0]}'s rotation "
                                   f"matrix, found {len(row3)}", n3)
        if head[0] in first:
            raise BlockError(path, f"photo '{head[0]}' is given twice (first on line {first[head[0]]})", number)
        first[head[0]] = number
        a = numbers(path, n2, row2, ("a11", "a12", "a13", "a21", "a22")) + \
            numbers(path, n3, row3, ("a23", "a31", "a32", "a33"))
        image.append(head[0])
        position.append(numbers(path, number, head[1:4], ("X0", "Y0", "Z0")))
        rotation.append(np.array(a).reshape(3, 3))
        lines.append(number)
    if not image:
        raise BlockError(path, "no orientation in the file")
    return Orientations(path, np.array(image, object), np.array(position, float), np.array(rotation),
                        np.array(lines, np.int64))


class PatbFiles(TypedDict):
    """The files of a PAT-B export: the image coordinates, and the control and orientations where present."""

    im: str
    con: str | None
    ori: str | None


def find_patb(source: str) -> PatbFiles:
    """The ``.im``, ``.con`` and ``.ori`` files of a PAT-B export: ``source`` is one of them or their stem
    (``export`` for ``export.im``...), or a folder holding exactly one ``.im``. Missing ``.con``/``.ori`` are None."""
    if os.path.isdir(source):
        found = sorted(f for f in os.listdir(source) if f.lower().endswith(".im"))
        if len(found) != 1:
            raise BlockError(source, f"expected one PAT-B .im file in the folder, found {len(found)}"
                                     + (f" ({', '.join(found)})" if found else ""))
        stem = os.path.join(source, found[0][:-3])
    else:
        stem, ext = os.path.splitext(source)
        if ext.lower() not in (".im", ".con", ".ori"):
            stem = source

    def existing(ext: str) -> str | None:
        return next((c for c in (stem + ext, stem + ext.upper()) if os.path.isfile(c)), None)

    im = existing(".im")
    if im is None:
        raise BlockError(stem + ".im", "file not found: a PAT-B import needs the image coordinates (.im)")
    return {"im": im, "con": existing(".con"), "ori": existing(".ori")}
