"""``selfcal.bundle_adjust``: the tested adjustment of ``selfcal adjust`` for a program that calls selfcal.

The CLI's defaults, as keyword arguments; progress goes to ``logging.getLogger("selfcal")``.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, replace

from ..adjust import AdjustOptions, RobustOptions
from ..adjust import SolverOptions
from ..block import Block
from ..stats.screening import ScreeningOptions
from ..stats.snooping import SnoopingOptions
from ..stats.variance import VarianceOptions
from .adjust import Adjusted, AdjustRequest, adjust_block, offers_sensor_models
from .progress import LOG, logging_progress, logging_rounds

__all__ = ["bundle_adjust", "Outcome"]


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


def bundle_adjust(block: Block | str | os.PathLike, ap: str = "none", *, snoop: float = 3.0, screen: bool = False,
                  variance_components: bool = False, max_iterations: int = 50, robust: str = "danish",
                  **options) -> Outcome:
    """The tested adjustment of ``block`` (a :class:`~selfcal.block.Block` or a block folder).

    ``ap``: the AP model (``"brown"``, ``"wavelet:db4"``...); ``snoop``: Baarda's critical value (0: none);
    ``screen``: drop insignificant and highly correlated APs; ``variance_components``: estimate each
    observation group's sigma; ``robust``: the loss of the robust cleaning before the tests (``"danish"``,
    ``"huber"``, ``"cauchy"``; ``"none"``: least squares throughout); other keywords are :class:`selfcal.adjust.AdjustOptions` fields (``grid``,
    ``gnss_drift``, ``sensor_model``...). Pushbroom blocks get seed 001's sensor model ``M6`` unless told.
    """
    from ..io.block_folder import read_block
    from ..report import result_files
    t0 = time.perf_counter()
    if not isinstance(block, Block):
        block = read_block(block)
    if offers_sensor_models(block):
        options.setdefault("sensor_model", "M6")
    adjust_options = replace(AdjustOptions(ap=ap, solver=SolverOptions(max_iterations=max_iterations)), **options)
    screening = ScreeningOptions() if screen else None
    request = AdjustRequest(adjust_options, SnoopingOptions(critical=snoop), screening,
                            VarianceOptions() if variance_components else None,
                            None if robust == "none" else RobustOptions(loss=robust))
    LOG.info(f"{block.name}: {len(block.images)} images, {len(block.points)} points, {len(block.observations)} "
             f"image observations; AP model {ap}")
    adjusted = adjust_block(block, request, progress=logging_progress(block.image_sigma_px),
                            report=logging_rounds(), say=LOG.info)
    extra = {"seconds": time.perf_counter() - t0, "grid": list(adjust_options.grid)} | adjusted.summary_extra
    files = result_files(adjusted.block, adjusted.tested, extra, screening, adjusted.checks, adjusted.track)
    return Outcome(adjusted, files)
