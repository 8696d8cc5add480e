"""Strict CSV tables: every defect is a :class:`~selfcal.errors.BlockError`
naming the file, the line and the column.

A table is described by its columns; each column is a string, a number that
must be given, or a number that may be left empty (read as NaN). Extra columns
are an error (a misspelt header must not be silently ignored), and so are NaN
or infinite numbers written out, wrong field counts and duplicate headers.
"""
from __future__ import annotations

import contextlib
import csv
import gc
import io
import math
import os
from dataclasses import dataclass
from typing import TextIO

import numpy as np

from ..errors import BlockError
from .text import read_text

__all__ = ["Column", "Table", "read_table", "write_table"]

STR, NUM, OPT_NUM = "str", "num", "opt_num"


@dataclass(frozen=True)
class Column:
    """One column: its header name, kind and whether the header must appear."""

    name: str
    kind: str = STR
    required: bool = True


@dataclass(frozen=True)
class Table:
    """Columns by name (str columns as object arrays, numbers as float) and the
    1-based file line of every row."""

    path: str
    columns: dict[str, np.ndarray]
    line: np.ndarray

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    def __contains__(self, name: str) -> bool:
        return name in self.columns

    def __len__(self) -> int:
        return len(self.line)


def _parse_number(text: str, path: str, line: int, column: str, allow_empty: bool) -> float:
    text = text.strip()
    if text == "":
        if allow_empty:
            return math.nan
        raise BlockError(path, "empty value where a number is required", line, column)
    try:
        value = float(text)
    except ValueError:
        raise BlockError(path, f"'{text}' is not a number", line, column) from None
    if not math.isfinite(value):
        raise BlockError(path, f"'{text}' is not a finite number (NaN and infinity are not allowed)",
                         line, column)
    return value


def read_table(path: str | os.PathLike, columns: list[Column]) -> Table:
    """Read a comma-separated table with a header line.

    Blank lines and lines starting with ``#`` are skipped.
    """
    path = str(path)
    if not os.path.isfile(path):
        raise BlockError(path, "file not found")
    with _collector_paused():
        return _read_table(path, {c.name: c for c in columns}, columns)


@contextlib.contextmanager
def _collector_paused():
    """Python's cyclic garbage collector paused while a table's rows are built: tens of thousands of small lists
    set off its scans over every object made so far (BAL problem-49's folder: 0.2 s of a 0.45 s read), and rows
    hold no reference cycles for it to find."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def _read_table(path: str, spec: dict, columns: list[Column]) -> Table:
    reader = csv.reader(io.StringIO(read_text(path), newline=""))
    rows = []
    try:
        for fields in reader:
            rows.append((reader.line_num, fields))
    except csv.Error as exc:
        raise BlockError(path, f"not a CSV line: {exc}", reader.line_num + 1) from None
    rows = [(n, r) for n, r in rows if r and "".join(r).strip() and not r[0].lstrip().startswith("#")]
    if not rows:
        raise BlockError(path, "empty file: a header line is required", 1)
    header_line, header = rows[0]
    header = [h.strip() for h in header]
    seen: set[str] = set()
    for name in header:
        if name in seen:
            raise BlockError(path, "duplicated column", header_line, name)
        seen.add(name)
        if name not in spec:
            known = ", ".join(spec)
            raise BlockError(path, f"unknown column (known: {known})", header_line, name)
    for column in columns:
        if column.required and column.name not in seen:
            raise BlockError(path, "missing column", header_line, column.name)
    for line, fields in rows[1:]:
        if len(fields) != len(header):
            raise BlockError(path, f"expected {len(header)} fields, found {len(fields)}", line)
    lines = np.array([line for line, _ in rows[1:]], dtype=np.int64)
    texts = list(zip(*(fields for _, fields in rows[1:]))) or [()] * len(header)
    out = _columns_at_once(header, texts, spec)
    if out is None:                     # a value to refuse or an empty optional one: value by value, in line order
        out = _columns_value_by_value(path, header, rows[1:], spec)
    return Table(path, out, lines)


def _columns_at_once(header: list[str], texts: list[tuple], spec: dict) -> dict[str, np.ndarray] | None:
    """Each column converted in one pass (``float`` of every text, as :func:`_parse_number` does); None when a
    number column holds anything else than finite numbers, for the value-by-value reading to say where."""
    out: dict[str, np.ndarray] = {}
    for name, column in zip(header, texts):
        if spec[name].kind == STR:
            out[name] = np.array([text.strip() for text in column], dtype=object)
            continue
        cells = np.array(column, dtype=object)
        if spec[name].kind == OPT_NUM:
            empty = np.array([text.strip() == "" for text in column], dtype=bool)
            cells[empty] = "nan"
        try:
            values = cells.astype(float)
        except (ValueError, TypeError):
            return None
        if spec[name].kind == OPT_NUM:
            if not np.isfinite(values[~empty]).all():
                return None
            out[name] = values
            continue
        if not np.isfinite(values).all():
            return None
        out[name] = values
    return out


def _columns_value_by_value(path: str, header: list[str], rows: list, spec: dict) -> dict[str, np.ndarray]:
    data: dict[str, list] = {name: [] for name in header}
    for line, fields in rows:
        for name, text in zip(header, fields):
            kind = spec[name].kind
            if kind == STR:
                data[name].append(text.strip())
            else:
                data[name].append(_parse_number(text, path, line, name, kind == OPT_NUM))
    return {name: np.array(data[name], dtype=object if spec[name].kind == STR else float) for name in header}


def _quoted(text: str) -> str:
    """A CSV field as RFC 4180 writes it: quoted when it holds a comma, a quote or a line break."""
    if any(c in text for c in ',"\n\r'):
        return '"' + text.replace('"', '""') + '"'
    return text


def _column_text(column, fmt: str) -> list[str]:
    values = np.asarray(column).tolist()
    if fmt == "":
        # each distinct text quoted once (an observation table repeats its few thousand ids 300,000 times)
        quoted = {v: _quoted(str(v)) for v in set(values)}
        return [quoted[v] for v in values]
    return ["" if isinstance(v, float) and not math.isfinite(v) else format(v, fmt) for v in values]


def write_table(handle: TextIO, header: list[str], columns: list, formats: list[str]) -> None:
    """Write columns (equal-length sequences) as CSV to an open text handle.

    ``formats`` are ``format()`` specifications per column (``""`` for
    strings); NaN numbers are written as empty fields.
    """
    handle.write(",".join(_quoted(h) for h in header) + "\n")
    texts = [_column_text(c, f) for c, f in zip(columns, formats)]
    if texts and texts[0]:
        handle.write("\n".join(",".join(row) for row in zip(*texts)))
        handle.write("\n")
