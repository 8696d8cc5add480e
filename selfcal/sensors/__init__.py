"""Projection models with analytic Jacobians, found by name."""
from . import frame

#: sensor model name (``model =`` in block.toml) -> module
SENSORS = {"frame": frame}

__all__ = ["SENSORS", "frame"]
