"""The ``selfcal`` command: one sub-command per verb, each in its own module.

Exit codes (DESIGN.md §5): 0 success, 1 the adjustment failed (singular,
diverged or not converged; the reason is printed), 2 bad input (file, line,
column and reason are printed).
"""
from __future__ import annotations

import argparse
import sys

from .. import __version__
from ..allocator import keep_freed_memory
from ..errors import SelfcalError, UsageError
from . import adjust, compare, demo, export, import_, report, simulate, undistort

#: verb -> module with ``add_arguments(parser)`` and ``run(args) -> int``
COMMANDS = {
    "adjust": adjust,
    "simulate": simulate,
    "compare": compare,
    "report": report,
    "import": import_,
    "export": export,
    "undistort": undistort,
    "demo": demo,
}


class _Parser(argparse.ArgumentParser):
    """argparse whose usage errors are UsageError (one line, exit 2, through main's handler)."""

    def error(self, message: str):
        raise _ArgumentError(self.prog, message)


class _ArgumentError(UsageError):
    def __init__(self, prog: str, message: str):
        self.prog = prog
        super().__init__(f"{message} (see {prog} --help)")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="selfcal",
        description="Self-calibrating bundle adjustment of frame and pushbroom sensors.")
    parser.add_argument("--version", action="version", version=f"selfcal {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, module in COMMANDS.items():
        doc = (module.__doc__ or "").strip().splitlines()[0]
        p = sub.add_parser(name, help=doc, description=doc)
        module.add_arguments(p)
    return parser


def _interrupted(exc: BaseException) -> bool:
    """Whether a KeyboardInterrupt is among the causes of ``exc``."""
    seen = set()
    cause: BaseException | None = exc
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, KeyboardInterrupt):
            return True
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    return False


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except _ArgumentError as exc:
        print(f"{exc.prog}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    keep_freed_memory()
    try:
        return int(COMMANDS[args.command].run(args) or 0)
    except SelfcalError as exc:
        print(f"selfcal {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except (KeyboardInterrupt, SystemError) as exc:
        # Ctrl-C while a compiled kernel called back into Python (Numba unpickling a constant): Numba reports
        # the KeyboardInterrupt as the cause of a SystemError
        if not _interrupted(exc):
            raise
        print(f"selfcal {args.command}: interrupted; nothing was written", file=sys.stderr)
        return 130
    except OSError as exc:             # a disk that fills up, a folder removed under the run: no traceback
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"selfcal {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
