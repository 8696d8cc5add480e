"""What a surveyor reads: metrics and tables of an adjustment (:mod:`.metrics`), the comparison
table of a model study (:mod:`.compare`), and the HTML report with its figures (:mod:`.render`)."""
from .metrics import model_choice_table, result_files, summary
from .render import best_cells, render_comparison_report, render_report

__all__ = ["model_choice_table", "result_files", "summary", "render_report", "render_comparison_report",
           "best_cells"]
