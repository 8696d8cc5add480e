"""Write a results folder (DESIGN.md §4) atomically.

The caller passes every file as data: a dict is written as JSON, a
``(header, columns, formats)`` tuple as CSV, a str as text. The folder appears complete or
not at all (:func:`selfcal.io.atomic.atomic_folder`).
"""
from __future__ import annotations

import json
import math
import os

import numpy as np

from .atomic import atomic_folder, atomic_write
from .table import write_table

__all__ = ["write_results", "write_files", "to_jsonable"]


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
    """Write files into an existing folder, each atomically."""
    for name, content in files.items():
        path = os.path.join(folder, name)
        if isinstance(content, str):
            with atomic_write(path) as handle:
                handle.write(content)
        elif isinstance(content, dict):
            with atomic_write(path) as handle:
                json.dump(to_jsonable(content), handle, indent=2)
                handle.write("\n")
        else:
            header, columns, formats = content
            with atomic_write(path) as handle:
                write_table(handle, header, columns, formats)


def write_results(folder: str | os.PathLike, files: dict) -> None:
    """Replace ``folder`` by a complete results folder holding ``files``."""
    with atomic_folder(folder) as tmp:
        write_files(tmp, files)
