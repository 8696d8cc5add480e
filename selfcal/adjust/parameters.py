"""Which parameters an adjustment estimates: each camera's parameter vector (:class:`CameraParameters`) and what
screening holds (:func:`apply_free`)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..ap import APModel

if TYPE_CHECKING:
    from .problem import Problem

__all__ = ["CameraParameters", "apply_free"]


@dataclass
class CameraParameters:
    """One camera's parameter vector [core parameters of its sensor | AP coefficients] and its settings."""

    camera_id: str
    ap: APModel
    pixel_size_mm: float
    free: np.ndarray          # bool, which entries are unknowns
    prior_value: np.ndarray   # a-priori (start) values (observed where prior_sigma is finite)
    prior_sigma: np.ndarray   # NaN: no prior observation
    names: list[str]
    sensor: str = "frame"     # name of the camera's sensor model (selfcal.sensors.SENSORS)
    n_core: int = 3           # the sensor's own parameters, before the AP coefficients
    core_screened: tuple = (False, False, False)   # which core parameters screening may hold at their start
    units: tuple = ()         # unit of every entry

    @property
    def size(self) -> int:
        return len(self.free)

    @property
    def screenable(self) -> np.ndarray:
        """Which entries screening may hold: the flagged core parameters and every AP coefficient."""
        return np.concatenate([np.asarray(self.core_screened, bool), np.ones(self.size - self.n_core, bool)])

    @property
    def reference(self) -> np.ndarray:
        """What screening tests an entry against and holds it at: the start value of a core
        parameter, zero for an AP coefficient (its given value for one held by block.toml, sigma 0)."""
        ap = np.where(self.prior_sigma[self.n_core:] == 0, self.prior_value[self.n_core:], 0.0)
        return np.concatenate([self.prior_value[:self.n_core], ap])



def _offsets(problem: Problem) -> list[int]:
    offsets, start = [], problem.n_e
    for cam in problem.cameras:
        offsets.append(start)
        start += int(cam.free.sum())
    return offsets


def apply_free(problem: Problem, free: dict) -> None:
    """Hold parameters as screening decided: ``free`` maps an owner to a bool mask of what stays
    estimated, a camera id to its AP coefficients, ``("core", camera id)`` to its sensor's own
    parameters, ``("image", image id)`` to an image's parameters, "GNSS" / "IMU" to the
    trajectory terms. Held parameters keep their start value (zero for an AP coefficient)."""
    image_of = {i: k for k, i in enumerate(problem.image_ids)}
    for cam in problem.cameras:
        if cam.camera_id in free:
            cam.free[cam.n_core:] = np.asarray(free[cam.camera_id], bool)
        if ("core", cam.camera_id) in free:
            cam.free[:cam.n_core] = np.asarray(free[("core", cam.camera_id)], bool)
    for key, mask in free.items():
        if isinstance(key, tuple) and key[0] == "image" and key[1] in image_of:
            problem.image_free[image_of[key[1]]] = np.asarray(mask, bool)
    for t in problem.trajectory:
        if t.sensor in free:
            t.free[:] = np.asarray(free[t.sensor], bool)
    problem.d_offset = _offsets(problem)

