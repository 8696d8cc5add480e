"""An XML file whose elements know their line, so that reader errors name file, line and key.

:class:`XmlDocument` parses with expat into an ElementTree (the standard library's parser keeps
no line numbers) and offers the look-ups the vendor readers need (DigitalGlobe XML, SPOT DIMAP):
each raises :class:`~selfcal.errors.BlockError` with the file, the line of the element where the
key was looked for (or of the offending element) and the key as ``parent/child`` path.
"""
from __future__ import annotations

import re
import xml.etree.ElementTree as ElementTree
from datetime import datetime, timedelta
from xml.parsers import expat

import numpy as np

from ..errors import BlockError

__all__ = ["XmlDocument", "parse_utc", "seconds_between", "iso_utc"]


class XmlDocument:
    """A parsed XML file: ``root`` and the 1-based source line of every element."""

    def __init__(self, path: str, what: str):
        self.path = str(path)
        self._lines: dict[int, int] = {}
        builder = ElementTree.TreeBuilder()
        parser = expat.ParserCreate()
        parser.buffer_text = True
        lines = self._lines

        def start(name, attributes):
            element = builder.start(name, attributes)
            lines[id(element)] = parser.CurrentLineNumber

        parser.StartElementHandler = start
        parser.EndElementHandler = builder.end
        parser.CharacterDataHandler = builder.data
        try:
            with open(self.path, "rb") as handle:
                parser.ParseFile(handle)
        except expat.ExpatError as exc:
            raise BlockError(self.path, f"not XML: {expat.errors.messages[exc.code]}", line=exc.lineno) from None
        except (LookupError, ValueError) as exc:        # an unknown encoding declared, a broken character reference
            raise BlockError(self.path, f"not XML: {exc}", line=parser.CurrentLineNumber) from None
        except OSError as exc:
            raise BlockError(self.path, f"cannot read the {what}: {exc.strerror}") from None
        self.root = builder.close()
        self._names = {id(self.root): self.root.tag}

    # --- locating ------------------------------------------------------------------------------

    def line(self, element) -> int | None:
        return self._lines.get(id(element))

    def name(self, element) -> str:
        """The element's path from the root (``isd/EPH``), for messages."""
        return self._names.get(id(element), element.tag)

    def _remember(self, parent, child, key: str):
        self._names[id(child)] = f"{self.name(parent)}/{key}"
        return child

    def error(self, element, reason: str, key: str | None = None) -> BlockError:
        return BlockError(self.path, reason, line=self.line(element), column=key)

    # --- look-ups ------------------------------------------------------------------------------

    def find(self, parent, key: str):
        """The child (or descendant path) ``key`` of ``parent``, or None."""
        child = parent.find(key)
        return None if child is None else self._remember(parent, child, key)

    def node(self, parent, key: str):
        child = self.find(parent, key)
        if child is None:
            raise self.error(parent, f"missing element {key} in {self.name(parent)}", f"{self.name(parent)}/{key}")
        return child

    def children(self, parent, key: str) -> list:
        return [self._remember(parent, child, key) for child in parent.findall(key)]

    def text(self, parent, key: str) -> str:
        child = self.node(parent, key)
        if child.text is None or not child.text.strip():
            raise self.error(child, f"element {self.name(child)} is empty", self.name(child))
        return child.text.strip()

    def numbers(self, parent, key: str, count: int | None = None) -> np.ndarray:
        """The whitespace-separated finite numbers of an element."""
        child = self.node(parent, key)
        text = child.text or ""
        try:
            values = np.array(text.replace(",", " ").split(), float)
        except ValueError:
            raise self.error(child, f"{self.name(child)} must hold numbers, found {text.strip()[:40]!r}",
                             self.name(child)) from None
        if count is not None and len(values) != count:
            raise self.error(child, f"{self.name(child)} must hold {count} numbers, found {len(values)}",
                             self.name(child))
        if not np.all(np.isfinite(values)):
            raise self.error(child, f"{self.name(child)} must be finite", self.name(child))
        return values

    def number(self, parent, key: str) -> float:
        return float(self.numbers(parent, key, 1)[0])

    def utc(self, parent, key: str) -> tuple:
        """A UTC time element (:func:`parse_utc`)."""
        text = self.text(parent, key)
        time = parse_utc(text)
        if time is None:
            child = self.node(parent, key)
            raise self.error(child, f"{self.name(child)} must be a UTC time YYYY-MM-DDThh:mm:ss.ffffff, found {text!r}",
                             self.name(child))
        return time

    def integer(self, parent, key: str, minimum: int | None = None) -> int:
        value = self.number(parent, key)
        if value != round(value) or (minimum is not None and value < minimum):
            child = self.node(parent, key)
            bound = "" if minimum is None else f" >= {minimum}"
            raise self.error(child, f"{self.name(child)} must be an integer{bound}, found {value:g}", self.name(child))
        return int(round(value))


# --- UTC times as vendors write them -----------------------------------------------------------

_UTC = re.compile(r"^\s*(\d{4})-(\d{2})-(\d{2})[T ](\d{2}):(\d{2}):(\d{2})(\.\d+)?\s*Z?\s*$")


def parse_utc(text: str) -> tuple[datetime, float] | None:
    """(whole second, fraction of a second) of an ISO 8601 UTC time such as ``2008-03-04T12:31:39.349737``
    or ``1959-11-25T17:39:48.740958Z`` (any number of decimals, kept in full); None if it is not one."""
    match = _UTC.match(text)
    if match is None:
        return None
    year, month, day, hour, minute, second = (int(match.group(k)) for k in range(1, 7))
    try:
        whole = datetime(year, month, day, hour, minute, second)
    except ValueError:
        return None
    return whole, float(match.group(7) or 0.0)


def seconds_between(start: tuple[datetime, float], end: tuple[datetime, float]) -> float:
    """end - start in seconds (whole seconds exactly, then the fractions)."""
    return (end[0] - start[0]).total_seconds() + (end[1] - start[1])


def iso_utc(time: tuple[datetime, float]) -> str:
    """The ISO 8601 text of a parsed time (microseconds, Z)."""
    whole, fraction = time
    return (whole + timedelta(microseconds=round(fraction * 1e6))).isoformat(timespec="microseconds") + "Z"
