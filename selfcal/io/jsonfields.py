"""Typed access to the values of a JSON document (ISDs, camera.json, cameras.json): a missing key, a
``null``, a string where a number belongs, a list of the wrong length or a NaN is a
:class:`~selfcal.errors.BlockError` naming the file and the key (``parent.key``) and saying what was expected.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import BlockError

__all__ = ["need", "mapping", "number", "integer", "string", "array", "found"]


def found(value: Any) -> str:
    """A value as a message shows it (shortened)."""
    text = "null" if value is None else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _fail(path: str, key: str, expected: str, value: Any) -> BlockError:
    return BlockError(path, f"'{key}' must be {expected}, found {found(value)}")


def need(path: str, obj: Any, key: str, parent: str = "") -> Any:
    """``obj[key]``; a missing key or ``null`` is an error (``parent``: where ``obj`` is, for the message)."""
    name = f"{parent}.{key}" if parent else key
    if not isinstance(obj, dict):
        raise _fail(path, parent or key, "an object", obj)
    if key not in obj:
        raise BlockError(path, f"missing key '{name}'")
    if obj[key] is None:
        raise BlockError(path, f"'{name}' is null; a value is needed")
    return obj[key]


def mapping(path: str, value: Any, key: str) -> dict:
    if not isinstance(value, dict):
        raise _fail(path, key, "an object {...}", value)
    return value


def string(path: str, value: Any, key: str) -> str:
    if not isinstance(value, str):
        raise _fail(path, key, "a string", value)
    return value


def number(path: str, value: Any, key: str, positive: bool = False) -> float:
    """A finite JSON number (not a boolean); ``positive``: above zero."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or abs(value) > 1e100 or positive and not value > 0:
        raise _fail(path, key, "a positive number" if positive else "a finite number", value)
    return float(value)


def integer(path: str, value: Any, key: str, low: int = 1) -> int:
    """A JSON whole number of at least ``low`` (2.0 is taken as 2)."""
    if isinstance(value, float) and value.is_integer() and abs(value) < 2**53:
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise _fail(path, key, f"a whole number of at least {low}", value)
    return value


def array(path: str, value: Any, key: str, shape: tuple[int | None, ...]) -> np.ndarray:
    """Finite numbers of ``shape`` (None: any length along that axis, at least one)."""
    described = " x ".join("n" if n is None else str(n) for n in shape)
    what = f"finite numbers of shape ({described})" if len(shape) > 1 else (
        "a list of finite numbers" if shape[0] is None else f"a list of {shape[0]} finite numbers")

    def check(item: Any, depth: int) -> bool:
        if depth == len(shape):
            return not isinstance(item, bool) and isinstance(item, (int, float)) and math.isfinite(item) \
                and abs(item) <= 1e100
        return isinstance(item, list) and (len(item) == shape[depth] if shape[depth] is not None else bool(item)) \
            and all(check(v, depth + 1) for v in item)

    if not check(value, 0):
        raise _fail(path, key, what, value)
    return np.array(value, float)
