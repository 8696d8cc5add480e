"""Projection models with analytic Jacobians, found by name."""
from . import frame, pushbroom

#: sensor model name (``model =`` in block.toml) -> module. Foreign descriptions that become a
#: pushbroom camera are read by selfcal.io (usgscsm ISD, Pleiades DIMAP) and built by the modules
#: usgscsm and dimap; the vendor RPC of an image is rpc.
SENSORS = {"frame": frame, "pushbroom": pushbroom}

__all__ = ["SENSORS", "frame", "pushbroom"]
