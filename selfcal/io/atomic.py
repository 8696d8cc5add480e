"""Atomic output: a file or a folder appears complete, or not at all.

``atomic_write`` writes to a temporary name beside the target and renames it
over the target when the block ends without an exception. ``atomic_folder``
does the same for a whole folder: everything is written into a temporary
sibling folder that replaces the target in two renames at the end, so a run
that fails half-way leaves the previous results (or nothing) in place.

Every folder ``atomic_folder`` writes holds :data:`MARKER`, which tells a later
run that selfcal wrote it and may replace it (:mod:`selfcal.io.output`). A
Ctrl-C that arrives while a folder is swapped in is held until the renames are
done, so no temporary name is ever left behind.
"""
from __future__ import annotations

import contextlib
import os
import shutil
import signal
import tempfile
import threading

__all__ = ["atomic_write", "atomic_folder", "MARKER", "TEMPORARY_PREFIXES"]

#: the file in every folder selfcal writes: a folder holding it may be replaced by another run's --out
MARKER = ".selfcal-output"
#: how the temporary names of this module begin (a test looks for strays with these)
TEMPORARY_PREFIXES = (".tmp-", ".selfcal-partial-", ".selfcal-old-")
_MARKER_TEXT = ("This folder was written by selfcal. A later selfcal command whose --out names it replaces it\n"
                "as a whole; a folder without this file is replaced only with --force.\n")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def _holding_ctrl_c():
    """Hold a Ctrl-C (SIGINT) until the block is done, then raise it (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
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


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "w", encoding: str | None = "utf-8"):
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise IsADirectoryError(f"{path} is a folder, not a file")
    os.makedirs(directory, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix="-" + os.path.basename(path), dir=directory)
    try:
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the file the usual permissions
        with os.fdopen(fd, mode, encoding=None if "b" in mode else encoding,
                       newline=None if "b" in mode else "") as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        with _holding_ctrl_c():
            os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike):
    """Yield a temporary folder that replaces ``path`` when the block succeeds.

    A file at ``path`` is never replaced by a folder (FileExistsError); a folder at ``path`` is replaced as a
    whole (the caller decides whether it may be: :func:`selfcal.io.output.output_folder`).
    """
    path = os.path.abspath(os.fspath(path))
    parent = os.path.dirname(path)
    if os.path.lexists(path) and not os.path.isdir(path):
        raise FileExistsError(f"{path} is a file; selfcal does not turn a file into a folder")
    os.makedirs(parent, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix=".selfcal-partial-", dir=parent)
    try:
        os.chmod(tmp, 0o777 & ~_umask())
        yield tmp
        with open(os.path.join(tmp, MARKER), "w", encoding="utf-8") as handle:
            handle.write(_MARKER_TEXT)
        with _holding_ctrl_c():
            old = None
            if os.path.lexists(path):
                old = tempfile.mkdtemp(prefix=".selfcal-old-", dir=parent)
                os.rmdir(old)
                os.replace(path, old)
            try:
                os.replace(tmp, path)
            except BaseException:
                if old is not None:
                    os.replace(old, path)
                raise
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
