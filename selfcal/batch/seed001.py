"""The pushbroom study of seed 001 as a matrix of workflow calls: models M1-M7 x {3, 4, 5} GCPs x
{mono F, N, B; stereo F+N, F+N+B}, after the focal-length step (:mod:`selfcal.workflows.seed001`)."""
from __future__ import annotations

from dataclasses import replace

from ..adjust import AdjustOptions
from ..block import Block
from ..sensors.pushbroom import SENSOR_MODELS
from ..stats.snooping import SnoopingOptions
from ..workflows.seed001 import PushbroomCase, calibrate_focal, choose_gcps, image_sets, run_case, with_focal

__all__ = ["run_study"]


def run_study(block: Block, height, models=tuple(SENSOR_MODELS), gcp_counts=(3, 4, 5), sets=None,
              prior_sigma: dict | None = None, calibrate: bool = True, progress=None,
              snooping: SnoopingOptions | None = None, options: AdjustOptions | None = None
              ) -> tuple[list[PushbroomCase], dict, dict]:
    """The whole matrix. Returns the cases and the calibrated focal lengths with their sigma (empty when
    ``calibrate`` is False: the block's focal lengths are used). ``prior_sigma`` overrides M6's weights."""
    options = options or AdjustOptions()
    focal, focal_sigma = calibrate_focal(block, options=options) if calibrate else ({}, {})
    block = with_focal(block, focal) if calibrate else block
    sets = image_sets(block) if sets is None else sets
    cases = []
    for label, image_set in sets.items():
        for name in models:
            weights = replace(options, sensor=replace(options.sensor, parameter_sigma=prior_sigma if name == "M6" else None))
            for n in gcp_counts:
                case = run_case(block, name, choose_gcps(block, n), image_set, height, label, weights, snooping)
                cases.append(case)
                if progress is not None:
                    progress(case)
    return cases, focal, focal_sigma
