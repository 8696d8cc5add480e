"""Seed 001's workflows for pushbroom blocks: the focal-length step, GCP layouts, mono and stereo cases.

As in the paper, the focal length of each camera is calibrated first (M7 on all images with every
GCP of the block) and then held for every model; the models differ in which attitude corrections
they estimate. The GCPs of a case are chosen among the block's gcp points, spread over the scene
(:data:`GCP_LAYOUTS`); every other gcp and chk point is a check point. In mono, check points are
restituted on the terrain from their image coordinates in the one image; in stereo they are tie
points of the adjustment (:mod:`.checks`). Errors are given across track (X), along track (Y) and
up (Z) at the scene centre of the block's middle image (seed 001, Tables 3-6).

A case is one tested adjustment (:func:`selfcal.workflows.tested.adjust_with_tests`) of a sub-block;
nothing here solves anything of its own.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..adjust import AdjustOptions
from ..block import Block
from ..errors import AdjustmentError, UsageError
from ..sensors import sensor_of
from ..sensors.pushbroom import M6_SIGMA, PushbroomSensor
from ..sensors.pushbroom import track_frame as line_track_frame
from ..stats.screening import ScreeningOptions
from ..stats.snooping import SnoopingOptions
from ..stats import checks
from .tested import TestedAdjustment, adjust_with_tests, prune_for

__all__ = ["GCP_LAYOUTS", "ATTITUDE_FREE_SIGMA", "PushbroomCase", "image_sets", "choose_gcps", "case_block",
           "with_focal", "calibrate_focal", "run_case", "needs_focal_step", "track_frame"]

#: where the GCPs of a case are, as (row, col) fractions of the middle image: spread over the scene
GCP_LAYOUTS = {
    3: ((0.1, 0.1), (0.1, 0.9), (0.9, 0.5)),
    4: ((0.1, 0.1), (0.1, 0.9), (0.9, 0.1), (0.9, 0.9)),
    5: ((0.1, 0.1), (0.1, 0.9), (0.9, 0.1), (0.9, 0.9), (0.5, 0.5)),
}
#: M6 without the given attitude (seed 001, Table 5): the constant terms are free to take the whole
#: attitude (loose weights), the linear terms keep M6's weights
ATTITUDE_FREE_SIGMA = {**M6_SIGMA, "d_roll0": 1e-2, "d_pitch0": 1e-2, "d_yaw0": 1e-2}


@dataclass
class PushbroomCase:
    """One case of seed 001: a sensor model, its GCPs and images, the tested adjustment and the check points."""

    model: str
    n_gcp: int
    images: str                      # label of the image set
    gcps: np.ndarray                 # point indices of the block
    tested: TestedAdjustment | None
    checks: checks.CheckPoints | None
    track_axes: np.ndarray           # (3, 3) rows: across, along, up at the middle image's scene centre
    failure: str = ""
    block: Block | None = None       # the case's block (images, control and check points of the case)
    track_centre: np.ndarray | None = None   # the middle image's scene centre (ECEF)

    @property
    def result(self):
        return None if self.tested is None else self.tested.result

    @property
    def check_errors_m(self) -> np.ndarray | None:
        """d = estimate - reference at the check points, across / along / up (n, 3)."""
        if self.checks is None:
            return None
        return (self.checks.estimate - self.checks.reference) @ self.track_axes.T

    @property
    def rmse_m(self) -> np.ndarray | None:
        """RMSE across / along / up at the check points (None when the case failed or has none)."""
        e = self.check_errors_m
        if self.failure or e is None or not len(e):
            return None
        return np.sqrt(np.mean(e ** 2, axis=0))

    @property
    def n_check(self) -> int:
        return 0 if self.checks is None else len(self.checks)

    @property
    def sigma0(self) -> float:
        """A-posteriori sigma of unit weight (unitless)."""
        return float("nan") if self.result is None else float(np.sqrt(self.result.variance_factor))


def _with_sensor(options: AdjustOptions | None, model: str, parameter_sigma: Any = ...) -> AdjustOptions:
    """``options`` (default ones if None) with the sensor model ``model`` (and these parameter sigmas, if given)."""
    options = options or AdjustOptions()
    sensor = replace(options.sensor, model=model)
    if parameter_sigma is not ...:
        sensor = replace(sensor, parameter_sigma=parameter_sigma)
    return replace(options, sensor=sensor)


def image_sets(block: Block) -> dict[str, tuple[int, ...]]:
    """Mono for every image, stereo for the first two and for all (F+N, F+N+B for a triplet)."""
    ids = [str(i) for i in block.images.image_id]
    sets: dict[str, tuple[int, ...]] = {i: (k,) for k, i in enumerate(ids)}
    if len(ids) >= 2:
        sets["+".join(ids[:2])] = (0, 1)
    if len(ids) >= 3:
        sets["+".join(ids)] = tuple(range(len(ids)))
    return sets


def choose_gcps(block: Block, n: int | None) -> np.ndarray:
    """``n`` of the block's gcp points, those nearest to the layout of :data:`GCP_LAYOUTS` in the
    middle image (all of them when ``n`` is None or the block has no more)."""
    candidates = np.flatnonzero(block.points.role == "gcp")
    if n is None or n >= candidates.size:
        return candidates
    if n not in GCP_LAYOUTS:
        raise UsageError(f"--gcps {n}: choose 3, 4 or 5 of the block's {candidates.size} gcp")
    middle = len(block.images) // 2
    camera = block.cameras[block.images.camera_id[middle]]
    obs = block.observations
    mine = (obs.image_index == middle) & np.isin(obs.point_index, candidates)
    rows, cols = obs.pixel[mine, 1] / camera.rows, obs.pixel[mine, 0] / camera.columns
    points = obs.point_index[mine]
    chosen: list[int] = []
    for r, c in GCP_LAYOUTS[n]:
        for k in np.argsort((rows - r) ** 2 + (cols - c) ** 2):
            if points[k] not in chosen:
                chosen.append(int(points[k]))
                break
    return np.array(chosen)


def case_block(block: Block, image_set, gcps: np.ndarray, mono: bool | None = None) -> Block:
    """The sub-block of a case: the images ``image_set`` (indices), ``gcps`` as control and every other
    point with reference coordinates as check point; in mono only the control is observed (the check
    points are restituted, :func:`selfcal.workflows.checks.restituted`)."""
    mono = len(image_set) == 1 if mono is None else mono
    pts = block.points
    control = np.isin(np.arange(len(pts)), gcps)
    role = np.where(control, "gcp", np.where(pts.role == "tie", "tie", "chk")).astype(object)
    obs = block.observations
    keep = np.isin(obs.image_index, image_set)
    if mono:
        keep &= control[obs.point_index]
    sub = replace(block, points=replace(pts, role=role), observations=obs.take(np.flatnonzero(keep)))
    return prune_for(sub)


def with_focal(block: Block, focal_mm: dict[str, float]) -> Block:
    """``block`` with the focal lengths of some cameras replaced (camera id -> mm)."""
    cameras = {k: replace(c, focal_mm=float(focal_mm[k])) if k in focal_mm else c for k, c in block.cameras.items()}
    return replace(block, cameras=cameras)


def needs_focal_step(sensor_model: str) -> bool:
    """Seed 001 calibrates the focal lengths first unless the model estimates them itself (M3, M4, M7)."""
    from ..sensors.pushbroom import sensor_model as parse
    return "focal" not in parse(sensor_model).free


def calibrate_focal(block: Block, gcps: np.ndarray | None = None, options: AdjustOptions | None = None,
                    robust=None) -> tuple[dict[str, float], dict[str, float]]:
    """Step 1 of seed 001: each camera's focal length (mm) and its sigma, from M7 on all images and
    every gcp (``gcps``: indices of the block's points; default all its gcp); ``robust``: the robust cleaning
    of the adjustment it is a step of (:class:`~selfcal.adjust.RobustOptions`), else least squares."""
    gcps = np.flatnonzero(block.points.role == "gcp") if gcps is None else gcps
    options = _with_sensor(options, "M7", None)
    sub = case_block(block, tuple(range(len(block.images))), gcps, mono=False)
    try:
        tested = adjust_with_tests(sub, options, snooping=None, robust=robust)
    except AdjustmentError as exc:
        raise AdjustmentError(f"focal-length calibration (M7 on all images) failed: {exc}") from None
    result = tested.result
    if not result.converged:
        raise AdjustmentError(f"focal-length calibration (M7 on all images) failed: {result.reason}")
    sigmas = result.camera_sigma()
    values = {cam.camera_id: float(v[0]) for cam, v in zip(result.problem.cameras, result.state.cameras)}
    sigma = {cam.camera_id: float(s[0]) for cam, s in zip(result.problem.cameras, sigmas)}
    return values, sigma


def track_frame(block: Block) -> tuple[np.ndarray, np.ndarray]:
    """The scene centre of the block's middle image (ECEF) and the across, along, up axes there (rows)."""
    middle = len(block.images) // 2
    sensor = sensor_of(block.cameras[block.images.camera_id[middle]])
    assert isinstance(sensor, PushbroomSensor), "seed 001's workflows are for line images"   # (its sensor models)
    return line_track_frame(sensor.line_image(block, middle))


def run_case(block: Block, model: str, gcps: np.ndarray, image_set, height=None, label: str = "",
             options: AdjustOptions | None = None, snooping: SnoopingOptions | None = None,
             screening: ScreeningOptions | None = None, progress=None, report=None,
             variance=None, robust=None) -> PushbroomCase:
    """One adjustment with ``gcps`` (point indices) as control on the images ``image_set``; check points
    are the other points with reference coordinates, restituted on ``height`` (a DEM callable or metres;
    mono) or intersected (stereo). ``options`` gives the AP model and weights; its ``sensor_model`` is
    ``model``. With ``snooping``, Baarda's data snooping; with ``screening``, the calibration parameters
    are screened (:func:`~selfcal.workflows.tested.adjust_with_tests`)."""
    mono = len(image_set) == 1
    options = _with_sensor(options, model)
    centre, axes = track_frame(block)
    name = model.upper() if model.upper() in ("M1", "M2", "M3", "M4", "M5", "M6", "M7") else model
    known = np.flatnonzero(~np.isnan(block.points.xyz_m).any(axis=1))
    others = np.setdiff1d(known, gcps)
    if mono and height is None and others.size:
        raise UsageError(f"a mono adjustment restitutes the check points ({others.size}) on the terrain: give a DEM "
                         f"or a height")
    sub = case_block(block, image_set, gcps, mono)
    base: dict[str, Any] = dict(model=name, n_gcp=len(gcps), images=label, gcps=np.asarray(gcps), track_axes=axes,
                                block=sub, track_centre=centre)
    try:
        tested = adjust_with_tests(sub, options, snooping, screening, progress=progress, report=report,
                                   variance=variance, robust=robust)
    except AdjustmentError as exc:
        return PushbroomCase(tested=None, checks=None, failure=str(exc), **base)
    result = tested.result
    if tested.failure:
        return PushbroomCase(tested=tested, checks=None, failure=tested.failure, **base)
    if not result.converged:
        return PushbroomCase(tested=tested, checks=None, failure=f"no convergence in {result.iterations} iterations",
                             **base)
    if mono:
        image_id = str(block.images.image_id[image_set[0]])
        found = checks.restituted(result, block, image_id, others, height)
    else:
        found = checks.intersected(result)
    return PushbroomCase(tested=tested, checks=found, **base)
