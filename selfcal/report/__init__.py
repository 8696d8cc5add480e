"""What a surveyor reads: metrics and tables of an adjustment (:mod:`.metrics`), the comparison
table of a model study (:mod:`.compare`), and the HTML report with its figures (:mod:`.render`).

The names are imported on first use (:mod:`selfcal.lazy`): ``selfcal report`` renders from the results files
with :mod:`.render` alone, without :mod:`.metrics` and the statistics, sensors and Numba kernels it imports."""
from typing import TYPE_CHECKING

from ..lazy import attach

#: module -> the public names it defines
_MODULES = {
    ".metrics": ("model_choice_table", "result_files", "summary"),
    ".render": ("best_cells", "render_comparison_report", "render_report"),
}
__getattr__, __dir__ = attach(__name__, _MODULES)

if TYPE_CHECKING:
    from .metrics import model_choice_table, result_files, summary
    from .render import best_cells, render_comparison_report, render_report

__all__ = ["model_choice_table", "result_files", "summary", "render_report", "render_comparison_report",
           "best_cells"]
