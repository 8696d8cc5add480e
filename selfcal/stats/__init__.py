"""Statistics of the adjustment: correlation analysis, (and data snooping, AP screening)."""
from .correlation import max_abs_correlation_by_group

__all__ = ["max_abs_correlation_by_group"]
