"""Synthetic blocks with known truth, for tests, benchmarks and the demo."""
from .uav import DISTORTIONS, FLIGHTS, SCENARIOS, TrueDistortion, UAVSimulation, UAVTruth, simulate_uav, truth_files

__all__ = ["simulate_uav", "truth_files", "UAVSimulation", "UAVTruth", "TrueDistortion", "SCENARIOS", "DISTORTIONS", "FLIGHTS"]
