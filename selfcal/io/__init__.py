"""Reading and validating block folders and foreign formats; writing results.

I/O never does mathematics: it turns files into the plain data of
:mod:`selfcal.block` and results into files (DESIGN.md §1).
"""
from typing import TYPE_CHECKING

from ..lazy import attach

#: module -> the public names it defines (imported on first use: ``selfcal.io.atomic`` or ``selfcal.io.output``
#: do not load the block reader, the sensors and Numba)
_MODULES = {
    ".atomic": ("atomic_folder", "atomic_write"),
    ".block_folder": ("read_block", "write_block"),
}
__getattr__, __dir__ = attach(__name__, _MODULES)

if TYPE_CHECKING:
    from .atomic import atomic_folder, atomic_write
    from .block_folder import read_block, write_block

__all__ = ["read_block", "write_block", "atomic_folder", "atomic_write"]
