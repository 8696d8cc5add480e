"""The protocol-buffer wire format, read and written without a schema compiler (ISIS binary control networks).

Why not the ``protobuf`` package: ISIS's messages are a few dozen scalar fields (varints, doubles, strings and
nested messages) and selfcal's errors name the byte offset of a defect, which the generated classes do not
give; the wire format is small and fixed (https://protobuf.dev/programming-guides/encoding/).

Reading: :func:`fields` splits a message into ``(field number, wire type, value, offset)``, the value an int for
a varint (0) or a fixed32/fixed64 (5/1, the raw unsigned integer), ``bytes`` for a length-delimited field (2);
the offset is that of the field's tag in the file. :func:`as_double`, :func:`as_signed` and :func:`packed_doubles`
interpret them. Writing: :func:`varint`, :func:`key` and the ``put_*`` helpers append to a ``bytearray``.
Every defect (a truncated varint or field, a length past the end, an unknown wire type) is a
:class:`~selfcal.errors.BlockError` naming the file and the byte offset.
"""
from __future__ import annotations

import struct
from collections.abc import Iterable

from ..errors import BlockError

__all__ = ["fields", "read_varint", "as_double", "as_signed", "packed_doubles", "varint", "key", "put_varint",
           "put_bytes", "put_string", "put_double", "put_bool", "put_packed_doubles"]

VARINT, FIXED64, LENGTH, FIXED32 = 0, 1, 2, 5


def read_varint(data: bytes, pos: int, end: int, path: str, base: int = 0) -> tuple[int, int]:
    """The unsigned varint at ``data[pos]`` and the position after it (``base``: the file offset of data[0])."""
    value, shift, start = 0, 0, pos
    while True:
        if pos >= end:
            raise BlockError(path, f"byte {base + start}: truncated varint (the message ends at byte {base + end})")
        b = data[pos]
        pos += 1
        value |= (b & 0x7F) << shift
        if not b & 0x80:
            return value, pos
        shift += 7
        if shift >= 70:
            raise BlockError(path, f"byte {base + start}: varint longer than 10 bytes")


def fields(data: bytes, path: str, start: int = 0, end: int | None = None, base: int = 0):
    """``(field, wire type, value, offset)`` of each field of the message ``data[start:end]`` in order;
    ``base`` is the file offset of ``data[0]`` (offsets in errors and in the tuples are the file's)."""
    end = len(data) if end is None else end
    pos = start
    out = []
    while pos < end:
        offset = base + pos
        tag, pos = read_varint(data, pos, end, path, base)
        number, wire = tag >> 3, tag & 7
        value: int | bytes
        if number == 0:
            raise BlockError(path, f"byte {offset}: field number 0 (not a protobuf message here)")
        if wire == VARINT:
            value, pos = read_varint(data, pos, end, path, base)
        elif wire in (FIXED64, FIXED32):
            size = 8 if wire == FIXED64 else 4
            if pos + size > end:
                raise BlockError(path, f"byte {offset}: field {number} needs {size} bytes, the message ends at byte "
                                       f"{base + end}")
            value = int.from_bytes(data[pos:pos + size], "little")
            pos += size
        elif wire == LENGTH:
            size, pos = read_varint(data, pos, end, path, base)
            if pos + size > end:
                raise BlockError(path, f"byte {offset}: field {number} is {size} bytes long, past the end of its "
                                       f"message at byte {base + end}")
            value = bytes(data[pos:pos + size])
            pos += size
        else:
            raise BlockError(path, f"byte {offset}: field {number} has wire type {wire} (known: 0, 1, 2, 5)")
        out.append((number, wire, value, offset))
    return out


def as_double(value, wire: int, path: str, offset: int, name: str) -> float:
    """A ``double`` field (wire type 1)."""
    if wire != FIXED64:
        raise BlockError(path, f"byte {offset}: '{name}' must be a double (wire type 1), found wire type {wire}")
    return struct.unpack("<d", value.to_bytes(8, "little"))[0]


def as_signed(value, wire: int, path: str, offset: int, name: str) -> int:
    """An ``int32``/``enum``/``bool`` field (varint; negative int32 values are 10-byte two's complement)."""
    if wire != VARINT:
        raise BlockError(path, f"byte {offset}: '{name}' must be a varint (wire type 0), found wire type {wire}")
    return value - (1 << 64) if value >= 1 << 63 else value


def packed_doubles(value, wire: int, path: str, offset: int, name: str) -> list[float]:
    """A ``repeated double``: packed (one length-delimited field) or not (one fixed64 per value)."""
    if wire == FIXED64:
        return [as_double(value, wire, path, offset, name)]
    if wire != LENGTH or len(value) % 8:
        raise BlockError(path, f"byte {offset}: '{name}' must be packed doubles (a multiple of 8 bytes), found "
                               f"wire type {wire}" + (f", {len(value)} bytes" if wire == LENGTH else ""))
    return list(struct.unpack(f"<{len(value) // 8}d", value))


# --- writing ----------------------------------------------------------------------------------------

def varint(value: int) -> bytes:
    """The varint of ``value`` (a negative int32 as its 64-bit two's complement, as protobuf does)."""
    if value < 0:
        value += 1 << 64
    out = bytearray()
    while True:
        b = value & 0x7F
        value >>= 7
        if value:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def key(number: int, wire: int) -> bytes:
    return varint(number << 3 | wire)


def put_varint(out: bytearray, number: int, value: int) -> None:
    out += key(number, VARINT) + varint(int(value))


def put_bool(out: bytearray, number: int, value: bool) -> None:
    put_varint(out, number, 1 if value else 0)


def put_bytes(out: bytearray, number: int, value: bytes) -> None:
    out += key(number, LENGTH) + varint(len(value)) + value


def put_string(out: bytearray, number: int, value: str) -> None:
    put_bytes(out, number, value.encode("utf-8"))


def put_double(out: bytearray, number: int, value: float) -> None:
    out += key(number, FIXED64) + struct.pack("<d", float(value))


def put_packed_doubles(out: bytearray, number: int, values: Iterable[float]) -> None:
    values = [float(v) for v in values]
    put_bytes(out, number, struct.pack(f"<{len(values)}d", *values))
