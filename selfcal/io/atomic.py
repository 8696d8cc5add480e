"""Atomic output: a file or a folder appears complete, or not at all.

``atomic_write`` writes to a temporary name beside the target and renames it
over the target when the block ends without an exception. ``atomic_folder``
does the same for a whole folder: everything is written into a temporary
sibling folder that replaces the target in two renames at the end, so a run
that fails half-way leaves the previous results (or nothing) in place.

Every folder ``atomic_folder`` writes holds :data:`MARKER`, which tells a later
run that selfcal wrote it and may replace it (:mod:`selfcal.io.output`). A
signal (Ctrl-C, SIGTERM, SIGHUP: :mod:`selfcal.interrupts`) that arrives while a
temporary name is created, renamed into place or removed is held until that is
done, so no temporary name is ever left behind; a write that fails (a full disk)
is an :class:`~selfcal.errors.OutputError` naming the final path, never the
temporary one. :func:`atomic_update` changes a copy of a folder and swaps it in.
"""
from __future__ import annotations

import contextlib
import errno
import os
import shutil
import tempfile

from ..errors import OutputError
from ..interrupts import check, deferred, record_written

__all__ = ["atomic_write", "atomic_folder", "atomic_update", "MARKER", "TEMPORARY_PREFIXES"]

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


#: errno values that mean "no room", whatever call met them
_FULL = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG}


def _inside(name, folder: str) -> bool:
    if not isinstance(name, str):
        return False
    name = os.path.abspath(name)
    return name == folder or name.startswith(folder + os.sep)


def _as_output_error(exc: BaseException, tmp: str, final: str) -> BaseException:
    """``exc`` with the temporary ``tmp`` (a file or folder being written in place of ``final``) named as ``final``:
    an OutputError for a write that failed there (a full disk: ENOSPC, a quota, a read-only remount), the exception
    itself for anything else (a read error in the caller's code, an interrupt)."""
    if isinstance(exc, OutputError):
        if _inside(exc.path, tmp):
            return OutputError(final + os.path.abspath(exc.path)[len(tmp):], exc.reason)
        return exc
    if isinstance(exc, OSError):
        if _inside(exc.filename, tmp) or (exc.filename is None and exc.errno in _FULL):
            where = final if exc.filename is None else final + os.path.abspath(exc.filename)[len(tmp):]
            return OutputError(where, exc.strerror or str(exc))
    return exc


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "w", encoding: str | None = "utf-8"):
    """Yield a handle on a temporary file beside ``path`` that replaces ``path`` when the block succeeds.

    A write that fails (a full disk) is an :class:`~selfcal.errors.OutputError` naming ``path``; the temporary
    file is removed whatever happens (an interrupt included)."""
    path = os.path.abspath(os.fspath(path))
    directory = os.path.dirname(path)
    if os.path.isdir(path):
        raise IsADirectoryError(f"{path} is a folder, not a file")
    tmp = None
    try:
        os.makedirs(directory, exist_ok=True)
        with deferred():                # no signal between creating the name and taking charge of it
            fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix="-" + os.path.basename(path), dir=directory)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the file the usual permissions
        with os.fdopen(fd, mode, encoding=None if "b" in mode else encoding,
                       newline=None if "b" in mode else "") as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        with deferred():
            check()                     # a signal whose exception was swallowed: never put the file in place
            os.replace(tmp, path)
            tmp = None
            _record(path)
    except BaseException as exc:
        with deferred():
            if tmp is not None:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(tmp)
        if isinstance(exc, OSError) and (exc.filename in (None, tmp) or exc.filename == path):
            raise OutputError(path, exc.strerror or str(exc)) from None
        raise


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike):
    """Yield a temporary folder that replaces ``path`` when the block succeeds.

    A file at ``path`` is never replaced by a folder (FileExistsError); a folder at ``path`` is replaced as a
    whole (the caller decides whether it may be: :func:`selfcal.io.output.output_folder`). A write into the
    temporary folder that fails is an :class:`~selfcal.errors.OutputError` naming its place below ``path``.
    """
    path = os.path.abspath(os.fspath(path))
    parent = os.path.dirname(path)
    if os.path.lexists(path) and not os.path.isdir(path):
        raise FileExistsError(f"{path} is a file; selfcal does not turn a file into a folder")
    tmp = None
    try:
        os.makedirs(parent, exist_ok=True)
        with deferred():
            tmp = tempfile.mkdtemp(prefix=".selfcal-partial-", dir=parent)
        os.chmod(tmp, 0o777 & ~_umask())
        yield tmp
        with open(os.path.join(tmp, MARKER), "w", encoding="utf-8") as handle:
            handle.write(_MARKER_TEXT)
        with deferred():
            check()
            _swap_in(tmp, path)
            tmp = None
            _record(path)
    except BaseException as exc:
        with deferred():
            if tmp is not None:
                shutil.rmtree(tmp, ignore_errors=True)
        translated = _as_output_error(exc, tmp, path) if tmp is not None else exc
        if translated is not exc:
            raise translated from None
        raise


def _record(path: str) -> None:
    """Note a finished output for the message of a later interrupt, unless it lies in a folder still being
    written (that folder is the output)."""
    if ".selfcal-partial-" not in path:
        record_written(path)


def _swap_in(tmp: str, path: str) -> None:
    """Rename the finished folder ``tmp`` to ``path``, moving a folder there aside first and removing it after."""
    parent = os.path.dirname(path)
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


@contextlib.contextmanager
def atomic_update(path: str | os.PathLike):
    """Yield a temporary copy of the folder ``path`` to change; it replaces ``path`` when the block succeeds
    (``selfcal report``: new figures and report.html appear together, or the folder stays as it was)."""
    path = os.path.realpath(os.fspath(path))   # a link to the folder stays a link
    with atomic_folder(path) as tmp:
        for entry in os.scandir(path):
            target = os.path.join(tmp, entry.name)
            if entry.is_dir(follow_symlinks=False):
                shutil.copytree(entry.path, target, symlinks=True)
            else:
                shutil.copy2(entry.path, target, follow_symlinks=False)
        yield tmp
