"""OpenCV FileStorage files (YAML, XML, JSON) read without OpenCV: the top-level nodes, checked.

``cv2.FileStorage`` trusts what it reads: a mutated file makes it raise (``cv2.error``, ``SystemError``),
allocate what a ``rows``/``cols`` pair asks for (86 GB) or abort the process (SIGABRT, which no ``except``
catches). So selfcal never hands it a file to read: this module parses the three formats with PyYAML's
composer, expat and JSON, and checks every ``!!opencv-matrix`` (``type_id="opencv-matrix"``) before it
becomes an array: ``rows`` and ``cols`` positive integers, ``dt`` one of OpenCV's element types, and exactly
``rows x cols x channels`` numbers in ``data``, all finite. Any defect is a BlockError naming the file, the
line and the key.

Only what a calibration file needs is read: top-level scalars (numbers and strings) and matrices; nested
maps and sequences are kept as :data:`NESTED` and never looked into.
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass

import numpy as np

from ..errors import BlockError
from .text import decode_text, yaml_error

__all__ = ["Matrix", "Node", "NESTED", "read_file_storage", "MAX_FILE_BYTES"]

#: a camera file is a few kB; beyond this it is not one (and is not read into memory)
MAX_FILE_BYTES = 16 * 2**20
#: OpenCV's element types (dt), with an optional channel count in front ("3d")
_DT = re.compile(r"([1-4]?)([ucswifdh])")
_INT = re.compile(r"[+-]?\d+")


class _Nested:
    def __repr__(self) -> str:
        return "NESTED"


#: the value of a top-level key that holds a map or a sequence other than a matrix (not read)
NESTED = _Nested()


@dataclass(frozen=True)
class Matrix:
    """An ``opencv-matrix`` node: its values as a float array of shape (rows, cols * channels)."""

    values: np.ndarray
    dt: str


@dataclass(frozen=True)
class Node:
    """A top-level key: its value (a str, an int, a float, a :class:`Matrix` or :data:`NESTED`) and line."""

    value: object
    line: int | None


def _scalar(text: str) -> int | float | str:
    """An unquoted scalar as OpenCV writes it: an int, a float, or the text."""
    token = text.strip()
    if _INT.fullmatch(token):
        return int(token)
    lowered = token.lower()
    if lowered in (".nan", ".inf", "-.inf", "+.inf"):
        return float(lowered.replace(".", ""))
    try:
        return float(token)
    except ValueError:
        return token


def _matrix(path: str, key: str, line: int | None, fields: dict, data: list[str], data_line: int | None) -> Matrix:
    def fail(reason: str, at: int | None = line) -> BlockError:
        return BlockError(path, reason, at, key)

    sizes = {}
    for name in ("rows", "cols"):
        value = fields.get(name)
        if value is None:
            raise fail(f"the opencv-matrix has no '{name}'")
        if not _INT.fullmatch(value.strip()) or int(value) <= 0:
            raise fail(f"'{name}' must be a positive integer, found {value.strip()[:40]!r}")
        sizes[name] = int(value)
    dt = (fields.get("dt") or "").strip()
    match = _DT.fullmatch(dt)
    if match is None:
        raise fail(f"'dt' must be an OpenCV element type (d, f, i, u, ...), found {dt[:40]!r}")
    channels = int(match.group(1) or 1)
    expected = sizes["rows"] * sizes["cols"] * channels
    if len(data) != expected:
        raise fail(f"rows x cols{' x channels' if channels > 1 else ''} = {expected} numbers expected in 'data', "
                   f"found {len(data)}", data_line)
    values = np.empty(len(data))
    for k, token in enumerate(data):
        value = _scalar(token)
        if isinstance(value, str) or not math.isfinite(value):
            raise fail(f"'data' value {k + 1} is {token.strip()[:40]!r}, not a finite number", data_line)
        values[k] = value
    return Matrix(values.reshape(sizes["rows"], sizes["cols"] * channels), dt)


def read_file_storage(path: str | os.PathLike) -> dict[str, Node]:
    """The top-level nodes of an OpenCV FileStorage file (format by content: ``%YAML`` or ``!!opencv-``
    YAML, ``<`` XML, ``{`` JSON; otherwise by extension)."""
    path = os.fspath(path)
    try:
        size = os.path.getsize(path)
        if size > MAX_FILE_BYTES:
            raise BlockError(path, f"{size / 2**20:.0f} MB: too large for an OpenCV camera file")
        with open(path, "rb") as handle:
            data = handle.read()
    except FileNotFoundError:
        raise BlockError(path, "file not found") from None
    except IsADirectoryError:
        raise BlockError(path, "is a folder; expected an OpenCV camera file") from None
    except OSError as exc:
        raise BlockError(path, f"cannot read the OpenCV camera file: {exc.strerror}") from None
    text = decode_text(data, path)
    head = text.lstrip()
    ext = os.path.splitext(path)[1].lower()
    if head.startswith("<") or (not head and ext == ".xml"):
        from .opencv_xml import read_xml_storage
        return read_xml_storage(path, text, _matrix, _scalar)
    if head.startswith("{") or (not head.startswith("%") and ext == ".json"):
        return _read_json_storage(path, text)
    return _read_yaml_storage(path, text)


# --- YAML -------------------------------------------------------------------------------------------------

def _read_yaml_storage(path: str, text: str) -> dict[str, Node]:
    import yaml

    # OpenCV's own directive '%YAML:1.0' is not YAML's (and its files have no '---' after it): a comment
    text = re.sub(r"\A(\s*)%YAML:", r"\1#YAML:", text)
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as exc:
        raise yaml_error(path, exc, "OpenCV YAML") from None
    except RecursionError:
        raise BlockError(path, "not OpenCV YAML: nested too deeply") from None
    if root is None:
        raise BlockError(path, "empty: not an OpenCV camera file")
    if not isinstance(root, yaml.MappingNode):
        raise BlockError(path, "not an OpenCV FileStorage file: the top level is not a map of keys",
                         root.start_mark.line + 1)
    nodes: dict[str, Node] = {}
    for key_node, value_node in root.value:
        line = key_node.start_mark.line + 1
        if not isinstance(key_node, yaml.ScalarNode):
            raise BlockError(path, "a key that is not a name", line)
        key = str(key_node.value)
        if key in nodes:
            raise BlockError(path, f"'{key}' repeats (first at line {nodes[key].line})", line, key)
        nodes[key] = Node(_yaml_value(path, key, line, value_node), line)
    return nodes


def _yaml_value(path: str, key: str, line: int, node) -> object:
    import yaml

    if isinstance(node, yaml.ScalarNode):
        quoted = node.style in ("'", '"')
        return str(node.value) if quoted else _scalar(str(node.value))
    if not (isinstance(node, yaml.MappingNode) and node.tag.endswith("opencv-matrix")):
        return NESTED
    fields: dict[str, str] = {}
    data: list[str] = []
    data_line = line
    for k, v in node.value:
        name = str(k.value) if isinstance(k, yaml.ScalarNode) else ""
        if name == "data":
            data_line = k.start_mark.line + 1
            if not isinstance(v, yaml.SequenceNode) or not all(isinstance(item, yaml.ScalarNode) for item in v.value):
                raise BlockError(path, "'data' must be a list of numbers", data_line, key)
            data = [str(item.value) for item in v.value]
        elif isinstance(v, yaml.ScalarNode):
            fields[name] = str(v.value)
    return _matrix(path, key, line, fields, data, data_line)


# --- JSON -------------------------------------------------------------------------------------------------

class _JsonNumber(str):
    """A number of a JSON file, kept as its text (so that a string "3" stays a string)."""


def _read_json_storage(path: str, text: str) -> dict[str, Node]:
    import json

    try:
        root = json.loads(text, parse_float=_JsonNumber, parse_int=_JsonNumber, parse_constant=_JsonNumber)
    except json.JSONDecodeError as exc:
        raise BlockError(path, f"not OpenCV JSON: {exc.msg}", exc.lineno) from None
    except RecursionError:
        raise BlockError(path, "not OpenCV JSON: nested too deeply") from None
    if not isinstance(root, dict):
        raise BlockError(path, "not an OpenCV FileStorage file: the top level is not an object of keys")

    def line_of(key: str) -> int | None:
        match = re.search(rf'"{re.escape(key)}"\s*:', text)
        return text.count("\n", 0, match.start()) + 1 if match else None

    nodes: dict[str, Node] = {}
    for key, value in root.items():
        line = line_of(key)
        if isinstance(value, _JsonNumber):
            nodes[key] = Node(_scalar(value), line)
        elif isinstance(value, str):
            nodes[key] = Node(value, line)
        elif isinstance(value, dict) and value.get("type_id") == "opencv-matrix":
            data = value.get("data")
            if not isinstance(data, list) or not all(isinstance(v, _JsonNumber) for v in data):
                raise BlockError(path, "'data' must be a list of numbers", line, key)
            fields = {name: v for name, v in value.items() if isinstance(v, str)}
            nodes[key] = Node(_matrix(path, key, line, fields, data, line), line)
        else:
            nodes[key] = Node(NESTED, line)
    return nodes
