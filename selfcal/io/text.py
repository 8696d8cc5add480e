"""Text files as every reader takes them: UTF-8, with or without a byte-order mark.

Excel's "CSV UTF-8" and Notepad start a file with the UTF-8 byte-order mark; it is dropped. Any other
encoding (Latin-1, a UTF-16 export, binary data) is a :class:`~selfcal.errors.BlockError` naming the file,
the line and the byte, never a misread header or a traceback.
"""
from __future__ import annotations

import os

from ..errors import BlockError

__all__ = ["read_text", "read_json", "decode_text", "decode_utf8", "without_bom", "is_number", "yaml_error", "UTF8_BOM"]

UTF8_BOM = b"\xef\xbb\xbf"


def decode_text(data: bytes, path: str) -> str:
    """``data`` as text (UTF-8, a leading byte-order mark dropped); anything else is a BlockError."""
    return decode_utf8(without_bom(data, path), path)


def without_bom(data: bytes, path: str) -> bytes:
    """The first bytes of a file without UTF-8's byte-order mark; UTF-16's is a BlockError."""
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise BlockError(path, "UTF-16 text: save the file as UTF-8", 1)
    return data.removeprefix(UTF8_BOM)


def decode_utf8(data: bytes, path: str, lines_before: int = 0) -> str:
    """``data`` as UTF-8 text without a NUL; anything else is a BlockError on its line, counted after
    ``lines_before`` (``data`` a block of a file that starts a line)."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = lines_before + data.count(b"\n", 0, exc.start) + 1
        column = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        raise BlockError(path, f"byte 0x{data[exc.start]:02x} at character {column} is not UTF-8 text (save the file "
                               f"as UTF-8)", line) from None
    if "\0" in text:
        line = lines_before + text.count("\n", 0, text.index("\0")) + 1
        raise BlockError(path, "a NUL byte: binary data, not a text file", line)
    return text


def read_text(path: str | os.PathLike, what: str = "file") -> str:
    """The text of the file ``path`` (see :func:`decode_text`); a missing or unreadable file is a BlockError."""
    path = os.fspath(path)
    try:
        with open(path, "rb") as handle:
            data = handle.read()
    except FileNotFoundError:
        raise BlockError(path, "file not found") from None
    except IsADirectoryError:
        raise BlockError(path, f"is a folder; expected the {what}") from None
    except OSError as exc:
        raise BlockError(path, f"cannot read the {what}: {exc.strerror}") from None
    return decode_text(data, path)


class _NotFinite(ValueError):
    def __init__(self, token: str):
        self.token = token
        super().__init__(token)


#: no quantity of a sensor model comes near this; a number beyond it is a corrupt file (and overflows on squaring)
LARGEST_PLAUSIBLE = 1e100


def _finite_float(token: str) -> float:
    value = float(token)
    if not abs(value) <= LARGEST_PLAUSIBLE:             # NaN fails this too
        raise _NotFinite(token)
    return value


def _constant(token: str):
    raise _NotFinite(token)


def read_json(path: str | os.PathLike, what: str = "file"):
    """A JSON file (UTF-8, see :func:`read_text`) whose numbers are all finite: NaN, Infinity and numbers beyond
    the double range (1e400) are a BlockError naming the line, and so is text that is not JSON."""
    import json
    import re
    path = os.fspath(path)
    text = read_text(path, what)
    try:
        return json.loads(text, parse_float=_finite_float, parse_constant=_constant)
    except _NotFinite as exc:
        match = re.search(rf"(?<![\w.\"]){re.escape(exc.token)}(?![\w.])", text)
        line = text.count("\n", 0, match.start()) + 1 if match else None
        raise BlockError(path, f"{exc.token} is not a finite number of plausible size", line) from None
    except json.JSONDecodeError as exc:
        raise BlockError(path, f"not JSON: {exc.msg}", exc.lineno) from None
    except RecursionError:
        raise BlockError(path, "not JSON: nested too deeply") from None


def is_number(text: str) -> bool:
    """Whether ``float`` reads ``text`` (NaN and infinity included: the readers refuse those themselves)."""
    try:
        float(text)
    except ValueError:
        return False
    return True


def yaml_error(path: str, exc: Exception, what: str = "YAML") -> BlockError:
    """A PyYAML error as a one-line BlockError with its line (PyYAML's own text spans several lines)."""
    mark = getattr(exc, "problem_mark", None)
    line = mark.line + 1 if mark is not None else None
    problem = getattr(exc, "problem", None)
    if problem is None and hasattr(exc, "character"):          # a ReaderError: a character YAML does not allow
        character = exc.character
        code = ord(character) if isinstance(character, str) else character
        problem = f"character #x{code:04x} is not allowed"
    reason = " ".join(str(problem or exc).split())
    return BlockError(path, f"not {what}: {reason}", line)
