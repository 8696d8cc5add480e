"""The gate every command's ``--out`` passes before any work is done.

A command names what it will write and what it reads; :func:`output_folder`,
:func:`output_file` and :func:`update_folder` refuse with a
:class:`~selfcal.errors.UsageError` (exit 2) saying why:

* an empty path (an unset shell variable);
* an output that is an input, holds one or lies inside one (compared after links are resolved);
* a folder where a file stands, or a file where a folder stands;
* an existing, non-empty folder that selfcal did not write (no :data:`~selfcal.io.atomic.MARKER` in it),
  unless ``force``;
* a place that cannot be written: the nearest existing folder is probed by creating and removing a
  temporary folder in it, so a read-only folder, a parent that is a file or a full disk is found before
  an adjustment of minutes rather than after it.

The writing itself stays with :mod:`selfcal.io.atomic`, which leaves the marker in each folder it writes.
"""
from __future__ import annotations

import errno
import os
import shutil
import tempfile

from ..errors import UsageError
from ..interrupts import deferred
from .atomic import MARKER

__all__ = ["output_folder", "output_file", "update_folder", "check_inputs", "holds_results", "failed_run_folder"]


def _real(path: str) -> str:
    return os.path.realpath(os.path.abspath(os.path.expanduser(path)))


def _inside(inner: str, outer: str) -> bool:
    """Whether real path ``inner`` is ``outer`` or lies below it."""
    try:
        return os.path.commonpath([inner, outer]) == outer
    except ValueError:                  # different drives
        return False


def _nonempty(path: str, option: str) -> str:
    if path is None or str(path) == "":
        raise UsageError(f"{option} is empty (an unset shell variable?); name the place to write")
    if "\0" in str(path):
        raise UsageError(f"{option} holds a NUL character")
    return os.fspath(path)


def check_inputs(path: str, inputs, option: str = "--out") -> None:
    """Refuse an output ``path`` that is, holds or lies inside one of ``inputs`` (None entries are skipped)."""
    out = _real(path)
    for given in inputs:
        if given is None or str(given) == "":
            continue
        source = _real(os.fspath(given))
        if out == source:
            raise UsageError(f"{option} {path} is the input {given}; selfcal never writes over what it reads")
        if _inside(source, out):
            raise UsageError(f"{option} {path} holds the input {given}; writing there would replace it")
        if _inside(out, source):
            raise UsageError(f"{option} {path} lies inside the input {given}; write the output elsewhere")


def _nearest_existing(path: str) -> str:
    here = os.path.dirname(os.path.abspath(path))
    while not os.path.lexists(here):
        parent = os.path.dirname(here)
        if parent == here:
            break
        here = parent
    return here


def _probe(folder: str, path: str, option: str) -> None:
    """Create and remove a temporary folder in ``folder`` (where ``path`` will be written)."""
    if not os.path.isdir(folder):
        raise UsageError(f"{option} {path}: {folder} is a file, not a folder")
    with deferred():                    # a signal never leaves the probe behind
        try:
            probe = tempfile.mkdtemp(prefix=".selfcal-partial-", dir=folder)
        except OSError as exc:
            reason = "read-only" if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS) else exc.strerror
            raise UsageError(f"{option} {path}: cannot write in {folder} ({reason})") from None
        shutil.rmtree(probe, ignore_errors=True)


def output_folder(path, inputs=(), force: bool = False, option: str = "--out", force_name: str = "--force") -> str:
    """Check that a command may write (replace) the folder ``path``; return it.

    An existing folder is replaced only when it is empty, when selfcal wrote it (it holds the marker) or
    with ``force``; an existing file never is.
    """
    path = _nonempty(path, option)
    check_inputs(path, inputs, option)
    if os.path.lexists(path):
        if not os.path.isdir(path):
            raise UsageError(f"{option} {path} is a file; selfcal writes a folder there and never turns a file "
                             f"into a folder")
        try:
            entries = os.listdir(path)
        except OSError as exc:
            raise UsageError(f"{option} {path}: cannot read the folder ({exc.strerror})") from None
        if entries and MARKER not in entries and not force:
            raise UsageError(f"{option} {path} exists and was not written by selfcal (no {MARKER} in it); "
                             f"selfcal would replace all of it: name another folder, or add {force_name}")
    _probe(_nearest_existing(path), path, option)
    return path


def output_file(path, inputs=(), option: str = "--out") -> str:
    """Check that a command may write (replace) the file ``path``; return it. An existing folder is refused,
    a missing parent folder is created when the file is written."""
    path = _nonempty(path, option)
    check_inputs(path, inputs, option)
    if os.path.isdir(path) or path.endswith(os.sep):
        raise UsageError(f"{option} {path} is a folder; name the file to write")
    _probe(_nearest_existing(path), path, option)
    return path


def update_folder(path, option: str = "RESULTS") -> str:
    """Check that the existing folder ``path`` may be updated (``selfcal report``: a changed copy replaces it, so
    its parent folder must be writable)."""
    path = _nonempty(path, option)
    if os.path.isdir(path):
        real = os.path.realpath(path)
        _probe(os.path.dirname(real), path, option)
    return path


def holds_results(path) -> bool:
    """Whether ``path`` is a non-empty folder: earlier output (or the user's files) a failed run must not replace."""
    try:
        return os.path.isdir(path) and bool(os.listdir(path))
    except OSError:
        return True


def failed_run_folder(path: str) -> tuple[str | None, str]:
    """Where the files of a failed or unconverged run go when ``path`` already holds results: the sibling
    ``PATH-failed`` (replaced if selfcal wrote it), or nowhere; and the sentence that says which and why."""
    path = os.fspath(path).rstrip(os.sep) or os.sep
    if not holds_results(path):
        return path, f"this run's files are in {path}"
    sibling = path + "-failed"
    kept = f"{path} keeps the earlier results; this run's files were not written"
    if os.path.lexists(sibling) and not os.path.isdir(sibling):
        return None, f"{kept} ({sibling} is a file)"
    if holds_results(sibling) and not os.path.exists(os.path.join(sibling, MARKER)):
        return None, f"{kept} ({sibling} exists and selfcal did not write it)"
    try:
        _probe(_nearest_existing(sibling), sibling, "the folder")
    except UsageError as exc:
        return None, f"{kept} ({exc})"
    return sibling, f"{path} keeps the earlier results; this run's files are in {sibling}"
