"""``selfcal.bundle_adjust``: the tested adjustment of ``selfcal adjust`` for a program that calls selfcal.

The CLI's defaults, as keyword arguments; progress goes to ``logging.getLogger("selfcal")``.
"""
from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from typing import TypeVar

from ..adjust import AdjustOptions, RobustOptions, SolverOptions
from ..block import Block
from ..errors import SelfcalError, UsageError
from ..stats.screening import ScreeningOptions
from ..stats.snooping import SnoopingOptions
from ..stats.variance import VarianceOptions
from .adjust import Adjusted, AdjustRequest, adjust_block, ap_candidates, default_ap_model, is_auto, \
    offers_sensor_models
from .progress import LOG, logging_progress, logging_rounds

__all__ = ["bundle_adjust", "Outcome", "OPTION_KEYWORDS", "adjust_options"]

#: the keywords of :func:`bundle_adjust` beyond its own, named as the CLI's flags: the group of
#: :class:`~selfcal.adjust.AdjustOptions` and the field each sets
OPTION_KEYWORDS = {
    "grid": ("ap", "grid"), "ap_cameras": ("ap", "cameras"), "ap_sigma_px": ("ap", "sigma_px"),
    "ap_at": ("ap", "evaluated_at"),
    "gnss_drift": ("trajectory", "gnss_drift"), "imu_drift": ("trajectory", "imu_drift"),
    "lever_arm": ("trajectory", "lever_arm"), "boresight": ("trajectory", "boresight"),
    "sensor_model": ("sensor", "model"), "parameter_sigma": ("sensor", "parameter_sigma"),
    "attitude_telemetry": ("sensor", "attitude_telemetry"),
}


def adjust_options(ap: str, max_iterations: int, keywords: dict) -> AdjustOptions:
    """The :class:`~selfcal.adjust.AdjustOptions` of ``bundle_adjust(block, ap, max_iterations=..., **keywords)``;
    a keyword it does not know: :class:`~selfcal.errors.UsageError` naming it.

    >>> adjust_options("wavelet:db4", 50, {"grid": (5, 4), "gnss_drift": 0}).trajectory.gnss_drift
    0
    """
    unknown = sorted(set(keywords) - set(OPTION_KEYWORDS))
    if unknown:
        raise UsageError(f"bundle_adjust({unknown[0]}=...): not an argument (the options' keywords: "
                         f"{', '.join(OPTION_KEYWORDS)})")
    base = AdjustOptions()
    groups: dict[str, dict] = {"ap": {"model": ap}, "trajectory": {}, "sensor": {}}
    for name, value in keywords.items():
        group, field_name = OPTION_KEYWORDS[name]
        groups[group][field_name] = value
    return AdjustOptions(ap=replace(base.ap, **groups["ap"]),
                         trajectory=replace(base.trajectory, **groups["trajectory"]),
                         sensor=replace(base.sensor, **groups["sensor"]),
                         solver=SolverOptions(max_iterations=max_iterations))

T = TypeVar("T")


@dataclass
class Outcome:
    """A tested adjustment and the files of its results folder (as data, DESIGN.md §4)."""

    adjusted: Adjusted
    files: dict
    #: the files and folders the adjustment read (the block folder, a DEM): write never goes there
    inputs: tuple = ()

    @property
    def summary(self) -> dict:
        """summary.json as a dict."""
        return self.files["summary.json"]

    @property
    def result(self):
        """The final :class:`selfcal.adjust.AdjustmentResult` (estimates, covariance, residuals)."""
        return self.adjusted.tested.result

    @property
    def failed(self) -> str | None:
        """Why the adjustment failed (summary.json ``failure``, or that it did not converge), or None."""
        if self.summary.get("failure"):
            return str(self.summary["failure"])
        if not self.adjusted.tested.result.converged:
            return f"the adjustment did not converge: {self.adjusted.tested.result.reason}"
        return None

    def write(self, folder: str | os.PathLike, report: bool = True, force: bool = False) -> str | None:
        """Write the results folder (atomically: complete or not at all), with report.html unless told not to;
        returns the folder written (None: a failed outcome that had nowhere to go).

        The folder passes the check of every ``--out`` (:func:`selfcal.io.output.output_folder`): never the
        block folder, its sensor files or DEM (nor a folder holding or inside them), never a folder that selfcal
        did not write (no ``.selfcal-output`` in it) unless ``force``; a refusal is a
        :class:`~selfcal.errors.UsageError` naming the path. A failed or unconverged outcome never replaces
        earlier results: it goes to ``FOLDER-failed`` (or is not written; the warning on the ``selfcal`` logger
        says which), as ``selfcal adjust`` does. A write that fails (a full disk) is an
        :class:`~selfcal.errors.OutputError` naming the path, and the folder stays as it was.
        """
        from ..io.output import failed_run_folder, output_folder
        from ..io.results import results_from_files, write_results
        from ..report import render_report
        block = self.adjusted.block
        inputs = (block.folder, block.dem_path, *(block.image_files or {}).values(), *self.inputs)
        target = output_folder(os.fspath(folder), inputs, force, option="Outcome.write:",
                               force_name="force=True")
        if self.failed:
            where, why = failed_run_folder(target)
            LOG.warning(f"{self.failed}; {why}")
            if where is None:
                return None
            target = where
        files = dict(self.files)
        if report:
            files |= render_report(results_from_files(files))
        write_results(target, files)
        return target


def _argument(name: str, value: object, make: Callable[[], T]) -> T:
    """``make()``, its ValueError or TypeError a UsageError naming the argument ``name`` (bad input, exit code 2,
    as the CLI's options are)."""
    try:
        return make()
    except SelfcalError:
        raise
    except (ValueError, TypeError) as exc:
        raise UsageError(f"bundle_adjust({name}={value!r}): {exc}") from None


def _groups(value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"a whole number of groups, 0 or more (0: no jackknife), found {value!r}")
    return value


def bundle_adjust(block: Block | str | os.PathLike, ap: str | None = None, *, snoop: float = 3.0, screen: bool = False,
                  variance_components: bool = False, max_iterations: int = 50, robust: str = "danish",
                  control_loo: bool = True, orthonormal: bool = False, half_block: bool = True,
                  jackknife: int = 0, **options) -> Outcome:
    """The tested adjustment of ``block`` (a :class:`~selfcal.block.Block` or a block folder).

    ``ap``: the AP model (``"brown"``, ``"wavelet:db4"``..., ``"auto[:MODEL,...]"`` to choose by prediction; None: the
    default of ``selfcal adjust``, :func:`~selfcal.workflows.adjust.default_ap_model`); ``snoop``: Baarda's critical value (0: none);
    ``screen``: drop insignificant and highly correlated APs; ``variance_components``: estimate each
    observation group's sigma; ``robust``: the loss of the robust cleaning before the tests (``"danish"``,
    ``"huber"``, ``"cauchy"``; ``"none"``: least squares throughout); ``control_loo``: the leave-one-out check
    of the control (``control_loo.csv``); ``orthonormal``: Table 4's further correlation figures in summary.json
    (``selfcal adjust --orthonormal``); ``half_block``: the half-block check of the calibration (two more
    adjustments: summary.json ``half_block``, the difference columns of ``distortion_sigma.csv``); ``jackknife``:
    groups of images of the jackknife that checks the calibration's sigma (0: none; summary.json
    ``calibration_precision``); other keywords are named as the CLI's flags
    (:data:`OPTION_KEYWORDS`: ``grid``, ``gnss_drift``, ``sensor_model``...). Pushbroom blocks get seed 001's
    sensor model ``M6`` unless told. An argument that cannot be used (``snoop=-1``, an unknown keyword) is a
    :class:`~selfcal.errors.UsageError` naming it.
    """
    from ..io.block_folder import read_block
    from ..report import model_choice_table, result_files
    t0 = time.perf_counter()
    inputs: tuple = ()
    if not isinstance(block, Block):
        inputs = (os.fspath(block),)
        block = read_block(block)
    if offers_sensor_models(block):
        options.setdefault("sensor_model", "M6")
    if isinstance(snoop, bool) or not isinstance(snoop, (int, float)) or not math.isfinite(snoop) or snoop < 0:
        raise UsageError(f"bundle_adjust(snoop={snoop!r}): Baarda's critical value must be a finite number, 0 or "
                         f"more (0: no data snooping)")
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, int) or max_iterations < 1:
        raise UsageError(f"bundle_adjust(max_iterations={max_iterations!r}): must be a whole number, 1 or more")
    if ap is None:
        ap = default_ap_model(block)
    auto = isinstance(ap, str) and is_auto(ap)
    chosen = _argument("ap", ap, lambda: adjust_options("none" if auto else ap, max_iterations, options))
    candidates = _argument("ap", ap, lambda: ap_candidates(ap, chosen.ap.grid)) if auto else None
    screening = ScreeningOptions() if screen else None
    snooping = _argument("snoop", snoop, lambda: SnoopingOptions(critical=snoop))
    robust_options = None if robust == "none" else _argument("robust", robust, lambda: RobustOptions(loss=robust))
    request = AdjustRequest(chosen, snooping, screening,
                            VarianceOptions() if variance_components else None, robust_options, candidates=candidates,
                            control_loo=bool(control_loo), orthonormal=bool(orthonormal),
                            half_block=bool(half_block),
                            jackknife=_argument("jackknife", jackknife, lambda: _groups(jackknife)))
    LOG.info(f"{block.name}: {len(block.images)} images, {len(block.points)} points, {len(block.observations)} "
             f"image observations; AP model {ap}")
    adjusted = adjust_block(block, request, progress=logging_progress(block.image_sigma_px),
                            report=logging_rounds(), say=LOG.info)
    extra = {"seconds": time.perf_counter() - t0, "grid": list(chosen.ap.grid)} | adjusted.summary_extra
    files = result_files(adjusted.block, adjusted.tested, extra, screening, adjusted.checks, adjusted.track,
                         adjusted.plane)
    if adjusted.choice is not None:
        files["model_choice.csv"] = model_choice_table(adjusted.choice)
    return Outcome(adjusted, files, inputs)
