"""Reading and validating block folders and foreign formats; writing results.

I/O never does mathematics: it turns files into the plain data of
:mod:`selfcal.block` and results into files (DESIGN.md §1).
"""
from .atomic import atomic_folder, atomic_write
from .block_folder import read_block, write_block

__all__ = ["read_block", "write_block", "atomic_folder", "atomic_write"]
