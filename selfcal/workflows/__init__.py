"""The actions: one function per verb, from a block to what the results folder holds.

A workflow composes the layers below it (adjust, stats, sensors) into what a user asks for: the
tested adjustment (adjust, snoop, screen, variance components: :mod:`.tested`), the choice of an
AP model (:mod:`.model_choice`), seed 001's focal-length step and GCP layouts (:mod:`.seed001`),
check points by 3-D intersection or mono restitution (:mod:`selfcal.stats.checks`). It reads no files and
prints nothing; the CLI wires it to files, :mod:`selfcal.batch` runs matrices of it.
"""
from typing import TYPE_CHECKING

from ..lazy import attach

#: module -> the public names it defines (imported on first use: ``selfcal.workflows.progress`` stays light)
_MODULES = {
    ".model_choice": ("CandidateScore", "ModelChoice", "choose_ap_model", "parse_candidate"),
    ".tested": ("TestedAdjustment", "adjust_with_tests"),
}
__getattr__, __dir__ = attach(__name__, _MODULES)

if TYPE_CHECKING:
    from .model_choice import CandidateScore, ModelChoice, choose_ap_model, parse_candidate
    from .tested import TestedAdjustment, adjust_with_tests

__all__ = ["TestedAdjustment", "adjust_with_tests", "CandidateScore", "ModelChoice", "choose_ap_model",
           "parse_candidate"]
