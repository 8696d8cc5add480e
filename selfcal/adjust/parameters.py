"""Which parameters an adjustment estimates: each camera's parameter vector (:class:`CameraParameters`) and what
screening holds (:func:`apply_free`)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..ap import APModel

if TYPE_CHECKING:
    from .problem import Problem

__all__ = ["CameraParameters", "ParameterTable", "parameter_table", "apply_free"]


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
    #: per core parameter what screening tests it against and holds it at where not its start value (NaN: the
    #: start value; a rolling shutter's readout: 0); empty: every start value
    core_reference: tuple = ()

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
        parameter (or its sensor's reference, :attr:`core_reference`), zero for an AP coefficient (its given value
        for one held by block.toml, sigma 0)."""
        ap = np.where(self.prior_sigma[self.n_core:] == 0, self.prior_value[self.n_core:], 0.0)
        core = self.prior_value[:self.n_core]
        if self.core_reference:
            given = np.asarray(self.core_reference, float)
            core = np.where(np.isfinite(given) & (self.prior_sigma[:self.n_core] != 0), given, core)
        return np.concatenate([core, ap])



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



@dataclass(frozen=True)
class ParameterTable:
    """Every parameter of an adjustment by name, in the order of the unknowns (images, cameras, the residual
    blocks' own: trajectory terms), as columns of equal length.

    ``owner`` the image id, camera id or sensor ("GNSS", "IMU") it belongs to; ``kind`` "image", "core" (a
    sensor's own camera parameter), "ap" (an AP coefficient) or "trajectory"; ``name``, ``unit`` (code units:
    m, rad, mm, px, ...), ``group`` ("EOP", "IOP", "AP", or the trajectory sensor); ``free`` whether it is
    estimated; ``screenable`` whether screening may hold it; ``index`` its column of theta (-1 where it has none:
    a held camera or trajectory parameter; a held image parameter keeps its column); ``start`` its start value;
    ``reference`` what screening tests it against and holds it at; ``value`` and ``sigma`` (a-posteriori, NaN where
    held) where the table comes from a result; ``key`` and ``position``: where it is in the ``free`` masks of
    :func:`selfcal.adjust.adjust` (a camera id for its APs, ("core", id), ("image", id), the sensor).
    """

    owner: np.ndarray
    kind: np.ndarray
    name: np.ndarray
    unit: np.ndarray
    group: np.ndarray
    free: np.ndarray
    screenable: np.ndarray
    index: np.ndarray
    start: np.ndarray
    reference: np.ndarray
    value: np.ndarray
    sigma: np.ndarray
    key: list
    position: np.ndarray

    def __len__(self) -> int:
        return len(self.name)

    def labels(self) -> list[str]:
        """``owner: name`` of every row."""
        return [f"{o}: {n}" for o, n in zip(self.owner, self.name)]

    def where(self, **equal) -> np.ndarray:
        """The rows whose columns equal the given values, e.g. ``where(kind="ap", free=True)``."""
        pick = np.ones(len(self), bool)
        for column, value in equal.items():
            pick &= np.asarray(getattr(self, column)) == value
        return np.flatnonzero(pick)


def parameter_table(problem: "Problem", state=None, theta_sigma: np.ndarray | None = None) -> ParameterTable:
    """The :class:`ParameterTable` of ``problem``; with ``state`` its values, with ``theta_sigma`` (the a-posteriori
    sigma of every column of theta) their sigmas."""
    rows: dict[str, list] = {k: [] for k in ("owner", "kind", "name", "unit", "group", "free", "screenable", "index",
                                             "start", "reference", "value", "key", "position")}

    def add(**values):
        for column, value in values.items():
            rows[column].append(value)
    sensor_of_image = {}
    for slot in problem.sensors:
        for i in slot.images:
            sensor_of_image[int(i)] = slot.sensor
    theta = problem.image_theta()
    for i in range(problem.n_images):
        image_id = str(problem.image_ids[i])
        for k, name in enumerate(problem.image_names[i]):
            group = sensor_of_image[i].image_parameters[k].group if i in sensor_of_image else "EOP"
            add(owner=image_id, kind="image", name=name, unit=problem.image_units[i][k], group=group,
                free=bool(problem.image_free[i, k]), screenable=bool(problem.image_screenable[i, k]),
                index=int(theta[i, k]), start=float(problem.image_prior_value[i, k]),
                reference=float(np.nan_to_num(problem.image_prior_value[i, k])),
                value=float(state.image[i, k]) if state is not None else np.nan, key=("image", image_id), position=k)
    for c, (cam, start) in enumerate(zip(problem.cameras, problem.d_offset)):
        sensor = next((sensor_of_image[int(i)] for i in np.flatnonzero(problem.image_camera == c)), None)
        column = start + np.cumsum(cam.free) - 1
        reference = cam.reference
        for i in range(cam.size):
            core = i < cam.n_core
            add(owner=cam.camera_id, kind="core" if core else "ap", name=cam.names[i],
                unit=cam.units[i] if i < len(cam.units) else ("" if core else "px"),
                group=(sensor.camera_parameters[i].group if sensor is not None else "IOP") if core else "AP",
                free=bool(cam.free[i]), screenable=bool(cam.core_screened[i]) if core else True,
                index=int(column[i]) if cam.free[i] else -1, start=float(cam.prior_value[i]),
                reference=float(reference[i]),
                value=float(state.cameras[c][i]) if state is not None else np.nan,
                key=("core", cam.camera_id) if core else cam.camera_id, position=i if core else i - cam.n_core)
    first, full = problem.n_e + problem.n_d, 0
    for block in problem.trajectory:
        column = first + np.cumsum(block.free) - 1
        initial = block.initial()
        for i, name in enumerate(block.names):
            add(owner=block.sensor, kind="trajectory", name=name, unit="m" if block.offset == 0 else "rad",
                group=block.sensor, free=bool(block.free[i]), screenable=True,
                index=int(column[i]) if block.free[i] else -1, start=float(initial[i]), reference=float(initial[i]),
                value=float(state.extra[full + i]) if state is not None else np.nan, key=block.sensor, position=i)
        first += int(block.free.sum())
        full += block.n_params
    index = np.array(rows["index"], np.int64)
    sigma = np.full(len(index), np.nan)
    if theta_sigma is not None:
        has = (index >= 0) & np.array(rows["free"], bool)
        sigma[has] = theta_sigma[index[has]]
    text = {c: np.array(rows[c], dtype=object) for c in ("owner", "kind", "name", "unit", "group")}
    return ParameterTable(**text, free=np.array(rows["free"], bool), screenable=np.array(rows["screenable"], bool),
                          index=index, start=np.array(rows["start"], float),
                          reference=np.array(rows["reference"], float), value=np.array(rows["value"], float),
                          sigma=sigma, key=rows["key"], position=np.array(rows["position"], np.int64))
