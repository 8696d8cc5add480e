"""The names the UAV simulator takes (its scenarios, lens fields and flights), in a module of their own so that the
command line's ``simulate --help`` lists them without importing the simulator (and the sensors, and Numba)."""
from __future__ import annotations

__all__ = ["SCENARIOS", "DISTORTIONS", "FLIGHTS"]

SCENARIOS = ("type1", "type2", "type3", "type4")
DISTORTIONS = ("none", "brown", "local", "local+brown", "ripple", "edge")
#: seed000: the camera turns with the aircraft at the end of a strip (kappa 0 / 180°); serpentine: the same strips
#: flown with a fixed heading (the camera moves forwards on one strip, backwards on the next); corridor: two long
#: strips out and back with a fixed heading
FLIGHTS = ("seed000", "serpentine", "corridor")
