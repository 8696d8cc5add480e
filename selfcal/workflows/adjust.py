"""``selfcal adjust``: one block, whatever its sensors, from the block to what the results folder holds.

Frame and BAL blocks: the AP model (or its choice by prediction, :mod:`.model_choice`) and the tested
adjustment (:mod:`.tested`); the check points are those intersected in it. Blocks of a sensor that
offers seed 001's sensor models (pushbroom images): the focal-length step, the GCP layout, the images
of the case and the check points by intersection or mono restitution (:mod:`.seed001`). Either way
the outcome is one :class:`~selfcal.workflows.tested.TestedAdjustment` with its check points, written
by :func:`selfcal.report.result_files` in one schema.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Callable

import numpy as np

from ..adjust import AdjustOptions, RobustOptions, control_far_away, control_on_a_line, undetermined_points
from ..ap import takes_grid
from ..block import Block
from ..convert.control import block_control_swapped
from ..errors import AdjustmentError, BlockError, UsageError
from ..geometry.tangent import TangentPlane
from ..sensors import sensor_of
from ..stats.effect import MIN_EFFECT_PX
from ..stats.screening import ScreeningOptions
from ..stats.snooping import SnoopingOptions
from ..stats.variance import VarianceOptions
from ..stats import checks as check_points
from ..stats.correlation import correlation_figures
from ..stats.plausibility import collapse
from . import seed001
from .frames import loo_in_crs, object_frame_block, tangent_plane_block
from .half_block import half_block_check, half_block_notes, half_block_summary
from .jackknife import calibration_precision
from .loo import control_loo, loo_notes, loo_summary
from .model_choice import ModelChoice, choose_ap_model
from .terrain import name_terrain_points
from .tested import TestedAdjustment, adjust_with_tests

__all__ = ["AdjustRequest", "Adjusted", "adjust_block", "offers_sensor_models", "default_ap_model", "ap_candidates",
           "is_auto", "DEFAULT_FRAME_CANDIDATES", "run_options"]


@dataclass(frozen=True)
class AdjustRequest:
    """What ``selfcal adjust`` was asked to do."""

    options: AdjustOptions = field(default_factory=AdjustOptions)
    snooping: SnoopingOptions | None = field(default_factory=SnoopingOptions)
    screening: ScreeningOptions | None = None
    variance: VarianceOptions | None = None
    # robust cleaning before the tests (None: least squares throughout)
    robust: RobustOptions | None = field(default_factory=RobustOptions)
    candidates: list | None = None          # (model, grid) of --ap auto: choose the AP model by prediction
    #: --ap auto: a richer model must predict better than a simpler one by more than a field of this (px)
    min_effect_px: float = MIN_EFFECT_PX
    # seed 001 (sensors with sensor models)
    image_ids: tuple[str, ...] | None = None
    n_gcp: int | None = None
    keep_focal: bool = False
    height: object = None                   # terrain for mono restitution: a DEM callable or metres
    # validate the control point by point, each left out in turn (frame and BAL blocks; :mod:`.loo`)
    control_loo: bool = True
    # Table 4's further figures: the correlations in an orthonormal AP basis, the canonical correlations and the
    # design cosines (:func:`selfcal.stats.correlation.correlation_figures`)
    orthonormal: bool = False
    # the jackknife of the calibration over this many groups of images (0: none; :mod:`.jackknife`)
    jackknife: int = 0
    # calibrate each half of the block on its own and compare (frame APs; :mod:`.half_block`)
    half_block: bool = True


@dataclass
class Adjusted:
    tested: TestedAdjustment
    block: Block                            # the block as adjusted (before data snooping): residuals.csv lists it
    checks: check_points.CheckPoints
    summary_extra: dict
    track: tuple | None = None              # (centre, axes) of seed 001's across / along / up errors
    choice: ModelChoice | None = None
    #: the tangent plane a block in a projected CRS was adjusted in (``block``, ``tested`` and ``checks`` are in
    #: it; :func:`selfcal.report.result_files` writes the results back in the CRS), None: the block's own frame
    plane: TangentPlane | None = None


#: the AP models a frame camera chooses between when no model is asked for (issue 45 item 4): on 12 simulated
#: blocks (no distortion, Brown's, a local field + Brown's; Type 1 and Type 3 control; benchmarks/
#: study_default_ap.py) BIC chose none for every distortion-free lens, where brown costs up to 29 % in Z at the
#: check points, and brown for every distorted one, where none is 5-19x worse in Z
DEFAULT_FRAME_CANDIDATES = ("none", "brown")


def default_ap_model(block: Block) -> str:
    """The AP model of an adjustment that asks for none: for frame cameras whose calibration is not held, the
    better of none and brown by BIC on the same observations (``auto:none,brown``); otherwise ``none`` (a mission
    camera's ISD, pushbroom and RPC images, BAL: their sensors model what they know)."""
    cameras = list(block.cameras.values())
    held = [c for c in cameras if getattr(c, "initial_ap", None) is not None and c.initial_ap.sigma_px == 0]
    if cameras and all(c.model == "frame" for c in cameras) and len(held) < len(cameras):
        return "auto:" + ",".join(DEFAULT_FRAME_CANDIDATES)
    return "none"


def is_auto(spec: str) -> bool:
    """Whether an AP model spec asks for the model choice (``auto`` or ``auto:MODEL,...``)."""
    return spec == "auto" or spec.startswith("auto:")


def ap_candidates(spec: str, grid: tuple[int, int]) -> list[tuple[str, tuple[int, int]]]:
    """The (model, grid) candidates of ``auto`` (the ten models of seed 000's comparison, each wavelet family on
    every grid of :data:`~selfcal.workflows.model_choice.GRID_LADDER`) or ``auto:MODEL,MODEL@GxXGy,...`` (a wavelet
    without a grid on ``grid``); UsageError for an unknown model."""
    from ..ap import ALL_MODELS, AP_FAMILIES, parse_ap_spec, takes_grid
    from .model_choice import GRID_LADDER, parse_candidate
    listed = spec.partition(":")[2]
    if not listed:
        return [(m, g) for m in ALL_MODELS for g in (GRID_LADDER if takes_grid(m) else (grid,))]
    names = [m for m in listed.split(",") if m.strip()]
    candidates = []
    for name in names:
        try:
            model, grid_ = parse_candidate(name, grid)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        if parse_ap_spec(model)[0] not in AP_FAMILIES:
            raise UsageError(f"unknown AP model '{model}' in --ap {spec} (known: {', '.join(AP_FAMILIES)})")
        candidates.append((model, grid_))
    return candidates


def offers_sensor_models(block: Block) -> bool:
    """Whether the block's sensors offer seed 001's sensor models (and with them its workflow)."""
    return any(sensor_of(c).sensor_models for c in block.cameras.values())


def adjust_block(block: Block, request: AdjustRequest, progress: Callable | None = None,
                 report: Callable | None = None, say: Callable[[str], None] | None = None,
                 scores: Callable | None = None) -> Adjusted:
    """The tested adjustment of ``block`` as ``request`` asks (module docstring); ``say`` receives one-line
    messages on the way (the focal lengths, the chosen model), ``scores`` each candidate of ``--ap auto``.
    Its ``summary_extra`` holds the run's options (:func:`run_options`: summary.json ``options``)."""
    adjusted = _adjust_block(block, request, progress, report, say, scores)
    adjusted.summary_extra = {"options": run_options(block, request)} | adjusted.summary_extra
    if request.orthonormal and adjusted.tested.result.converged:
        adjusted.summary_extra |= correlation_figures(adjusted.tested.result)
    return adjusted


def run_options(block: Block, request: AdjustRequest) -> dict:
    """What the run was asked to do, for summary.json ``options`` (the report's processing parameters): the
    request's options (the AP model asked for, ``auto`` for the model choice; snooping, screening, robust cleaning,
    variance components, solver) and the block's a-priori weights: the sigma of an image coordinate, the median
    sigma of the control points (XY, Z; None where none is given), the GNSS and IMU sigmas."""
    o = request.options
    gcp = block.points.role == "gcp"
    sigma = block.points.sigma_m[gcp] if gcp.any() else np.zeros((0, 3))

    def median(values: np.ndarray) -> float | None:
        finite = values[np.isfinite(values)]
        return float(np.median(finite)) if finite.size else None
    sensor = {k: v for k, v in asdict(o.sensor).items() if v is not None} if offers_sensor_models(block) else None
    return {
        "ap_model": "auto" if request.candidates else o.ap.model,
        "ap_candidates": [f"{m}@{g[0]}x{g[1]}" if takes_grid(m) else m for m, g in request.candidates]
        if request.candidates else None,
        "grid": list(o.ap.grid),
        "ap_at": o.ap.evaluated_at,
        "ap_cameras": list(o.ap.cameras) if o.ap.cameras else None,
        "ap_sigma_px": o.ap.sigma_px,
        "image_sigma_px": float(block.image_sigma_px),
        "n_control": int(gcp.sum()),
        "control_sigma_xy_m": median(sigma[:, :2].ravel()),
        "control_sigma_z_m": median(sigma[:, 2]),
        "gnss_sigma_m": None if block.gnss_sigma_m is None else list(block.gnss_sigma_m),
        "imu_sigma_deg": None if block.imu_sigma_deg is None else list(block.imu_sigma_deg),
        "trajectory": asdict(o.trajectory) if block.has_trajectory else None,
        "sensor": sensor,
        "max_iterations": int(o.solver.max_iterations),
        "snooping": None if request.snooping is None else asdict(request.snooping),
        "screening": None if request.screening is None else asdict(request.screening),
        "robust": None if request.robust is None else asdict(request.robust),
        "variance_components": None if request.variance is None else asdict(request.variance),
        "image_ids": list(request.image_ids) if request.image_ids else None,
        "n_gcp": request.n_gcp,
        "keep_focal": bool(request.keep_focal),
        "orthonormal": bool(request.orthonormal),
        "jackknife": int(request.jackknife),
    }


def _adjust_block(block: Block, request: AdjustRequest, progress: Callable | None, report: Callable | None,
                  say: Callable[[str], None] | None, scores: Callable | None) -> Adjusted:
    say = say or (lambda text: None)
    _check_control_axes(block)
    block = object_frame_block(block)
    # the tie points of the terrain observations named once, for every adjustment below (issue 42)
    block = name_terrain_points(block, request.options)
    if offers_sensor_models(block):
        return _seed001(block, request, progress, report, say, scores)
    block, plane = tangent_plane_block(block)
    options, choice, reference = request.options, None, None
    _check_control(block)                   # before any work: the model choice adjusts too
    if request.candidates:
        choice = choose_ap_model(block, request.candidates, options, request.snooping, progress=scores,
                                 robust=request.robust, min_effect_px=request.min_effect_px)
        reference, choice = choice.tested, replace(choice, tested=None)     # (not kept beyond this run's start)
        options = replace(options, ap=replace(options.ap, model=choice.model, grid=choice.grid))
        say(f"chosen AP model: {choice.model}" + (f"@{choice.grid[0]}x{choice.grid[1]}" if
                                                  takes_grid(choice.model) else "") + _choice_reason(choice))
    jitter: dict = {}
    chosen = options
    options = _resolve_jitter(block, options, say, jitter)
    if reference is not None and options is chosen and request.screening is None and request.variance is None:
        # the reference of the model choice is the chosen model, adjusted with the same tests
        tested = reference
        say(f"the chosen model is the model choice's reference: its tested adjustment is the result "
            f"({len(tested.rejected_rows)} observations rejected)")
    else:
        reference = None                    # (its memory free before the tested adjustment runs)
        tested = adjust_with_tests(block, options, request.snooping, request.screening, progress=progress,
                                   report=report, variance=request.variance, robust=request.robust)
    _check_collapse(tested)
    extra = _check_points_determined(block, tested) | jitter
    if request.control_loo and tested.result.converged and not tested.failure:
        tested.loo = control_loo(tested, options, say)
        if tested.loo is not None:
            if plane is not None:           # (its errors along the CRS's coordinates, as the control's sigmas)
                tested.loo = loo_in_crs(tested.loo, plane, tested.result.block.points)
            extra["control_loo"] = loo_summary(tested.loo)
            tested.result.notes.extend(loo_notes(tested.loo))
    if request.half_block and tested.result.converged and not tested.failure:
        tested.half_block = half_block_check(tested, options, say)
        if tested.half_block is not None:
            extra["half_block"] = half_block_summary(tested.half_block)
            tested.result.notes.extend(half_block_notes(tested.half_block))
    if tested.result.converged and not tested.failure:
        precision, note = calibration_precision(tested, options, request.jackknife, say)
        if precision is not None:
            extra["calibration_precision"] = precision
        if note:
            tested.result.notes.append(note)
    if plane is not None:
        extra["object_frame"] = plane.describe()
    return Adjusted(tested, block, check_points.intersected(tested.result), extra, choice=choice, plane=plane)


def _without_jitter(options: AdjustOptions) -> AdjustOptions:
    return replace(options, sensor=replace(options.sensor, jitter="none", jitter_sigma_rad=None, jitter_axes=None))


def _resolve_jitter(block: Block, options: AdjustOptions, say: Callable[[str], None], extra: dict) -> AdjustOptions:
    """``options`` with the line images' jitter chosen by the data where ``--jitter`` leaves its level or its sigma to
    it (:mod:`.jitter`); the choice goes to ``extra["jitter"]`` (summary.json)."""
    from ..sensors.pushbroom.jitter import parse_jitter
    from .jitter import choose_jitter
    from ..errors import UsageError
    from ..sensors import sensor_of
    from ..sensors.pushbroom import PushbroomSensor
    spec = parse_jitter(options.sensor.jitter)
    if spec is None:
        return options
    if not any(isinstance(sensor_of(c), PushbroomSensor) for c in block.cameras.values()):
        raise UsageError(f"--jitter {options.sensor.jitter}: the block has no line images (pushbroom, usgscsm-line, "
                         f"dimap, dg) whose attitude it could correct")
    if spec.level is not None and options.sensor.jitter_sigma_rad is not None:
        extra["jitter"] = {"jitter": spec.text, "sigma_urad": list(np.atleast_1d(options.sensor.jitter_sigma_rad) * 1e6),
                           "chosen": False}
        return options
    say(f"choosing the attitude jitter ({spec.text}): levels and their power by the data")
    choice = choose_jitter(block, options, say=say)
    extra["jitter"] = choice.as_dict() | {"chosen": True}
    say(f"chosen jitter: {choice.spec}" + ("" if choice.sigma_rad is None else
                                           " (" + ", ".join(f"{a} {s * 1e6:.2f} urad" for a, s in
                                                            zip(choice.axes, choice.sigma_rad)) + ")"))
    return choice.options(options)


def _choice_reason(choice: ModelChoice) -> str:
    """What the chosen-model line says of the choice (:mod:`.model_choice`)."""
    if choice.rule == "bic":
        return (f" (smallest BIC: the block has more orientation and camera unknowns than the cross-validation's "
                f"fold systems take; scores in model_choice.csv)")
    if not choice.by_prediction:
        return (" (no candidate converged: the first one is adjusted)" if not choice.reference else
                f" (no candidate could be cross-validated: the reference {choice.reference} is adjusted)")
    scored = [s for s in choice.candidates if s.prediction is not None]
    best = min(scored, key=lambda s: s.prediction.rmse_px)          # type: ignore[union-attr]
    chosen = next(s for s in scored if s.model == choice.model and s.grid == choice.grid)
    assert chosen.prediction is not None and best.prediction is not None
    return (f" (the simplest within one standard error of the best prediction: {chosen.prediction.rmse_px:.4f} px "
            f"against {best.label}'s {best.prediction.rmse_px:.4f} ± {best.prediction.se_px:.4f} px; "
            f"{choice.n_blunders} observations left out as blunders for every candidate; scores in model_choice.csv)")


def _check_control_axes(block: Block) -> None:
    """BlockError (exit 2, before any work) when points.csv's control looks swapped (northing, easting; latitude,
    longitude) against the images' positions (:func:`selfcal.convert.control.block_control_swapped`)."""
    reason = block_control_swapped(block)
    if reason:
        raise BlockError("points.csv", reason)


def _check_collapse(tested: TestedAdjustment) -> None:
    """A solution that collapsed (:func:`selfcal.stats.plausibility.collapse`) has not converged: it fails, and says
    what collapsed and where it started."""
    reason = collapse(tested.result)
    if reason:
        tested.result.converged = False
        tested.result.reason = reason
        tested.failure = tested.failure or reason


def _check_control(block: Block) -> None:
    """AdjustmentError (exit 1, before any work) when the control that is to fix the datum lies on one line."""
    sensors = [sensor_of(c) for c in block.cameras.values()]
    if block.datum != "control" or block.has_trajectory or all(s.object_frame == "ECEF" for s in sensors):
        return
    gcp = np.flatnonzero(block.points.role == "gcp")
    span = np.vstack([block.points.xyz_m, block.images.position_m])
    reason = control_far_away(block.points.point_id[gcp], block.points.xyz_m[gcp], span, block.points.line[gcp]) or \
        control_on_a_line(block.points.point_id[gcp], block.points.xyz_m[gcp], block.points.sigma_m[gcp], span)
    if reason:
        raise AdjustmentError(reason)


def _check_points_determined(block: Block, tested: TestedAdjustment) -> dict:
    """Object points whose sigma is orders of magnitude above the block's median: a failure of a block whose
    datum is fixed (summary.json failure, exit 1), a warning counted in summary.json for a free network."""
    result = tested.result
    sigma = np.sqrt(np.trace(result.point_covariance(), axis1=1, axis2=2))
    found = undetermined_points(result.block.points.point_id, sigma)
    if found is None:
        return {}
    bad, reason = found
    result.notes.append(reason)
    extra: dict = {"n_points_undetermined": int(bad.size)}
    if block.datum != "free" and not tested.failure:
        extra["failure"] = reason
    return extra


def _seed001(block: Block, request: AdjustRequest, progress, report, say, scores) -> Adjusted:
    options = request.options
    model = options.sensor.model or "M6"
    extra: dict = {"sensor_model": model}
    if not request.keep_focal and seed001.needs_focal_step(model):
        # (the focal length's step without jitter: the jitter is chosen for the case's images below)
        focal, sigma = seed001.calibrate_focal(block, options=_without_jitter(options), robust=request.robust)
        block = seed001.with_focal(block, focal)
        extra["calibrated_focal_mm"] = {k: {"value": v, "sigma": sigma[k]} for k, v in focal.items()}
        say("focal lengths (M7 on all images): " + ", ".join(f"{k} {v:.3f} ± {sigma[k]:.3f} mm"
                                                               for k, v in focal.items()))
    ids = [str(i) for i in block.images.image_id]
    chosen = list(request.image_ids) if request.image_ids else ids
    unknown = [i for i in chosen if i not in ids]
    if unknown or len(set(chosen)) != len(chosen):
        raise UsageError(f"--images {','.join(chosen)}: give distinct image ids of the block ({', '.join(ids)})")
    image_set = tuple(ids.index(i) for i in chosen)
    gcps = seed001.choose_gcps(block, request.n_gcp)
    say(f"{block.name}: images {', '.join(chosen)}, {len(gcps)} GCP, sensor model {model}")
    choice = None
    if request.candidates:
        sub = seed001.case_block(block, image_set, gcps)
        choice = choose_ap_model(sub, request.candidates,
                                 replace(options, sensor=replace(_without_jitter(options).sensor, model=model)),
                                 request.snooping, progress=scores, robust=request.robust,
                                 min_effect_px=request.min_effect_px)
        options = replace(options, ap=replace(options.ap, model=choice.model, grid=choice.grid))
        say(f"chosen AP model: {choice.model}" + _choice_reason(choice))
    options = _resolve_jitter(seed001.case_block(block, image_set, gcps), options, say, extra)
    case = seed001.run_case(block, model, gcps, image_set, request.height, "+".join(chosen), options,
                            request.snooping, request.screening, progress, report, request.variance, request.robust)
    if case.tested is None:
        from ..errors import AdjustmentError
        raise AdjustmentError(case.failure)
    _check_collapse(case.tested)
    rmse = case.rmse_m
    extra |= {"images": chosen, "gcp_ids": [str(block.points.point_id[p]) for p in gcps],
              "rmse_chk_across_m": None if rmse is None else float(rmse[0]),
              "rmse_chk_along_m": None if rmse is None else float(rmse[1]),
              "rmse_chk_up_m": None if rmse is None else float(rmse[2])}
    if case.failure and not case.tested.failure:
        extra["failure"] = case.failure
    fitted = [k for k, i in enumerate(block.images.image_id) if i not in (block.image_models or {})]
    if fitted:
        from ..sensors.pushbroom import line_images
        images = line_images(block, options.sensor.attitude_telemetry, image_index=fitted)
        extra["trajectory_fit_rms"] = {img.image_id: {k: np.asarray(v).tolist() for k, v in img.trajectory.fit_rms.items()}
                                       for img in images}
    found = case.checks if case.checks is not None else check_points.intersected(case.tested.result)
    assert case.block is not None                   # (run_case gives every case its block)
    return Adjusted(case.tested, case.block, found, extra, (case.track_centre, case.track_axes), choice)
