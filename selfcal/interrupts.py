"""Ctrl-C, SIGTERM and SIGHUP as one exception, and the few steps no signal may cut in two.

The command line calls :func:`exit_early` in the first lines of ``selfcal.cli.main`` (before NumPy, SciPy or
any module of ours that needs them is imported): a signal while the modules load and the arguments are parsed
ends the process at once with one line (nothing can have been written). Once parsed, :func:`install`: from
then on SIGINT, SIGTERM and SIGHUP raise :class:`Interrupted` (a :class:`KeyboardInterrupt`, so every
``finally`` and every atomic writer cleans up as for a Ctrl-C) in the main thread; the clean-ups of temporary names run under :func:`deferred`, so a second signal never cuts them short.
A signal is also remembered: if some library swallowed its exception (a bare ``except:``), :func:`check` raises
it again before an output is put in place, and ``main`` exits as interrupted all the same.
:func:`release` (when the command is done) makes later signals do nothing, so a signal in the last
microseconds never turns a finished run into a traceback.

:func:`deferred` holds signals over a few statements that must run together (create a temporary name and
take charge of it; rename a finished output into place): a signal that arrives inside is raised when the
block ends. Without :func:`install` (selfcal used as a library) it holds a Ctrl-C as before and leaves the
program's own handlers of the other signals alone.

This module imports nothing of selfcal's and nothing heavy.
"""
from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading

__all__ = ["Interrupted", "install", "exit_early", "release", "restore", "deferred", "check", "noted", "exit_code", "signal_name", "SIGNALS",
           "record_written", "written"]

#: the signals treated as Ctrl-C (SIGHUP does not exist on Windows)
SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


class Interrupted(KeyboardInterrupt):
    """A signal asked the process to stop; ``signum`` says which."""

    def __init__(self, signum: int = signal.SIGINT):
        super().__init__(signum)
        self.signum = int(signum)


class _State:
    installed = False       # our handler is the one of SIGNALS
    released = False        # the command is done: signals do nothing
    signum: int | None = None   # the first signal that came (kept even if some library swallowed its exception)
    depth = 0               # nesting of deferred()
    pending: list[int] = []
    early: dict | None = None   # the handlers exit_early() found, until install()
    unraisablehook = staticmethod(sys.__unraisablehook__)
    exit_line: str | None = None


_state = _State()


def _handler(signum, frame) -> None:
    if _state.released:
        return
    if _state.signum is None:
        _state.signum = int(signum)
    if _state.depth:
        _state.pending.append(signum)
        return
    raise Interrupted(signum)


def install() -> dict:
    """Make SIGINT, SIGTERM and SIGHUP raise :class:`Interrupted` in the main thread (the command line); returns
    the handlers they had before this or :func:`exit_early` (for :func:`restore`)."""
    handlers = {number: signal.signal(number, _handler) for number in SIGNALS}
    previous = _state.early if _state.early is not None else handlers
    _state.early, _state.exit_line = None, None
    _state.installed, _state.released, _state.signum = True, False, None
    _state.depth, _state.pending = 0, []
    _WRITTEN.clear()
    if sys.unraisablehook is not _unraisable:
        _state.unraisablehook = sys.unraisablehook
        sys.unraisablehook = _unraisable
    return previous


def _unraisable(unraisable) -> None:
    """An Interrupted raised where Python cannot propagate it (the handler ran inside a weakref callback or a
    ``__del__``: "Exception ignored in ..." and a traceback) is sent again to this process, so that it is raised
    at a statement of the program instead. Once an interrupted run is over (released), nothing is printed: objects
    the signal left half-built (a module cut short while it was imported: pyparsing's ``Forward`` under
    matplotlib) fail in ``__del__`` as the interpreter finalises them, and their traceback would follow the one
    line that says what happened. Anything else goes to the previous hook."""
    if _state.released and _state.signum is not None:
        return
    if isinstance(unraisable.exc_value, Interrupted) and not _state.released:
        # from another thread, a moment later: a signal sent here would run the handler inside this hook
        # (the timer can fire before start() returns, under load: the handler then raises here, inside the hook,
        # where the interrupt would be lost again; it is caught and the signal sent once more, later)
        signum, delay = unraisable.exc_value.signum, 0.002
        for _ in range(6):
            try:
                again = threading.Timer(delay, os.kill, (os.getpid(), signum))
                again.daemon = True
                again.start()
                return
            except Interrupted:
                delay *= 10
        return
    _state.unraisablehook(unraisable)


def exit_early(prefix: str) -> None:
    """Until :func:`install`, end the process at once on SIGINT, SIGTERM or SIGHUP with ``PREFIX: interrupted
    (SIGTERM); nothing was written`` and 128 + the number (the command line while its modules are imported and its
    arguments parsed: nothing can have been written yet, and an exception raised inside the import of a compiled
    extension comes out as some other error, or is swallowed by a library's bare ``except:``)."""
    _state.exit_line = prefix
    if _state.early is None:
        _state.early = {number: signal.signal(number, _exit_handler) for number in SIGNALS}


def _exit_handler(signum, frame) -> None:
    line = f"{_state.exit_line}: interrupted ({signal_name(signum)}); nothing was written\n"
    try:
        os.write(2, line.encode("utf-8", "backslashreplace"))
    finally:
        os._exit(exit_code(signum))


def restore(previous: dict) -> None:
    """Give the signals the handlers :func:`install` found (``main`` called from a program, not as a process)."""
    for number, handler in previous.items():
        signal.signal(number, handler if handler is not None else signal.SIG_DFL)
    _state.installed, _state.signum, _state.pending = False, None, []
    if sys.unraisablehook is _unraisable:
        sys.unraisablehook = _state.unraisablehook


_WRITTEN: list[str] = []


def record_written(path: str) -> None:
    """Note that an output has been put in place complete (:mod:`selfcal.io.atomic`): the message of an
    interrupt that comes later names it instead of saying that nothing was written."""
    _WRITTEN.append(path)


def written() -> list[str]:
    """The outputs put in place since :func:`install` (or since this module was loaded)."""
    return list(_WRITTEN)


def release(ignore: bool = False) -> None:
    """From now on signals do nothing more (the command has finished and is about to exit). ``ignore``: set them
    to SIG_IGN (the process itself: the interpreter's finalisation puts a Python handler back to SIG_DFL, and a
    signal then would end a finished run with -2 or -15)."""
    _state.released = True
    if ignore:
        for number in SIGNALS:
            signal.signal(number, signal.SIG_IGN)


def check() -> None:
    """Raise :class:`Interrupted` if a signal came since :func:`install`, even one whose exception some code
    swallowed (a bare ``except:`` in a library being imported): called before an output is put in place."""
    if _state.signum is not None and not _state.released:
        raise Interrupted(_state.signum)


def noted() -> int | None:
    """The first signal since :func:`install`, or None."""
    return _state.signum


def exit_code(signum: int) -> int:
    """The shell's status of a process ended by ``signum``: 128 + its number (130 Ctrl-C, 143 SIGTERM, 129 SIGHUP)."""
    return 128 + int(signum)


def signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


@contextlib.contextmanager
def deferred():
    """Hold SIGINT, SIGTERM and SIGHUP until the block is done, then raise the first one that came."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if _state.installed and signal.getsignal(signal.SIGINT) is _handler:
        _state.depth += 1
        try:
            yield
        finally:
            _state.depth -= 1
            if not _state.depth and _state.pending and not _state.released:
                signum = _state.pending[0]
                _state.pending = []
                raise Interrupted(signum)
        return
    caught: list[int] = []
    try:
        previous = signal.signal(signal.SIGINT, lambda number, frame: caught.append(number))
    except ValueError:                  # not the main interpreter
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if caught:
            raise KeyboardInterrupt
