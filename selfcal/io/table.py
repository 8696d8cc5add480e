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
import itertools
import math
import operator
import os
import re
from dataclasses import dataclass
from typing import Iterator, Sequence, TextIO

import numpy as np

from ..errors import BlockError
from .text import UTF8_BOM, decode_utf8, without_bom

__all__ = ["Column", "Table", "read_table", "read_table_chunks", "write_table"]

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


#: rows a chunk of a table holds at most while it is read (:func:`read_table_chunks`): its text fields are Python
#: objects, about 350 bytes a row of observations.csv, so a chunk holds some 23 MB of them whatever the file's size
ROWS_PER_CHUNK = 1 << 16

#: bytes of the file decoded at a time (held as text twice: the decoded block and the StringIO that the reader reads,
#: which keeps four bytes a character)
BYTES_PER_BLOCK = 1 << 20


def read_table(path: str | os.PathLike, columns: list[Column]) -> Table:
    """Read a comma-separated table with a header line.

    Blank lines and lines starting with ``#`` are skipped.
    """
    chunks = list(read_table_chunks(path, columns))
    first = chunks[0]
    if len(chunks) == 1:
        return first
    columns_read = {name: np.concatenate([chunk.columns[name] for chunk in chunks]) for name in first.columns}
    return Table(first.path, columns_read, np.concatenate([chunk.line for chunk in chunks]))


def read_table_chunks(path: str | os.PathLike, columns: list[Column],
                      rows_per_chunk: int | None = None) -> Iterator[Table]:
    """The table of :func:`read_table` in consecutive chunks of at most ``rows_per_chunk`` rows (ROWS_PER_CHUNK by
    default; at least one chunk, empty for a table of a header alone), read and checked as they come: the text of one
    chunk at a time is held, not the file's. A defect is the BlockError of :func:`read_table`, raised with the chunk
    that holds it: the first in line order."""
    path = str(path)
    if not os.path.isfile(path):
        raise BlockError(path, "file not found")
    spec = {c.name: c for c in columns}
    rows_per_chunk = rows_per_chunk or ROWS_PER_CHUNK
    reader = csv.reader(itertools.chain.from_iterable(_text_blocks(path)))      # a line at a time, in C
    header: list[str] | None = None
    done = 0                                   # lines the reader has consumed before this chunk
    yielded = False
    while True:
        with _collector_paused():
            try:
                rows = list(itertools.islice(reader, rows_per_chunk))
            except csv.Error as exc:
                raise BlockError(path, f"not a CSV line: {exc}", reader.line_num + 1) from None
            last = len(rows) < rows_per_chunk                   # the reader has given every row
            lines = _row_lines(rows, done, reader.line_num)
            done = reader.line_num
            lengths = np.fromiter(map(len, rows), np.int64, len(rows))
            if (lengths == 0).any() or _SUSPECT_START.search("\n".join(map(operator.itemgetter(0), rows))):
                kept = [i for i, fields in enumerate(rows) if not _blank_or_comment(fields)]
                rows, lines, lengths = [rows[i] for i in kept], lines[kept], lengths[kept]
            if header is None and rows:
                header = [h.strip() for h in rows[0]]
                _check_header(path, header, int(lines[0]), spec, columns)
                rows, lines, lengths = rows[1:], lines[1:], lengths[1:]
            if header is None:
                if last:
                    raise BlockError(path, "empty file: a header line is required", 1)
                continue
            table = _chunk_table(path, header, spec, rows, lines, lengths) if rows or (last and not yielded) else None
        if table is not None:
            yield table
            yielded = True
        if last:
            return


def _text_blocks(path: str) -> Iterator[io.StringIO]:
    """The text of the file in blocks of whole lines, each a ``StringIO(text, newline="")`` (UTF-8, a leading
    byte-order mark dropped, line endings kept), decoded BYTES_PER_BLOCK at a time; bytes that are not UTF-8 text or a
    NUL are the BlockError of :func:`~selfcal.io.text.decode_text`, on their line."""
    try:
        handle = open(path, "rb")
    except OSError as exc:
        raise BlockError(path, f"cannot read the file: {exc.strerror}") from None
    with handle:
        carry = b""
        lines_before = 0
        first = True
        while True:
            try:
                data = handle.read(BYTES_PER_BLOCK)
            except OSError as exc:
                raise BlockError(path, f"cannot read the file: {exc.strerror}") from None
            end = not data
            if first:
                while 0 < len(data) < len(UTF8_BOM):        # enough bytes to see a byte-order mark
                    more = handle.read(BYTES_PER_BLOCK)
                    if not more:
                        break
                    data += more
                data = without_bom(data, path)
                first = False
            if not end:
                block = carry + data
                cut = block.rfind(b"\n") + 1
                if cut == 0:                    # no line end yet: the next read continues the line
                    carry = block
                    continue
                block, carry = block[:cut], block[cut:]
            else:
                block, carry = carry, b""
                if not block:
                    return
            text = decode_utf8(block, path, lines_before)
            lines_before += block.count(b"\n")
            yield io.StringIO(text, newline="")


def _row_lines(rows: list, before: int, after: int) -> np.ndarray:
    """The file line of each row that the reader gave (its last line, as ``csv.reader.line_num`` counts them),
    ``before`` and ``after`` the reader's count of lines before and after the rows: consecutive unless a quoted
    field holds a line break."""
    if after - before == len(rows):
        return np.arange(before + 1, after + 1, dtype=np.int64)
    spans = [1 + sum(f.count("\n") + f.count("\r") - f.count("\r\n") for f in fields) for fields in rows]
    return before + np.cumsum(np.array(spans, dtype=np.int64))


#: a first field that may make its row blank or a comment (empty, or starting with a blank or ``#``); rows whose
#: first fields all start otherwise are kept without a look at each
_SUSPECT_START = re.compile(r"^(?:[\s#]|$)", re.MULTILINE)


def _blank_or_comment(fields: list[str]) -> bool:
    """A row without a value, or whose first field starts with ``#`` (after blanks)."""
    if not fields:
        return True
    first = fields[0][:1]
    if first and first != "#" and not first.isspace():
        return False
    return not "".join(fields).strip() or fields[0].lstrip().startswith("#")


def _check_header(path: str, header: list[str], header_line: int, spec: dict, columns: list[Column]) -> None:
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


def _chunk_table(path: str, header: list[str], spec: dict, rows: list, lines: np.ndarray,
                 lengths: np.ndarray) -> Table:
    if (lengths != len(header)).any():
        bad = int(np.argmax(lengths != len(header)))
        # a value that the rows before it cannot hold is the first defect in line order, whatever the chunks
        _columns_value_by_value(path, header, list(zip(lines[:bad].tolist(), rows[:bad])), spec)
        raise BlockError(path, f"expected {len(header)} fields, found {lengths[bad]}", int(lines[bad]))
    texts = list(zip(*rows)) or [()] * len(header)
    out = _columns_at_once(header, texts, spec)
    if out is None:                     # a value to refuse or an empty optional one: value by value, in line order
        out = _columns_value_by_value(path, header, list(zip(lines.tolist(), rows)), spec)
    return Table(path, out, lines)


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


def _columns_at_once(header: list[str], texts: list[tuple], spec: dict) -> dict[str, np.ndarray] | None:
    """Each column converted in one pass (``float`` of every text, as :func:`_parse_number` does); None when a
    number column holds anything else than finite numbers, for the value-by-value reading to say where."""
    out: dict[str, np.ndarray] = {}
    for name, column in zip(header, texts):
        if spec[name].kind == STR:
            out[name] = np.array(list(map(str.strip, column)), dtype=object)
            continue
        cells: Sequence[str] = column
        if spec[name].kind == OPT_NUM:
            empty = np.array([text.strip() == "" for text in column], dtype=bool)
            if empty.any():
                cells = ["nan" if blank else text for text, blank in zip(column, empty.tolist())]
        try:
            values = np.fromiter(map(float, cells), np.float64, len(cells))
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
    if "," in text or '"' in text or "\n" in text or "\r" in text:
        return '"' + text.replace('"', '""') + '"'
    return text


#: rows of a table formatted at a time when it is written: their texts are Python objects (about 70 bytes a value)
ROWS_PER_WRITE = 1 << 16


def _column_text(column, fmt: str, quoted: dict | None = None) -> list[str]:
    """The CSV fields of a column (a slice of one): ``format(value, fmt)``, NaN and infinite numbers empty; ``fmt``
    ``""`` writes text, quoted where it needs it (``quoted``: the fields of the texts met so far, kept over the
    slices of a column)."""
    array = np.asarray(column)
    values = array.tolist()                     # Python numbers: format() as the specification says
    if fmt == "":
        # each distinct text quoted once (an observation table repeats its few thousand ids 300,000 times)
        quoted = {} if quoted is None else quoted
        for v in set(values).difference(quoted):
            quoted[v] = _quoted(str(v))
        return list(map(quoted.__getitem__, values))
    texts = list(map(format, values, itertools.repeat(fmt, len(values))))
    if array.dtype.kind == "f":
        for k in np.flatnonzero(~np.isfinite(array)).tolist():
            texts[k] = ""
    elif array.dtype.kind not in "iub":
        for k, v in enumerate(values):
            if isinstance(v, float) and not math.isfinite(v):
                texts[k] = ""
    return texts


def write_table(handle: TextIO, header: list[str], columns: list, formats: list[str]) -> None:
    """Write columns (equal-length sequences) as CSV to an open text handle, ROWS_PER_WRITE rows at a time (the
    texts of those rows are held, not the table's).

    ``formats`` are ``format()`` specifications per column (``""`` for
    strings); NaN numbers are written as empty fields.
    """
    handle.write(",".join(_quoted(h) for h in header) + "\n")
    arrays = [np.asarray(c) for c in columns]
    quoted: list[dict] = [{} for _ in columns]
    n = min((len(a) for a in arrays), default=0)
    for start in range(0, n, ROWS_PER_WRITE):
        part = slice(start, min(n, start + ROWS_PER_WRITE))
        texts = [_column_text(a[part], f, q) for a, f, q in zip(arrays, formats, quoted)]
        handle.write("\n".join(map(",".join, zip(*texts))))
        handle.write("\n")
