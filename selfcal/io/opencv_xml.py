"""OpenCV FileStorage XML (``<opencv_storage>``) read with expat, for :mod:`selfcal.io.opencv_storage`.

No DOCTYPE is accepted (OpenCV writes none; entities are how an XML file asks for more memory than it has).
Strings OpenCV quotes (``"fx fy cx cy"``) lose their quotes.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any
from xml.parsers import expat

from ..errors import BlockError

__all__ = ["read_xml_storage"]


class _Element:
    def __init__(self, tag: str, attributes: dict[str, str], line: int):
        self.tag, self.attributes, self.line = tag, attributes, line
        self.text: list[str] = []
        self.children: list[_Element] = []


def _tree(path: str, text: str) -> _Element:
    parser = expat.ParserCreate()
    stack: list[_Element] = []
    roots: list[_Element] = []

    def start(tag: str, attributes: dict[str, str]) -> None:
        element = _Element(tag, attributes, parser.CurrentLineNumber)
        (stack[-1].children if stack else roots).append(element)
        stack.append(element)

    def end(tag: str) -> None:
        stack.pop()

    def characters(data: str) -> None:
        if stack:
            stack[-1].text.append(data)

    def doctype(*args: Any) -> None:
        raise BlockError(path, "a DOCTYPE: OpenCV XML has none", parser.CurrentLineNumber)

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = characters
    parser.StartDoctypeDeclHandler = doctype
    try:
        parser.Parse(text, True)
    except expat.ExpatError as exc:
        raise BlockError(path, f"not XML: {expat.ErrorString(exc.code)}", exc.lineno) from None
    except RecursionError:
        raise BlockError(path, "not XML: nested too deeply") from None
    if len(roots) != 1:
        raise BlockError(path, "not XML: no root element")
    return roots[0]


def read_xml_storage(path: str, text: str, matrix: Callable, scalar: Callable) -> dict:
    """Top-level nodes (:class:`selfcal.io.opencv_storage.Node`) of an OpenCV XML file."""
    from .opencv_storage import NESTED, Node

    root = _tree(path, text)
    if root.tag != "opencv_storage":
        raise BlockError(path, f"not OpenCV XML: the root element is <{root.tag}>, not <opencv_storage>", root.line)
    nodes: dict[str, Node] = {}
    for element in root.children:
        key = element.tag
        if key in nodes:
            raise BlockError(path, f"<{key}> repeats (first at line {nodes[key].line})", element.line, key)
        value: object
        if element.attributes.get("type_id") == "opencv-matrix":
            fields = {child.tag: "".join(child.text) for child in element.children}
            data = next((child for child in element.children if child.tag == "data"), None)
            tokens = "".join(data.text).split() if data is not None else []
            value = matrix(path, key, element.line, fields, tokens, data.line if data is not None else element.line)
        elif element.children or element.attributes.get("type_id"):
            value = NESTED
        else:
            content = "".join(element.text).strip()
            if len(content) >= 2 and content[0] == content[-1] == '"':
                value = content[1:-1]
            else:
                value = scalar(content)
        nodes[key] = Node(value, element.line)
    return nodes
