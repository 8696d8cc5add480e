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
    inputs: tuple = ()
    if not isinstance(block, Block):
        inputs = (os.fspath(block),)
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
    return Outcome(adjusted, files, inputs)
