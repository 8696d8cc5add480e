"""A small reader of PVL as ISIS writes it (cube labels, control networks, translation tables).

Why not the ``pvl`` package: selfcal's errors name the file *and the line* of a bad keyword, which
``pvl``'s parsed modules no longer know, and ISIS serial numbers are composed from the label's text
(``StartTime = 1971-07-31T14:00:53.547``), which ``pvl`` turns into ``datetime`` objects. This reader
keeps every value as the text it is, with its unit and line number; interpreting it is the caller's.

The subset read (what ISIS writes):

* ``Object = NAME`` ... ``End_Object``, ``Group = NAME`` ... ``End_Group`` (also ``Begin_Object`` /
  ``Begin_Group`` and ``EndObject`` / ``EndGroup``), nested; ``End`` ends the text (a cube's binary
  data may follow it);
* ``Keyword = value``, ``Keyword = value <unit>``, ``Keyword = (v1 <u>, v2, ...) <unit>`` (``{}`` too),
  arrays spanning lines; a keyword without ``=`` (``Auto`` in translation tables) has no values;
* values: bare words, ``"quoted"`` or ``'quoted'`` strings (a line break inside one, with the
  blanks around it, reads as one blank), and ISIS's wrapped words: a bare word ending in ``-`` at the
  end of a line continues on the next (``...pa.bp-`` / ``c`` reads ``...pa.bpc``);
* comments ``# ...`` to the end of the line and ``/* ... */``.

Keyword and block names compare case-insensitively, as in ISIS. A keyword may repeat (ISIS
allows it; the first one is what ISIS's ``findKeyword`` returns).
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field

from ..errors import BlockError
from .text import decode_text

__all__ = ["PvlKeyword", "PvlBlock", "parse_pvl", "read_pvl"]

_TOKEN = re.compile(r"""
    (?P<ws>[ \t\r\f\v]+)
  | (?P<nl>\n)
  | (?P<comment>\#[^\n]*|/\*.*?\*/)
  | (?P<string>"[^"]*"|'[^']*')
  | (?P<unit><[^<>\n]*>)
  | (?P<punct>[=(){},])
  | (?P<word>[^\s=(){},"'<>]+)
""", re.VERBOSE | re.DOTALL)

_OPEN = {"object": "Object", "begin_object": "Object", "group": "Group", "begin_group": "Group"}
_CLOSE = {"end_object": "Object", "endobject": "Object", "end_group": "Group", "endgroup": "Group"}


@dataclass(frozen=True)
class PvlKeyword:
    """One keyword: its values as text (one for a scalar, several for an array), the unit of each
    value (None where none is given; an array's trailing unit applies to the values without one),
    and the 1-based line of its name."""

    name: str
    values: tuple[str, ...]
    units: tuple[str | None, ...]
    line: int
    is_array: bool = False

    @property
    def value(self) -> str:
        """The first value (what ISIS's ``keyword[0]`` gives)."""
        return self.values[0] if self.values else ""


@dataclass
class PvlBlock:
    """An ``Object`` or ``Group`` (``kind``; the root is kind ``"Root"``) with its keywords and blocks in
    file order."""

    kind: str
    name: str
    line: int
    keywords: list[PvlKeyword] = field(default_factory=list)
    blocks: list["PvlBlock"] = field(default_factory=list)

    def keyword(self, name: str) -> PvlKeyword | None:
        """The first keyword of that name (case-insensitive), or None."""
        low = name.lower()
        for k in self.keywords:
            if k.name.lower() == low:
                return k
        return None

    def all(self, name: str) -> list[PvlKeyword]:
        """Every keyword of that name, in file order."""
        low = name.lower()
        return [k for k in self.keywords if k.name.lower() == low]

    def children(self, kind: str, name: str | None = None) -> list["PvlBlock"]:
        """Direct sub-blocks of a kind (``"Object"``/``"Group"``), optionally of one name."""
        return [b for b in self.blocks if b.kind == kind and (name is None or b.name.lower() == name.lower())]

    def find(self, kind: str, name: str) -> "PvlBlock | None":
        """The first block of that kind and name, searching depth first (ISIS's ``Pvl::Traverse``)."""
        for b in self.blocks:
            if b.kind == kind and b.name.lower() == name.lower():
                return b
            hit = b.find(kind, name)
            if hit is not None:
                return hit
        return None


def _tokens(text: str, path: str):
    """(kind, text, line) of every token; comments and blanks are dropped, line breaks kept."""
    out = []
    pos, line, n = 0, 1, len(text)
    while pos < n:
        m = _TOKEN.match(text, pos)
        if m is None:
            raise BlockError(path, f"cannot read PVL at {text[pos:pos + 20]!r}", line)
        kind, value = m.lastgroup, m.group()
        end = m.end()
        if kind == "word":
            start_line = line
            # ISIS wraps long words: '-' at the end of a line continues on the next one
            while value.endswith("-") and end < n and text[end] == "\n":
                nxt = re.compile(r"\n[ \t]*([^\s=(){},\"'<>]+)").match(text, end)
                if nxt is None:
                    break
                value = value[:-1] + nxt.group(1)
                line += 1
                end = nxt.end()
            out.append(("word", value, start_line))
        elif kind == "string":
            body = re.sub(r"[ \t]*\n[ \t]*", " ", value[1:-1])
            out.append(("string", body, line))
            line += value.count("\n")
        elif kind == "nl":
            out.append(("nl", "\n", line))
            line += 1
        elif kind == "comment":
            line += value.count("\n")
        elif kind in ("unit", "punct"):
            out.append((kind, value, line))
        pos = end
    out.append(("eof", "", line))
    return out


class _Parser:
    def __init__(self, tokens, path: str):
        self.t, self.i, self.path = tokens, 0, path

    def peek(self, skip_newlines: bool = False):
        j = self.i
        while skip_newlines and self.t[j][0] == "nl":
            j += 1
        return self.t[j]

    def take(self, skip_newlines: bool = False):
        while skip_newlines and self.t[self.i][0] == "nl":
            self.i += 1
        tok = self.t[self.i]
        self.i += 1
        return tok

    def fail(self, message: str, line: int, key: str | None = None):
        raise BlockError(self.path, message, line, key)

    def scalar(self, key: str):
        kind, text, line = self.take(skip_newlines=True)
        if kind not in ("word", "string"):
            self.fail(f"keyword '{key}' has no value (found {text!r})", line, key)
        unit = None
        if self.peek()[0] == "unit":
            unit = self.take()[1][1:-1].strip()
        return text, unit

    def array(self, key: str, closing: str, key_line: int):
        values, units = [], []
        if self.peek(True)[1] == closing:
            self.take(True)
        else:
            while True:
                if self.peek(True)[1] in "({":
                    self.fail(f"keyword '{key}': nested arrays are not read", self.peek(True)[2], key)
                v, u = self.scalar(key)
                values.append(v)
                units.append(u)
                kind, text, line = self.take(skip_newlines=True)
                if text == closing and kind == "punct":
                    break
                if kind == "eof":
                    self.fail(f"the array of '{key}' is never closed with '{closing}'", key_line, key)
                if text != ",":
                    self.fail(f"keyword '{key}': expected ',' or '{closing}' in the array, found {text!r}", line, key)
        if self.peek()[0] == "unit":
            common = self.take()[1][1:-1].strip()
            units = [u if u is not None else common for u in units]
        return tuple(values), tuple(units)

    def end_of_statement(self, key: str):
        kind, text, line = self.peek()
        if kind not in ("nl", "eof"):
            self.fail(f"unexpected {text!r} after the value of '{key}'", line, key)

    def parse(self) -> PvlBlock:
        root = PvlBlock("Root", "", 1)
        stack = [root]
        while True:
            kind, text, line = self.take(skip_newlines=True)
            if kind == "eof":
                break
            if kind != "word":
                self.fail(f"expected a keyword, found {text!r}", line)
            low = text.lower()
            if low == "end":
                break
            if low in _CLOSE:
                if len(stack) == 1 or stack[-1].kind != _CLOSE[low]:
                    opened = f"{stack[-1].kind} '{stack[-1].name}' (line {stack[-1].line})" if len(stack) > 1 \
                        else "nothing"
                    self.fail(f"{text} closes {opened}", line, text)
                stack.pop()
                self.end_of_statement(text)
                continue
            if self.peek()[1] != "=":
                self.end_of_statement(text)
                stack[-1].keywords.append(PvlKeyword(text, (), (), line))
                continue
            self.take()                                              # '='
            nxt = self.peek(True)
            if nxt[0] == "punct" and nxt[1] in "({":
                self.take(True)
                values, units = self.array(text, ")" if nxt[1] == "(" else "}", line)
                keyword = PvlKeyword(text, values, units, line, is_array=True)
            else:
                v, u = self.scalar(text)
                keyword = PvlKeyword(text, (v,), (u,), line)
            self.end_of_statement(text)
            if low in _OPEN:
                block = PvlBlock(_OPEN[low], keyword.value, line)
                stack[-1].blocks.append(block)
                stack.append(block)
            else:
                stack[-1].keywords.append(keyword)
        if len(stack) > 1:
            self.fail(f"{stack[-1].kind} '{stack[-1].name}' is never closed", stack[-1].line, stack[-1].kind)
        return root


def parse_pvl(text: str, path: str = "<text>") -> PvlBlock:
    """Parse PVL text; errors (BlockError) name ``path``, the line and the keyword."""
    return _Parser(_tokens(text, path), path).parse()


#: the largest PVL text read (labels are kilobytes; a control network of a million measures some hundred MB)
MAX_LABEL_BYTES = 1024 * 2**20


def read_pvl(path: str | os.PathLike) -> PvlBlock:
    """Read a PVL file (a detached ISIS label, a PVL control network); the text ends at ``End``."""
    path = str(path)
    end_line = re.compile(rb"^[ \t]*End[ \t]*\r?$", re.MULTILINE | re.IGNORECASE)
    raw, end = bytearray(), None
    try:
        with open(path, "rb") as handle:      # a cube's label, not its pixels: read up to 'End' only
            start = 0
            while True:
                chunk = handle.read(2**20)
                raw += chunk
                end = end_line.search(raw, start)
                if not chunk or end is not None and end.end() < len(raw):   # 'End' and its line end, or EOF
                    break
                start = max(0, len(raw) - 64)
                if len(raw) > MAX_LABEL_BYTES:
                    raise BlockError(path, f"no 'End' line in the first {MAX_LABEL_BYTES // 2**20} MB: not a PVL "
                                           f"label or control network of a size selfcal reads")
    except OSError as exc:
        raise BlockError(path, f"cannot read: {exc.strerror}") from None
    head = bytes(raw[:end.end()] if end else raw)
    text = decode_text(head, path)
    return parse_pvl(text, path)
