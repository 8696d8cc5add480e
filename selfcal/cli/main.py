"""The ``selfcal`` command: one sub-command per verb, each in its own module.

Exit codes (DESIGN.md §5): 0 success, 1 the adjustment failed (singular,
diverged or not converged; the reason is printed) or an output could not be
written (a full disk), 2 bad input (file, line, column and reason are printed),
128 + the signal's number when interrupted: 130 Ctrl-C (SIGINT), 143 SIGTERM,
129 SIGHUP.

The signal handlers are installed before anything heavy is imported (the verbs'
modules pull in NumPy, SciPy, matplotlib, OpenCV: seconds), so a signal at any
moment of a run is one line and the shell's status, never a traceback.
"""
from __future__ import annotations

import os
import sys

from .. import interrupts


def _verb(argv: list[str]) -> str:
    """``selfcal VERB`` of a command line (for messages before it is parsed)."""
    return f"selfcal {next((a for a in argv if not a.startswith('-')), '')}".rstrip()


def _is_command() -> bool:
    """True when this process is the ``selfcal`` command, not a process it started: a Dask worker of ``compare``
    or ``demo`` is spawned with the command's ``sys.argv`` and imports its script again as ``__mp_main__``; it must
    keep its own signal handling (its nanny stops it with SIGTERM), not exit with the command's line."""
    if "__mp_main__" in sys.modules:   # the spawned child runs the script as __mp_main__ (and keeps the name)
        return False
    mp = sys.modules.get("multiprocessing")
    if mp is not None and mp.parent_process() is not None:
        return False
    return __name__ == "__main__" or os.path.basename(sys.argv[0] if sys.argv else "") == "selfcal"


if _is_command():
    interrupts.exit_early(_verb(sys.argv[1:]))   # the command itself: a signal from here on is one line

import argparse  # noqa: E402
import importlib  # noqa: E402
from typing import Sequence  # noqa: E402

from ..errors import SelfcalError, UsageError  # noqa: E402
from . import outcome  # noqa: E402

#: verb -> (module in selfcal.cli with ``add_arguments(parser)`` and ``run(args) -> int``, the one-line help: the
#: first line of the module's docstring). Only the verb a command line names is imported, after the signal handlers
#: are in place: ``selfcal --help`` and ``--version`` load none of them, ``selfcal VERB --help`` only its own. A verb
#: with formats (import, export) has ``FORMATS`` and ``add_arguments(parser, chosen)``: only the chosen format's
#: module is imported.
COMMANDS = {
    "adjust": ("adjust", "Adjust a block folder and write a results folder, whatever the block's sensors."),
    "simulate": ("simulate", "Simulate a block with known truth (the UAV block of seed 000, the PRISM triplet of "
                             "seed 001)."),
    "compare": ("compare", "Adjust blocks with several AP models and tabulate the comparison (seed 000's tables)."),
    "plan": ("plan", "Predict the peak memory and the seconds per iteration of adjusting a block, before any "
                     "adjustment."),
    "report": ("report", "Render the report of a results folder again (report.html, figures/), without adjusting."),
    "import": ("import_", "Import another program's model, control, camera GNSS or calibration as a block folder."),
    "export": ("export", "Export a results folder to other programs: camera models (OpenCV, COLMAP, Metashape, "
                         "OpenSfM, Kalibr), maps, RPCs."),
    "undistort": ("undistort", "Resample images to the ideal (distortion-free) camera of a results folder, with "
                               "OpenCV's remap."),
    "demo": ("demo", "Simulate the seed-000 block and run the paper's 24 cases (4 control scenarios x 6 AP models)."),
}


def _module(verb: str):
    return importlib.import_module(f"selfcal.cli.{COMMANDS[verb][0]}")


class _Parser(argparse.ArgumentParser):
    """argparse whose usage errors are UsageError (one line, exit 2, through main's handler)."""

    def error(self, message: str):
        raise _ArgumentError(self.prog, message)


class _ArgumentError(UsageError):
    def __init__(self, prog: str, message: str):
        self.prog = prog
        super().__init__(f"{message} (see {prog} --help)")


def _chosen(words: list[str], names) -> tuple[str | None, list[str]]:
    """The first of ``words`` that is one of ``names`` (a verb, a format) and the words after it: options come
    before it only as ``--help`` / ``--version``, so the first word that is not an option is it or a mistake."""
    for k, word in enumerate(words):
        if not word.startswith("-"):
            return (word if word in names else None), words[k + 1:]
    return None, []


def build_parser(words: Sequence[str] = ()) -> argparse.ArgumentParser:
    """The parser of ``selfcal WORDS``: every verb listed, the arguments of the verb the words name only."""
    from .. import __version__
    parser = _Parser(
        prog="selfcal",
        description="Self-calibrating bundle adjustment of frame and pushbroom sensors.")
    parser.add_argument("--version", action="version", version=f"selfcal {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    verb, rest = _chosen(list(words), COMMANDS)
    for name, (_, doc) in COMMANDS.items():
        p = sub.add_parser(name, help=doc, description=doc)
        if name != verb:
            continue
        module = _module(name)
        formats = getattr(module, "FORMATS", None)
        if formats is None:
            module.add_arguments(p)
            outcome.add_options(p)
        else:                          # the output options go with the format's own (``import colmap --json``)
            module.add_arguments(p, _chosen(rest, formats)[0], outcome.add_options)
    return parser


def _signal_of(exc: BaseException) -> int | None:
    """The signal behind ``exc`` if a KeyboardInterrupt is among its causes (Ctrl-C while a compiled kernel
    called back into Python: Numba reports it as the cause of a SystemError; an import cut short), else None."""
    seen = set()
    cause: BaseException | None = exc
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, KeyboardInterrupt):
            return getattr(cause, "signum", interrupts.SIGNALS[0])
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    return None


def _run(argv: list[str], command: bool) -> int:
    import logging
    import time
    from ..allocator import keep_freed_memory
    t0 = time.perf_counter()
    try:
        args = build_parser(argv).parse_args(argv)
    except _ArgumentError as exc:
        print(f"{exc.prog}: error: {exc}", file=sys.stderr)
        if "--json" in argv:
            outcome.failed(argparse.Namespace(json=True), exc.prog.removeprefix("selfcal").strip(),
                           exc.exit_code, str(exc))
        return exc.exit_code
    if command:                        # the modules are loaded: from here a signal unwinds through the clean-ups
        interrupts.install()
    keep_freed_memory()
    outcome.configure(args)
    name = outcome.command_of(args)
    log = logging.getLogger("selfcal.cli")
    log.info(f"{name}: arguments parsed and the verb's modules loaded in {time.perf_counter() - t0:.2f} s")
    t_run = time.perf_counter()
    try:
        code = int(_module(args.command).run(args) or 0)
        log.info(f"{name}: done in {time.perf_counter() - t_run:.2f} s (exit {code})")
        return code
    except SelfcalError as exc:
        print(f"selfcal {args.command}: error: {exc}", file=sys.stderr)
        outcome.failed(args, name, exc.exit_code, str(exc), getattr(exc, "figures", None))
        return exc.exit_code
    except OSError as exc:             # a folder removed under the run, a device error: no traceback
        if _signal_of(exc) is not None:
            raise
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"selfcal {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        outcome.failed(args, name, 1, f"{where}{exc.strerror or exc}")
        return 1


def main(argv: list[str] | None = None) -> int:
    """Run ``selfcal ARGV`` (``sys.argv[1:]`` when None: the console script, which exits with the result)."""
    command = argv is None
    words = sys.argv[1:] if command else list(argv or [])
    if command:
        interrupts.exit_early(_verb(words))        # until the arguments are parsed (already so when run as the command)
        previous: dict = {}
    else:                              # called from a program (the tests): raise at once, and give the handlers back
        previous = interrupts.install()
    try:
        try:
            code = _run(words, command)
            interrupts.check()         # a signal whose exception some library swallowed
        finally:
            interrupts.release(ignore=command)    # a signal from here on changes nothing: the run is over
    except BaseException as exc:
        # an exception after a signal is the signal's doing, even one that lost it on the way (a C extension cut
        # short while it was imported raises ImportError without the KeyboardInterrupt as its cause)
        signum = _signal_of(exc) or interrupts.noted()
        if signum is None:
            raise
        done = interrupts.written()
        what = (f"after writing {', '.join(done)} completely" if done else "nothing was written")
        print(f"{_verb(words)}: interrupted ({interrupts.signal_name(signum)}); {what}", file=sys.stderr)
        code = interrupts.exit_code(signum)
    finally:
        if not command:
            interrupts.restore(previous)
    return code


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
