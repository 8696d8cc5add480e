"""Exceptions of selfcal.

Three kinds of failure reach the user, each with its own exit code (DESIGN.md §5):

* :class:`BlockError` — bad input. It names the file, the line and the column
  where the defect is, and why it is one. Exit code 2.
* :class:`UsageError` — a command-line value that cannot be used (an unknown
  AP model in a list). Exit code 2, as for argparse's own usage errors.
* :class:`AdjustmentError` — the input is well formed but the adjustment cannot
  produce an estimate (singular normal equations, divergence). Exit code 1.
* :class:`OutputError` — an output could not be written (a full disk, a folder removed under the run). It
  names the output's final path (never a temporary one) and the system's reason. Exit code 1: the input
  was fine, and the previous output is still in place.
"""
from __future__ import annotations

__all__ = ["SelfcalError", "BlockError", "UsageError", "AdjustmentError", "OutputError"]


class SelfcalError(Exception):
    """Root of every error selfcal raises on purpose."""

    exit_code = 1


class BlockError(SelfcalError, ValueError):
    """A defect in the input, located in its file.

    Parameters
    ----------
    path : str
        File the defect is in.
    reason : str
        What is wrong, in words a user can act on.
    line : int, optional
        1-based line number; None when the defect has no single line (a count).
    column : str, optional
        Column (CSV header name) or key (TOML) the defect is in.
    """

    exit_code = 2

    def __init__(self, path: str, reason: str, line: int | None = None, column: str | None = None):
        self.path = str(path)
        self.reason = reason
        self.line = line
        self.column = column
        super().__init__(self._format())

    def _format(self) -> str:
        where = self.path
        if self.line is not None:
            where += f", line {self.line}"
        if self.column is not None:
            where += f", column '{_one_line(self.column)}'"
        return f"{where}: {_one_line(self.reason, 2000)}"


def _one_line(text: str, limit: int = 80) -> str:
    """``text`` on one line (line breaks shown as \\n, as a quoted CSV field can hold them), cut to ``limit``
    characters: a message is one line whatever the file holds."""
    text = str(text).replace("\r", "\\r").replace("\n", "\\n")
    return text if len(text) <= limit else text[:limit - 3] + "..."


class UsageError(SelfcalError, ValueError):
    """A command-line value that cannot be used; the message names it."""

    exit_code = 2


class AdjustmentError(SelfcalError, RuntimeError):
    """The adjustment could not produce an estimate; the message says why."""

    exit_code = 1


class OutputError(SelfcalError):
    """An output could not be written; ``path`` is where it was to go, ``reason`` the system's words."""

    exit_code = 1

    def __init__(self, path: str, reason: str):
        self.path = str(path)
        self.reason = reason
        super().__init__(f"cannot write {self.path}: {reason}")
