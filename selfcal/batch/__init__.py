"""Experiment matrices: many adjustments (scenario x AP model) and their comparison table.

Runs serially for now; the matrix is independent cell by cell, which is what
the Dask back end (issue 5) will exploit.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

from ..adjust import AdjustOptions
from ..ap import AP_FAMILIES, parse_ap_spec
from ..errors import AdjustmentError
from ..report import result_files
from ..stats import ScreeningOptions, SnoopingOptions, adjust_with_tests

__all__ = ["Cell", "run_cell", "available_models", "PAPER_MODELS"]

#: the models of the seed-000 comparison, in the paper's order; "gruen" stands
#: for BINGO's polynomial AP set (BINGO is commercial; Grün's 44 is its classic core)
PAPER_MODELS = ("none", "gruen", "wavelet:db4", "wavelet:bl4", "wavelet:sym4", "wavelet:meyer")


def available_models(models) -> list[str]:
    """The models whose family is registered (others are skipped)."""
    return [m for m in models if parse_ap_spec(m)[0] in AP_FAMILIES]


@dataclass
class Cell:
    scenario: str
    model: str
    files: dict | None          # result files as data (see selfcal.report.result_files)
    error: str | None
    seconds: float


def run_cell(scenario: str, block, model: str, grid=(9, 6), snooping: SnoopingOptions | None = SnoopingOptions(),
             screening: ScreeningOptions | None = ScreeningOptions()) -> Cell:
    """Adjust one block with one AP model (with snooping and screening); failures are recorded, not raised."""
    t0 = time.perf_counter()
    try:
        tested = adjust_with_tests(block, AdjustOptions(ap=model, grid=grid), snooping,
                                   screening if model != "none" else None)
    except AdjustmentError as exc:
        return Cell(scenario, model, None, str(exc), time.perf_counter() - t0)
    files = result_files(block, tested, {"scenario": scenario}, screening)
    return Cell(scenario, model, files, None, time.perf_counter() - t0)
