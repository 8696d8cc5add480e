"""Rotations, reference frames and intersection: geometry with no knowledge of files."""
from .rotation import matrix_from_opk, matrix_from_opk_with_derivatives, opk_from_matrix

__all__ = ["matrix_from_opk", "matrix_from_opk_with_derivatives", "opk_from_matrix"]
