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

from ..adjust import AdjustOptions, RobustOptions
from ..adjust import SolverOptions
from ..block import Block
from ..errors import SelfcalError, UsageError
from ..stats.screening import ScreeningOptions
from ..stats.snooping import SnoopingOptions
from ..stats.variance import VarianceOptions
from .adjust import Adjusted, AdjustRequest, adjust_block, offers_sensor_models
from .progress import LOG, logging_progress, logging_rounds

__all__ = ["bundle_adjust", "Outcome"]

T = TypeVar("T")


@dataclass
class Outcome:
    """A tested adjustment and the files of its results folder (as data, DESIGN.md §4)."""

    adjusted: Adjusted
    files: dict

    @property
    def summary(self) -> dict:
        """summary.json as a dict."""
        return self.files["summary.json"]

    @property
    def result(self):
        """The final :class:`selfcal.adjust.AdjustmentResult` (estimates, covariance, residuals)."""
        return self.adjusted.tested.result

    def write(self, folder: str | os.PathLike, report: bool = True) -> None:
        """Write the results folder (atomically: complete or not at all), with report.html unless told not to."""
        from ..io.results import results_from_files, write_results
        from ..report import render_report
        files = dict(self.files)
        if report:
            files |= render_report(results_from_files(files))
        write_results(folder, files)


def _argument(name: str, value: object, make: Callable[[], T]) -> T:
    """``make()``, its ValueError or TypeError a UsageError naming the argument ``name`` (bad input, exit code 2,
    as the CLI's options are)."""
    try:
        return make()
    except SelfcalError:
        raise
    except (ValueError, TypeError) as exc:
        raise UsageError(f"bundle_adjust({name}={value!r}): {exc}") from None


def bundle_adjust(block: Block | str | os.PathLike, ap: str = "none", *, snoop: float = 3.0, screen: bool = False,
                  variance_components: bool = False, max_iterations: int = 50, robust: str = "danish",
                  **options) -> Outcome:
    """The tested adjustment of ``block`` (a :class:`~selfcal.block.Block` or a block folder).

    ``ap``: the AP model (``"brown"``, ``"wavelet:db4"``...); ``snoop``: Baarda's critical value (0: none);
    ``screen``: drop insignificant and highly correlated APs; ``variance_components``: estimate each
    observation group's sigma; ``robust``: the loss of the robust cleaning before the tests (``"danish"``,
    ``"huber"``, ``"cauchy"``; ``"none"``: least squares throughout); other keywords are :class:`selfcal.adjust.AdjustOptions` fields (``grid``,
    ``gnss_drift``, ``sensor_model``...). Pushbroom blocks get seed 001's sensor model ``M6`` unless told.
    An argument that cannot be used (``snoop=-1``, an unknown keyword) is a :class:`~selfcal.errors.UsageError`
    naming it.
    """
    from ..io.block_folder import read_block
    from ..report import result_files
    t0 = time.perf_counter()
    if not isinstance(block, Block):
        block = read_block(block)
    if offers_sensor_models(block):
        options.setdefault("sensor_model", "M6")
    if isinstance(snoop, bool) or not isinstance(snoop, (int, float)) or not math.isfinite(snoop) or snoop < 0:
        raise UsageError(f"bundle_adjust(snoop={snoop!r}): Baarda's critical value must be a finite number, 0 or "
                         f"more (0: no data snooping)")
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, int) or max_iterations < 1:
        raise UsageError(f"bundle_adjust(max_iterations={max_iterations!r}): must be a whole number, 1 or more")
    solver = _argument("max_iterations", max_iterations, lambda: SolverOptions(max_iterations=max_iterations))
    adjust_options = _argument("ap", ap, lambda: AdjustOptions(ap=ap, solver=solver))
    unknown = sorted(set(options) - {f.name for f in fields(AdjustOptions)})
    if unknown:
        raise UsageError(f"bundle_adjust({unknown[0]}=...): not an argument (AdjustOptions fields: "
                         f"{', '.join(f.name for f in fields(AdjustOptions))})")
    for name, value in options.items():
        adjust_options = _argument(name, value, lambda: replace(adjust_options, **{name: value}))
    screening = ScreeningOptions() if screen else None
    snooping = _argument("snoop", snoop, lambda: SnoopingOptions(critical=snoop))
    robust_options = None if robust == "none" else _argument("robust", robust, lambda: RobustOptions(loss=robust))
    request = AdjustRequest(adjust_options, snooping, screening,
                            VarianceOptions() if variance_components else None, robust_options)
    LOG.info(f"{block.name}: {len(block.images)} images, {len(block.points)} points, {len(block.observations)} "
             f"image observations; AP model {ap}")
    adjusted = adjust_block(block, request, progress=logging_progress(block.image_sigma_px),
                            report=logging_rounds(), say=LOG.info)
    extra = {"seconds": time.perf_counter() - t0, "grid": list(adjust_options.grid)} | adjusted.summary_extra
    files = result_files(adjusted.block, adjusted.tested, extra, screening, adjusted.checks, adjusted.track)
    return Outcome(adjusted, files)
