"""What a verb tells its caller, the same in every verb (issue 45; DESIGN.md §5).

* stdout holds the outcome only: one line (``sigma0 0.49 px, check points RMSD ...; results in res``), or with
  ``--json`` one JSON document (the line, the key figures and the paths written) that a script or a pipeline step
  reads without parsing files. Nothing else ever goes to stdout.
* stderr holds the rest: progress (:func:`progress`, off with ``--quiet``), warnings and errors (always), and with
  ``--verbose`` the lines of the ``selfcal`` logger (each stage's timing, the solver's details, the verb's time).
  No step of a verb stays silent for more than ~2 s: a long step made of short ones (a report's sections) says
  its steps through :func:`steps`; :func:`say` sends a line that may be a warning where it belongs.

A verb ends with ``return finish(args, line, figures, written)``; an error that ends a verb early (exit 1 or 2) is
reported by the command's handler (:mod:`.main`), which gives ``--json`` its document too.
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from collections.abc import Callable, Mapping, Sequence

__all__ = ["add_options", "configure", "progress", "steps", "say", "finish", "failed", "quiet", "verbose"]

_STATE = {"quiet": False, "verbose": False}
LOG = logging.getLogger("selfcal.cli")


def add_options(parser: argparse.ArgumentParser) -> None:
    """--json, --quiet, --verbose: every verb has them, with one meaning."""
    group = parser.add_argument_group("output (every verb)")
    group.add_argument("--json", action="store_true",
                       help="print the outcome as one JSON document on stdout (key figures, paths written, the "
                            "error if any) instead of the one-line outcome")
    loud = group.add_mutually_exclusive_group()
    loud.add_argument("--quiet", action="store_true",
                      help="no progress on stderr (warnings and errors are still printed)")
    loud.add_argument("--verbose", action="store_true",
                      help="more on stderr: the selfcal logger's lines (stages and their timing)")


def configure(args: argparse.Namespace) -> None:
    """Apply --quiet / --verbose for this run (the command's handler calls it once the arguments are parsed)."""
    _STATE["quiet"] = bool(getattr(args, "quiet", False))
    _STATE["verbose"] = bool(getattr(args, "verbose", False))
    logger = logging.getLogger("selfcal")
    # one run's handler only (main called again in one process, as the tests do: this run's stderr, this run's flag)
    for handler in [h for h in logger.handlers if hasattr(h, "_selfcal_level")]:
        logger.removeHandler(handler)
        logger.setLevel(getattr(handler, "_selfcal_level"))
    if _STATE["verbose"]:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("selfcal: %(message)s"))
        handler._selfcal_level = logger.level              # type: ignore[attr-defined]  # the level to go back to
        logger.addHandler(handler)
        logger.setLevel(logging.DEBUG)


def quiet() -> bool:
    """True under --quiet: a verb's own progress lines are left out."""
    return _STATE["quiet"]


def verbose() -> bool:
    """True under --verbose."""
    return _STATE["verbose"]


def progress(text: str) -> None:
    """A progress line on stderr (left out under --quiet), flushed at once: the user sees the step begin."""
    if not _STATE["quiet"]:
        print(text, file=sys.stderr, flush=True)


def say(text: str) -> None:
    """A line of a lower layer's ``say`` callback: a warning (``warning: ...``) always, anything else as
    :func:`progress`."""
    if text.startswith("warning:"):
        print(text, file=sys.stderr, flush=True)
    else:
        progress(text)


def steps(what: str, every_s: float = 1.0) -> Callable[[str], None]:
    """A callback for the steps of a long task (``what``: "report", the sections as steps): ``what: STEP ...``
    is printed as :func:`progress` when ``every_s`` have passed since the last line it printed (the first step
    at once), so the task is never silent longer than one step plus ``every_s``, and a fast task prints one line;
    under --verbose every step, with the time the one before took, also goes to the ``selfcal`` logger."""
    times = {"printed": -math.inf, "began": time.perf_counter()}
    last_step = [""]

    def step(text: str) -> None:
        now = time.perf_counter()
        if last_step[0]:
            LOG.debug(f"{what}: {last_step[0]}: {now - times['began']:.2f} s")
        times["began"], last_step[0] = now, text
        if now - times["printed"] >= every_s:
            times["printed"] = now
            progress(f"{what}: {text[:1].lower()}{text[1:]} ...")
    return step


def _plain(value):
    """``value`` as JSON can hold it: NumPy scalars as numbers, NaN and infinity as null, tuples as lists."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "item") and callable(value.item):        # a NumPy scalar
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _document(command: str, exit_code: int, line: str | None, figures: Mapping | None, written: Sequence[str],
              error: str | None) -> str:
    from .. import __version__
    return json.dumps(_plain({"selfcal": __version__, "command": command, "exit_code": exit_code,
                              "outcome": line, "error": error, "figures": dict(figures or {}),
                              "written": list(written)}), indent=1, allow_nan=False)


def command_of(args: argparse.Namespace) -> str:
    """``adjust``, ``import colmap``, ``export opencv``: the verb and its format."""
    return " ".join(v for v in (getattr(args, "command", None), getattr(args, "format", None)) if v)


def finish(args: argparse.Namespace, line: str, figures: Mapping | None = None, written: Sequence[str] = (),
           exit_code: int = 0, error: str | None = None) -> int:
    """Print the outcome (the line, or with --json the document) on stdout, and ``error`` as the verb's error line
    on stderr; return ``exit_code`` for the verb to return."""
    if error is not None:
        print(f"selfcal {args.command}: error: {error}", file=sys.stderr)
    if getattr(args, "json", False):
        print(_document(command_of(args), exit_code, line, figures, written, error), flush=True)
    else:
        print(line, flush=True)
    return exit_code


def failed(args: argparse.Namespace | None, command: str, exit_code: int, error: str,
           figures: Mapping | None = None) -> None:
    """With --json, the document of a verb ended by an error (bad input, a failed write) before its outcome, with
    the ``figures`` the error was found with, if any (`selfcal plan`'s refusal: the plan it refused)."""
    if args is not None and getattr(args, "json", False):
        print(_document(command_of(args) or command, exit_code, None, figures, (), error), flush=True)
