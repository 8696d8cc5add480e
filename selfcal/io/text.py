"""Text files as every reader takes them: UTF-8, with or without a byte-order mark.

Excel's "CSV UTF-8" and Notepad start a file with the UTF-8 byte-order mark; it is dropped. Any other
encoding (Latin-1, a UTF-16 export, binary data) is a :class:`~selfcal.errors.BlockError` naming the file,
the line and the byte, never a misread header or a traceback.
"""
from __future__ import annotations

import os

from ..errors import BlockError

__all__ = ["read_text", "decode_text", "UTF8_BOM"]

UTF8_BOM = b"\xef\xbb\xbf"


def decode_text(data: bytes, path: str) -> str:
    """``data`` as text (UTF-8, a leading byte-order mark dropped); anything else is a BlockError."""
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise BlockError(path, "UTF-16 text: save the file as UTF-8", 1)
    data = data.removeprefix(UTF8_BOM)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        column = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        raise BlockError(path, f"byte 0x{data[exc.start]:02x} at character {column} is not UTF-8 text (save the file "
                               f"as UTF-8)", line) from None
    if "\0" in text:
        line = text.count("\n", 0, text.index("\0")) + 1
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
