"""Statistics of the adjustment: redundancy numbers and w-tests, data snooping,
AP screening, correlation analysis by parameter group and variance components."""
from .accuracy import ce90, le90
from .correlation import max_abs_correlation_by_group
from .model_choice import CandidateScore, ModelChoice, choose_ap_model, parse_candidate
from .reliability import ObservationTests, observation_tests
from .screening import ScreeningOptions
from .snooping import SnoopingOptions
from .variance import VarianceComponent, VarianceOptions, estimate_variance_components
from .workflow import TestedAdjustment, adjust_with_tests

__all__ = ["ce90", "le90", "max_abs_correlation_by_group", "observation_tests", "ObservationTests", "ScreeningOptions",
           "SnoopingOptions", "TestedAdjustment", "VarianceComponent", "VarianceOptions", "adjust_with_tests",
           "estimate_variance_components", "CandidateScore", "ModelChoice", "choose_ap_model", "parse_candidate"]
