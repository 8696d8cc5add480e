"""Metrics, tables and (later) figures of an adjustment: what a surveyor reads."""
from .metrics import result_files, summary

__all__ = ["result_files", "summary"]
