"""Synthetic blocks with known truth, for tests, benchmarks and the demo."""
from typing import TYPE_CHECKING

from ..lazy import attach
from .names import DISTORTIONS, FLIGHTS, SCENARIOS

#: module -> the public names it defines (imported on first use: ``simulate --help`` reads only :mod:`.names`)
_MODULES = {
    ".uav": ("TrueDistortion", "UAVSimulation", "UAVTruth", "simulate_uav", "truth_files"),
}
__getattr__, __dir__ = attach(__name__, _MODULES)

if TYPE_CHECKING:
    from .uav import TrueDistortion, UAVSimulation, UAVTruth, simulate_uav, truth_files

__all__ = ["simulate_uav", "truth_files", "UAVSimulation", "UAVTruth", "TrueDistortion", "SCENARIOS", "DISTORTIONS",
           "FLIGHTS"]
