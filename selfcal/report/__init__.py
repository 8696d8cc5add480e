"""Metrics, tables and (later) figures of an adjustment: what a surveyor reads."""
from .metrics import model_choice_table, result_files, summary

__all__ = ["model_choice_table", "result_files", "summary"]
