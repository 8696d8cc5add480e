"""Statistics of an adjustment (written against AdjustmentResult only): redundancy numbers and w-tests,
data snooping, screening, correlation analysis by parameter group and variance components."""
from .accuracy import ce90, le90
from .correlation import max_abs_correlation_by_group
from .reliability import ObservationTests, observation_tests
from .screening import ScreeningOptions
from .snooping import SnoopingOptions
from .variance import VarianceComponent, VarianceOptions, estimate_variance_components

__all__ = ["ce90", "le90", "max_abs_correlation_by_group", "observation_tests", "ObservationTests", "ScreeningOptions",
           "SnoopingOptions", "VarianceComponent", "VarianceOptions", "estimate_variance_components"]
