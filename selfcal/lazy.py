"""A package's public names imported on first use (PEP 562), so that importing one light module of a package
(``selfcal.adjust.robust``, ``selfcal.workflows.progress``) does not import the whole package: the command line
answers ``--help`` without loading SciPy, Numba and matplotlib (issue 45). A package lists its names once, with
the module of each; static type checkers read the same imports under ``TYPE_CHECKING``."""
from __future__ import annotations

from importlib import import_module
from importlib.util import find_spec
from collections.abc import Mapping
from typing import Callable

__all__ = ["attach"]


def attach(package: str, modules: Mapping[str, tuple[str, ...]]) -> tuple[Callable[[str], object], Callable[[], list]]:
    """``__getattr__`` and ``__dir__`` for ``package`` whose public names live in ``modules`` (relative module
    name -> its names): a name is imported from its module the first time it is asked for, then kept; a
    submodule's name imports the submodule, as an eager ``__init__`` that imported it made it an attribute."""
    where = {name: module for module, names in modules.items() for name in names}

    def __getattr__(name: str):
        if name not in where:
            if not name.startswith("__") and find_spec(f"{package}.{name}") is not None:
                return import_module(f"{package}.{name}")      # a submodule (``selfcal.adjust.engine``)
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(where[name], package), name)
        setattr(import_module(package), name, value)
        return value

    def __dir__() -> list:
        return sorted(set(where) | set(vars(import_module(package))))
    return __getattr__, __dir__
