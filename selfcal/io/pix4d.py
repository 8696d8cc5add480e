"""Pix4D's ``params/`` folder (``PROJECT/1_initial/params``) as plain data.

Files read (Pix4D's "What does the Output Params Folder contain"):

* ``*_tp_bingo.txt`` (or ``*_bingo.txt``): the BINGO tie-point file, image coordinates of the GCPs, check points and
  a selection of automatic tie points on the original (distorted) images, one block per image: a header record
  ``image_name camera_name``, ``point_id x y`` records, ``-99`` (:func:`selfcal.io.patb.read_photo_blocks`); or,
  as the example of Pix4D's "What is the bingo file" shows it, the blocks without ``-99`` (the next
  ``image_name camera_name`` header closes a block).
  Pix4D's "What is the bingo file": "The origin of the image coordinate system is the center of the image.
  The coordinates are given in millimeters"; x right and y up as BINGO's photo coordinates.
* ``*_pix4d_calibrated_internal_camera_parameters.cam``: per camera ``F`` (focal length, mm), ``Px``, ``Py``
  (principal point, mm from the upper-left corner of the sensor, x right, y down, as the K matrix of
  ``*_calibrated_camera_parameters.txt`` gives it in pixels), ``K1 K2 K3`` (radial) and ``T1 T2``
  (tangential distortion), after a comment ``#Focal Length mm assuming a sensor width of WxHmm``.
* ``*_calibrated_external_camera_parameters.txt``: a header line, then ``imageName X Y Z Omega Phi Kappa``,
  angles in degrees in the PATB convention (Pix4D's "How are the internal and external camera parameters
  defined": R = Rx(omega) Ry(phi) Rz(kappa) maps the camera frame, x right, y up, z backwards, into the world).
* ``*_calibrated_camera_parameters.txt``: read for the image size only (a record ``fileName imageWidth
  imageHeight`` opens each image's block).
* ``*_measured_gcps_position.txt`` (or, where it is absent, ``*_measured_estimated_gcps_position.txt``): the GCPs
  and check points as they were imported into the project, written "if GCPs have been imported" (Pix4D's "What
  does the Output Params Folder contain"). Pix4D does not document their columns; the exports seen in public
  (a header line ``#Label,X/East,Y/North,Z/Altitude,Accuracy_(m),Error_(m),X_error,...,X_est,...``; a header
  ``GCP label, GCP measured X, GCP measured Y, GCP measured Z, ...`` separated by ``, ``) name them in a header,
  so the columns are found by name (:func:`read_gcps_position`): the label, the measured X, Y, Z and the
  accuracies; errors and estimated positions are left out. A file without a header is PIX4D's GCP import layout
  (:func:`selfcal.io.metashape.read_reference_csv`).
"""
from __future__ import annotations

import csv
import glob
import os
import re
from dataclasses import dataclass

import numpy as np

from ..errors import BlockError
from .patb import ControlPoints, PhotoMeasurements, numbers, read_photo_blocks
from .text import is_number, read_text

__all__ = ["Pix4dCamera", "Pix4dExternal", "Pix4dParams", "read_gcps_position", "read_pix4d_params",
           "params_folder"]


@dataclass(frozen=True)
class Pix4dCamera:
    path: str
    focal_mm: float
    principal_point_mm: tuple[float, float]    # from the sensor's upper-left corner, x right, y down
    sensor_width_mm: float
    sensor_height_mm: float
    width_px: int
    height_px: int
    distortion: dict                           # K1, K2, K3, T1, T2


@dataclass(frozen=True)
class Pix4dExternal:
    path: str
    image: np.ndarray          # (n,)
    position_m: np.ndarray     # (n, 3)
    opk_deg: np.ndarray        # (n, 3) omega, phi, kappa (PATB convention)
    line: np.ndarray           # (n,)


@dataclass(frozen=True)
class Pix4dParams:
    folder: str
    bingo: PhotoMeasurements
    camera: Pix4dCamera
    external: Pix4dExternal | None
    gcps_path: str | None = None               # *_measured_gcps_position.txt, where the folder has one


def params_folder(source: str) -> str:
    """The params folder of ``source`` (the folder itself, or a Pix4D project holding ``1_initial/params``)."""
    nested = os.path.join(source, "1_initial", "params")
    if os.path.isdir(nested):
        return nested
    if not os.path.isdir(source):
        raise BlockError(source, "not a folder: give Pix4D's params folder (PROJECT/1_initial/params) or the project")
    return source


def _one(folder: str, patterns: tuple[str, ...], what: str) -> str:
    """The one file of the folder matching the first of ``patterns`` that any file matches; none: an error."""
    found = _one_or_none(folder, patterns)
    if found is None:
        raise BlockError(folder, f"no {what} ({' or '.join(patterns)}) in the params folder")
    return found


def _one_or_none(folder: str, patterns: tuple[str, ...], exclude: str | None = None) -> str | None:
    """As :func:`_one`, None where no file matches (names holding ``exclude`` left out)."""
    found: list[str] = []
    for pattern in patterns:
        found = sorted(f for f in glob.glob(os.path.join(folder, pattern)) if not (exclude and exclude in f))
        if found:
            break
    if not found:
        return None
    if len(found) > 1:
        raise BlockError(folder, f"{len(found)} files match {patterns[0]}: {', '.join(map(os.path.basename, found))}")
    return found[0]


def _image_size(path: str) -> tuple[int, int]:
    sizes: dict[tuple[int, int], int] = {}
    for number, line in enumerate(read_text(path, "Pix4D calibrated camera parameters").splitlines(), start=1):
        tokens = line.split()
        if len(tokens) == 3 and tokens[1].isdigit() and tokens[2].isdigit() and not is_number(tokens[0]):
            sizes.setdefault((int(tokens[1]), int(tokens[2])), number)
    if not sizes:
        raise BlockError(path, "no 'fileName imageWidth imageHeight' record: the image size is unknown (give "
                               "--image-size)")
    if len(sizes) > 1:
        (a, _), (b, second) = list(sizes.items())[:2]
        raise BlockError(path, f"images of two sizes ({a[0]}x{a[1]} and {b[0]}x{b[1]}); selfcal imports one camera",
                         second)
    return next(iter(sizes))


def read_cam(path: str, width_px: int, height_px: int) -> Pix4dCamera:
    """The first camera of a Pix4D ``.cam`` file."""
    values, sensor, seen_cameras = {}, None, 0
    for number, line in enumerate(read_text(path, "Pix4D camera file").splitlines(), start=1):
        text = line.strip()
        if "camera calibration file" in text:
            seen_cameras += 1
            if seen_cameras > 1:
                break
            continue
        match = re.search(r"sensor width of\s*([-+0-9.eE]+)\s*x\s*([-+0-9.eE]+)\s*mm", text)
        if match:
            sensor = tuple(numbers(path, number, match.groups(), ("sensor width", "sensor height")))
            continue
        tokens = text.split()
        if len(tokens) == 2 and tokens[0] in ("F", "Px", "Py", "K1", "K2", "K3", "T1", "T2"):
            values[tokens[0]] = numbers(path, number, tokens[1:], (tokens[0],))[0]
        elif tokens and not text.startswith("#"):
            raise BlockError(path, f"expected 'KEY value' (F, Px, Py, K1..K3, T1, T2), found '{text[:60]}'", number)
    missing = [k for k in ("F", "Px", "Py") if k not in values]
    if missing:
        raise BlockError(path, f"the camera has no {', '.join(missing)}")
    if sensor is None or not (sensor[0] > 0 and sensor[1] > 0):
        raise BlockError(path, "no '#Focal Length mm assuming a sensor width of WxHmm' line: the pixel size is unknown")
    return Pix4dCamera(path, values["F"], (values["Px"], values["Py"]), sensor[0], sensor[1], width_px, height_px,
                       {k: values.get(k, 0.0) for k in ("K1", "K2", "K3", "T1", "T2")})


def read_external(path: str) -> Pix4dExternal:
    """``imageName X Y Z Omega Phi Kappa`` records after a header line."""
    image, position, opk, lines = [], [], [], []
    first: dict[str, int] = {}
    for number, line in enumerate(read_text(path, "Pix4D external camera parameters").splitlines(), start=1):
        tokens = line.split()
        if not tokens or tokens[0].startswith("#") or tokens[0] == "imageName":
            continue
        if len(tokens) != 7:
            raise BlockError(path, f"expected 'imageName X Y Z Omega Phi Kappa', found {len(tokens)} field(s)", number)
        if tokens[0] in first:
            raise BlockError(path, f"image '{tokens[0]}' is given twice (first on line {first[tokens[0]]})", number)
        first[tokens[0]] = number
        values = numbers(path, number, tokens[1:], ("X", "Y", "Z", "Omega", "Phi", "Kappa"))
        image.append(tokens[0])
        position.append(values[:3])
        opk.append(values[3:])
        lines.append(number)
    if not image:
        raise BlockError(path, "no image in the file")
    return Pix4dExternal(path, np.array(image, object), np.array(position, float), np.array(opk, float),
                         np.array(lines, np.int64))


def read_pix4d_params(source: str, image_size: tuple[int, int] | None = None) -> Pix4dParams:
    """The BINGO file, the first calibrated camera and the external parameters of a Pix4D params folder;
    ``image_size`` (px) where the folder has no ``*_calibrated_camera_parameters.txt``."""
    folder = params_folder(os.fspath(source))
    bingo = read_photo_blocks(_one(folder, ("*_tp_bingo.txt", "*bingo.txt"), "BINGO tie-point file"),
                              "Pix4D BINGO tie-point file", end_optional=True)
    cam_path = _one(folder, ("*_pix4d_calibrated_internal_camera_parameters.cam",), "calibrated internal parameters")
    if image_size is None:
        size_file = _one(folder, ("*_calibrated_camera_parameters.txt",), "calibrated camera parameters (image size)")
        image_size = _image_size(size_file)
    camera = read_cam(cam_path, *image_size)
    ext_path = _one_or_none(folder, ("*_calibrated_external_camera_parameters.txt",), exclude="wgs84")
    gcp_path = _one_or_none(folder, GCPS_POSITION_FILES)
    return Pix4dParams(folder, bingo, camera, read_external(ext_path) if ext_path else None, gcp_path)


#: the params folder's files of the project's GCPs, the first found is read
GCPS_POSITION_FILES = ("*_measured_gcps_position.txt", "*_measured_estimated_gcps_position.txt")

#: words of a column name that make it something other than the measured (input) position or its accuracy
_NOT_MEASURED = ("error", "est", "residual", "rms", "projection", "image", "marked")


def _column_kind(name: str) -> str | None:
    """What a header column of a GCP position file holds: label, x, y, z, accuracy_xy, accuracy_z, accuracy
    (all axes) or None (a column left out)."""
    n = name.strip().lstrip("#").strip().strip('"').lower()
    if "label" in n or n in ("name", "id", "gcp", "point"):
        return "label"
    if any(word in n for word in _NOT_MEASURED):
        return None
    if "accuracy" in n or "sigma" in n or n.startswith("std"):
        if any(word in n for word in ("horz", "horiz", "xy", "plan")):
            return "accuracy_xy"
        if any(word in n for word in ("vert", "_z", " z", "height")):
            return "accuracy_z"
        return "accuracy"
    core = re.sub(r"\b(gcp|measured)\b", "", n).strip(" _:")
    for kind, starts in (("x", ("x", "east")), ("y", ("y", "north")), ("z", ("z", "alt", "height", "elev"))):
        if core.startswith(starts):
            return kind
    return None


def _fields(line: str) -> list[str]:
    return [f.strip().strip('"').strip() for f in next(csv.reader([line], skipinitialspace=True))]


def read_gcps_position(path: str | os.PathLike) -> ControlPoints:
    """The control of a Pix4D GCP position file (the module's docstring): columns found by the header's names;
    an empty accuracy is NaN (the import's default sigma applies). A file whose first line is not a header is
    read as PIX4D's GCP import layout."""
    from .metashape import read_reference_csv

    path = os.fspath(path)
    lines = read_text(path, "Pix4D GCP position file").splitlines()
    head = next(((k, line) for k, line in enumerate(lines, start=1) if line.strip()), None)
    if head is None:
        raise BlockError(path, "no point in the file")
    head_number, head_line = head
    names = _fields(head_line)
    if len(names) >= 4 and is_number(names[1]):
        return read_reference_csv(path)                 # no header: label, X, Y, Z[, accuracies]
    kinds = [_column_kind(n) for n in names]
    column = {}
    for k, kind in enumerate(kinds):
        if kind is not None and kind not in column:
            column[kind] = k
    missing = [what for what in ("label", "x", "y", "z") if what not in column]
    if missing:
        raise BlockError(path, f"the header names no {', '.join(missing)} column (found: {', '.join(names)[:200]})",
                         head_number)
    ids, xyz, sigma, numbers_ = [], [], [], []
    first: dict[str, int] = {}
    for number, line in enumerate(lines[head_number:], start=head_number + 1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        fields = _fields(text)
        if len(fields) < len(names) and len(fields) <= max(column.values()):
            raise BlockError(path, f"expected {len(names)} fields as the header names, found {len(fields)}", number)
        label = fields[column["label"]]
        if not label:
            raise BlockError(path, "a point without a label", number)
        if label in first:
            raise BlockError(path, f"point '{label}' is given twice (first on line {first[label]})", number)
        first[label] = number
        coords = numbers(path, number, [fields[column[a]] for a in ("x", "y", "z")],
                         [names[column[a]] for a in ("x", "y", "z")])

        def accuracy(kind: str) -> float:
            if kind not in column or not fields[column[kind]]:
                return float("nan")
            value = numbers(path, number, [fields[column[kind]]], [names[column[kind]]])[0]
            if value <= 0:
                raise BlockError(path, f"{names[column[kind]]} must be positive, found {value:g}", number)
            return value

        every, plan, height = accuracy("accuracy"), accuracy("accuracy_xy"), accuracy("accuracy_z")
        plan = every if np.isnan(plan) else plan
        height = every if np.isnan(height) else height
        ids.append(label)
        xyz.append(coords)
        sigma.append([plan, plan, height])
        numbers_.append(number)
    if not ids:
        raise BlockError(path, "no point in the file")
    return ControlPoints(path, np.array(ids, object), np.array(xyz, float), np.array(sigma, float),
                         np.array(numbers_, np.int64), np.ones(len(ids), bool))
