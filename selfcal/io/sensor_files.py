"""Readers of the sensor descriptions that images name in images.csv (``sensor_file``, DESIGN.md §3a), by
camera model: one line per format family; the reader returns what the model's sensor binds (an RPC, a
line image)."""
from __future__ import annotations

from .rpc import read_rpc

#: camera model -> reader of an image's sensor_file
SENSOR_FILE_READERS = {
    "rpc": read_rpc,
}

__all__ = ["SENSOR_FILE_READERS"]
