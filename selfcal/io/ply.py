"""PLY (Stanford polygon format, binary little-endian) of a point cloud: one ``vertex`` element whose
properties are the fields of a NumPy structured array (float64 -> ``double``, float32 -> ``float``,
int32 -> ``int``, uint8 -> ``uchar``...), with ``comment`` lines in the header. CloudCompare, MeshLab,
Open3D and plyfile read it; double coordinates keep projected-CRS metres exact."""
from __future__ import annotations

import numpy as np

__all__ = ["ply_bytes"]

#: NumPy kind+size -> PLY scalar type
_PLY_TYPES = {"f8": "double", "f4": "float", "i4": "int", "u4": "uint", "i2": "short", "u2": "ushort",
              "i1": "char", "u1": "uchar"}


def ply_bytes(vertices: np.ndarray, comments=()) -> bytes:
    """The PLY file of the structured array ``vertices`` (one vertex per row)."""
    fields = vertices.dtype.names
    if not fields:
        raise ValueError("a PLY vertex element needs a structured array")
    lines = ["ply", "format binary_little_endian 1.0"]
    lines += [f"comment {' '.join(str(c).split())}" for c in comments]
    lines.append(f"element vertex {len(vertices)}")
    little = []
    for name in fields:
        dtype = vertices.dtype[name]
        key = f"{dtype.kind}{dtype.itemsize}"
        if key not in _PLY_TYPES:
            raise ValueError(f"PLY has no type for field {name} ({dtype})")
        lines.append(f"property {_PLY_TYPES[key]} {name}")
        little.append((name, dtype.newbyteorder("<")))
    lines.append("end_header")
    body = np.ascontiguousarray(vertices.astype(np.dtype(little))).tobytes()
    # the header is ASCII: other characters of a comment (a block name) are written as \u escapes
    return ("\n".join(lines) + "\n").encode("ascii", "backslashreplace") + body
