"""Write a results folder (DESIGN.md §4) atomically.

The caller passes every file as data: a dict is written as JSON, a
``(header, columns, formats)`` tuple as CSV, a str as text, bytes as they are; a name
may hold a sub-folder (``figures/residuals.png``). The folder appears complete or not
at all (:func:`selfcal.io.atomic.atomic_folder`).

:func:`read_results` reads a results folder back (for ``selfcal report``);
:func:`results_from_files` gives the same view of files still in memory.
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
from dataclasses import dataclass, field

import numpy as np

from ..errors import BlockError
from .atomic import atomic_folder, atomic_write
from .ply import ply_bytes
from .table import write_table
from .text import is_number, read_text

__all__ = ["summary_schema", "write_results", "write_files", "to_jsonable", "ResultsFolder", "read_results",
           "read_camera_json", "read_results_table", "results_from_files", "RESULT_TABLES", "OPTIONAL_TABLES"]

#: the CSV tables of every results folder that the report reads (DESIGN.md §4), by short name
RESULT_TABLES = {"images": "images.csv", "points": "points.csv", "residuals": "residuals.csv",
                 "correlation": "correlation.csv"}
#: tables that only some results folders have: distortion_grid.csv (frame APs), detector_line.csv (line APs),
#: trajectory.csv ([gnss] or [imu]), check_points.csv (seed 001's across / along / up), parameters.csv
#: (schema 2 and later), attitude_corrections.csv (line scanners), control_loo.csv (the control's leave-one-out test),
#: rolling_shutter.csv (rolling-shutter cameras)
#: distortion_sigma.csv (the σ of the frame APs' correction and the half-block check's difference)
OPTIONAL_TABLES = {"parameters": "parameters.csv", "distortion_grid": "distortion_grid.csv",
                   "distortion_sigma": "distortion_sigma.csv", "control_loo": "control_loo.csv",
                   "detector_line": "detector_line.csv", "trajectory": "trajectory.csv",
                   "check_points": "check_points.csv", "attitude_corrections": "attitude_corrections.csv",
                   "rolling_shutter": "rolling_shutter.csv", "terrain": "terrain.csv"}
#: columns that hold names, not numbers
_TEXT_COLUMNS = {"image_id", "camera_id", "strip_id", "point_id", "role", "parameter", "sensor", "term", "axis",
                 "unit", "owner", "group", "rejected_by", "status"}


def to_jsonable(value):
    """Plain Python for json: NumPy scalars and arrays converted, NaN as null."""
    if isinstance(value, dict):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return [to_jsonable(v) for v in value.tolist()]
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return None if not math.isfinite(value) else float(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def write_files(folder: str, files: dict) -> None:
    """Write files into a folder (created with any sub-folders a name holds), each atomically: bytes and str as
    they are, a dict as JSON (``.ply``: ``{"vertices": structured array, "comments": [...]}`` as PLY), a
    ``(header, columns, formats)`` tuple as CSV."""
    for name, content in files.items():
        path = os.path.join(folder, name)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        if isinstance(content, bytes):
            with atomic_write(path, "wb") as handle:
                handle.write(content)
        elif isinstance(content, str):
            with atomic_write(path) as handle:
                handle.write(content)
        elif isinstance(content, dict) and name.endswith(".ply"):
            with atomic_write(path, "wb") as handle:
                handle.write(ply_bytes(content["vertices"], content.get("comments", ())))
        elif isinstance(content, dict):
            with atomic_write(path) as handle:
                json.dump(to_jsonable(content), handle, indent=2)
                handle.write("\n")
        else:
            header, columns, formats = content
            with atomic_write(path) as handle:
                write_table(handle, header, columns, formats)


def summary_schema() -> dict:
    """The JSON Schema (draft 2020-12) of summary.json, shipped with selfcal (``selfcal/schemas``)."""
    path = os.path.join(os.path.dirname(os.path.dirname(__file__)), "schemas", "summary.schema.json")
    with open(path, encoding="utf-8") as handle:
        return json.load(handle)


def write_results(folder: str | os.PathLike, files: dict) -> None:
    """Replace ``folder`` by a complete results folder holding ``files``."""
    with atomic_folder(folder) as tmp:
        write_files(tmp, files)


@dataclass
class ResultsFolder:
    """A results folder as plain data: JSON files as dicts, CSV tables as columns by name.

    Text columns are object arrays; numeric columns are float arrays with NaN
    where the file has an empty field.
    """

    path: str | None
    summary: dict
    camera: dict
    screening: dict = field(default_factory=dict)
    tables: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)


def _columns(header: list[str], rows: list[list[str]], path: str) -> dict[str, np.ndarray]:
    out = {}
    for j, name in enumerate(header):
        texts = [row[j] for row in rows]
        if name in _TEXT_COLUMNS:
            out[name] = np.array(texts, dtype=object)
            continue
        try:
            out[name] = np.array([float(t) if t.strip() else math.nan for t in texts], dtype=float)
        except ValueError:
            bad = next(i for i, t in enumerate(texts) if t.strip() and not is_number(t))
            raise BlockError(path, f"'{texts[bad]}' is not a number", bad + 2, name) from None
    return out



def _read_csv(path: str) -> dict[str, np.ndarray]:
    try:
        lines = list(csv.reader(io.StringIO(read_text(path), newline="")))
    except csv.Error as exc:
        raise BlockError(path, f"not a CSV table: {exc}") from None
    if not lines:
        raise BlockError(path, "the file is empty; expected a header line")
    header, rows = lines[0], lines[1:]
    for k, row in enumerate(rows):
        if len(row) != len(header):
            raise BlockError(path, f"{len(row)} fields where the header has {len(header)}", k + 2)
    return _columns(header, rows, path)


def _read_json(path: str) -> dict:
    try:
        return json.loads(read_text(path))
    except json.JSONDecodeError as exc:
        raise BlockError(path, f"not valid JSON: {exc.msg}", exc.lineno) from None


def read_results(folder: str | os.PathLike) -> ResultsFolder:
    """Read the files of a results folder that the report needs; a missing one is a BlockError."""
    folder = os.fspath(folder)
    if not os.path.isdir(folder):
        raise BlockError(folder, "no such results folder")
    def path(name):
        p = os.path.join(folder, name)
        if not os.path.isfile(p):
            raise BlockError(p, "missing: is this a results folder written by 'selfcal adjust'?")
        return p
    screening = os.path.join(folder, "screening.json")
    summary, camera = _read_json(path("summary.json")), _read_json(path("camera.json"))
    tables = {key: _read_csv(path(name)) for key, name in RESULT_TABLES.items()}
    tables |= {key: _read_csv(os.path.join(folder, name)) for key, name in OPTIONAL_TABLES.items()
               if os.path.isfile(os.path.join(folder, name))}
    return ResultsFolder(
        path=folder,
        summary=summary,
        camera=camera,
        screening=_read_json(screening) if os.path.isfile(screening) else {},
        tables=tables)


def read_camera_json(folder: str | os.PathLike) -> dict:
    """camera.json of a results folder (the calibration, for exports), its structure checked
    (:func:`selfcal.io.camera_json.read_camera_json`); missing or unreadable: BlockError."""
    from .camera_json import read_camera_json as read
    return read(folder)


def read_results_table(folder: str | os.PathLike, name: str) -> dict[str, np.ndarray]:
    """One CSV table of a results folder (``parameters.csv``) as columns by name; missing: BlockError."""
    folder = os.fspath(folder)
    if not os.path.isdir(folder):
        raise BlockError(folder, "no such results folder")
    path = os.path.join(folder, name)
    if not os.path.isfile(path):
        raise BlockError(path, "missing: is this a results folder written by 'selfcal adjust'?")
    return _read_csv(path)


def results_from_files(files: dict, path: str | None = None) -> ResultsFolder:
    """The view :func:`read_results` gives, of results-folder files still in memory.

    JSON contents pass through :func:`to_jsonable`, so the numbers are those the
    files hold.
    """
    def table(content):
        header, columns, _ = content
        out = {}
        for name, column in zip(header, columns):
            values = np.asarray(column)
            out[name] = values.astype(object) if name in _TEXT_COLUMNS else values.astype(float)
        return out
    return ResultsFolder(
        path=path,
        summary=to_jsonable(files["summary.json"]),
        camera=to_jsonable(files.get("camera.json", {})),
        screening=to_jsonable(files.get("screening.json", {})),
        tables={key: table(files[name]) for key, name in (RESULT_TABLES | OPTIONAL_TABLES).items()
                if name in files})
