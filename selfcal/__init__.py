"""selfcal: self-calibrating bundle adjustment of frame cameras, pushbroom and RPC satellites and planetary
line scanners, with wavelet additional parameters, data snooping, screening and check-point evaluation.

The Python API (the same steps as ``selfcal adjust``)::

    import selfcal

    block = selfcal.read_block("block/")                 # a block folder (DESIGN.md §3)
    outcome = selfcal.bundle_adjust(block, ap="wavelet:db4", screen=True)
    print(outcome.summary["sigma0_px"], outcome.summary["rmsd_chk_xy_m"])
    outcome.write("results/")                            # the results folder (DESIGN.md §4), report included
    results = selfcal.read_results("results/")           # a results folder as plain data

Progress goes to ``logging.getLogger("selfcal")`` (INFO), beside the lines ``selfcal adjust`` prints.
Everything else is reached through its package (``selfcal.io``, ``selfcal.adjust``, ``selfcal.sensors``...).
"""
from __future__ import annotations

import os

# NumPy's and SciPy's wheels each bring their own OpenBLAS, and the engine alternates their calls (NumPy's
# products, SciPy's triangular solves and factorisations). An OpenBLAS thread that finished spins for about
# 2^28 cycles before it sleeps, and on two cores the other runtime's threads then wait for a core: Takahashi's
# recurrence on a 5000-image block took 14.6 s with that and 11.1 s with 2^12 (docs/DESIGN-NOTES.md, "Two
# BLAS runtimes"). OpenBLAS reads this when it is loaded: it applies where selfcal is imported before NumPy (the
# command line), and a value the user set stays.
os.environ.setdefault("OPENBLAS_THREAD_TIMEOUT", "12")

from importlib import import_module  # noqa: E402


def _version() -> str:
    """The installed distribution's version (importlib.metadata costs 35 ms: looked up on first use only, so
    that the command line installs its signal handlers within milliseconds of starting)."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("selfcal")
    except PackageNotFoundError:      # pragma: no cover - running from a tree that was never installed
        return "0+unknown"

#: public name -> module that defines it (imported on first use: ``import selfcal`` stays light)
_API = {
    "read_block": "selfcal.io.block_folder",
    "write_block": "selfcal.io.block_folder",
    "read_results": "selfcal.io.results",
    "bundle_adjust": "selfcal.workflows.api",
    "Outcome": "selfcal.workflows.api",
}

__all__ = ["__version__", *_API]


def __getattr__(name: str):
    if name == "__version__":
        value = _version()
        globals()["__version__"] = value
        return value
    if name in _API:
        return getattr(import_module(_API[name]), name)
    raise AttributeError(f"module 'selfcal' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_API) | {"__version__"})
