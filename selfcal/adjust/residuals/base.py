"""The residual-block contract: what the engine asks of a kind of observation besides the image points.

The image observations couple an image, its camera and an object point; they are the structure the
Schur assembly is cut along (:mod:`.image`). Every other kind of observation touches either the object
points alone or the reduced unknowns theta alone, and enters the normal equations through one of two
small interfaces:

* :class:`PointResiduals`: rows of each observed point (surveyed control coordinates, a terrain height):
  whitened residuals and their 3-column Jacobians, summed into the points' 3x3 normal blocks before the
  points are eliminated;
* :class:`ParameterResiduals`: rows of theta (priors on image and camera parameters, GNSS positions and IMU
  attitudes with their strip-wise shift and drift, a sensor's mounting): a sparse Jacobian added to the
  reduced normal equations. A block may own parameters of its own (the shift and drift terms): they are the
  ``x`` part of theta, laid out in the order of the blocks.

Every row is whitened (l - f divided by its sigma): its normal-equation terms are J^T J and J^T r. A block
has a weight factor per observed item (``weight``, 1 by default): a robust re-weighting multiplies each
item's rows by the square root of its factor, in every kind the same way. Blocks are made by the builders of
:data:`selfcal.adjust.residuals.RESIDUALS` (one line per kind), which the engine iterates over without
knowing any kind by name.
"""
from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

__all__ = ["PointResiduals", "ParameterResiduals", "Triplets"]

#: sparse rows of a parameter block: (row, column, value) triplets (rows counted from the block's first) and the
#: whitened residuals of its rows
Triplets = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


class PointResiduals(ABC):
    """Observations of object points alone, ``width`` rows per observed point.

    ``index`` (n,) lists the block's points it observes; ``weight`` (n,) is each one's weight factor.
    """

    #: observation group (variance components, reports)
    group: str = ""
    #: rows per observed point
    width: int = 3

    def __init__(self, index: np.ndarray):
        self.index = np.asarray(index, np.int64)
        self.weight = np.ones(len(self.index))
        self._position: tuple[int, np.ndarray] | None = None

    def __len__(self) -> int:
        return len(self.index)

    def position(self, n_points: int) -> np.ndarray:
        """The row-group of each of ``n_points`` points (-1: not observed by this block), computed once."""
        if self._position is None or self._position[0] != n_points:
            position = np.full(n_points, -1, np.int64)
            position[self.index] = np.arange(len(self.index))
            self._position = (n_points, position)
        return self._position[1]

    def rows(self, points: np.ndarray, sel: np.ndarray | slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """Whitened residuals l - f (k, width) and Jacobians df/dX (k, width, 3) of the observed points ``sel``
        (positions in ``index``) at their coordinates ``points`` (k, 3), weight factors included."""
        r, J = self.whitened_rows(points, sel)
        w = self.weight[sel]
        if np.any(w != 1.0):
            root = np.sqrt(w)
            r = r * root[:, None]
            J = J * root[:, None, None]
        return r, J

    @abstractmethod
    def whitened_rows(self, points: np.ndarray, sel: np.ndarray | slice) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`rows` without the weight factors."""

    def cost(self, all_points: np.ndarray) -> float:
        """0.5 r^T r of every row at the points' coordinates ``all_points`` (n_points, 3)."""
        if not len(self.index):
            return 0.0
        r, _ = self.rows(all_points[self.index])
        return 0.5 * float(np.sum(r * r))


class ParameterResiduals(ABC):
    """Observations of the reduced unknowns theta alone.

    A block may own parameters (names, which are free, start values): the ``x`` part of theta. The engine lays
    out the free ones of every block in order after the image and camera parameters.
    """

    #: observation group of its rows (variance components, reports), unless :meth:`labels` says otherwise
    group: str = ""
    #: whether it has parameters of its own: then it has the attributes ``names`` (list of str) and ``free`` (bool
    #: array, which of them are estimated; screening holds some), perhaps none of them (see
    #: :class:`.trajectory.TrajectoryTerms`: plain GNSS observations have no shift or drift)
    owns_parameters: bool = False

    @property
    def n_params(self) -> int:
        """How many parameters of its own it has (free or held)."""
        return len(getattr(self, "free", ()))

    def initial(self) -> np.ndarray:
        """Start values of its own parameters."""
        return np.zeros(self.n_params)

    @abstractmethod
    def n_rows(self, problem) -> int:
        """How many rows it has in ``problem`` (held parameters have no prior rows)."""

    def labels(self, problem) -> list[str]:
        """The observation group of each row."""
        return [self.group] * self.n_rows(problem)

    @abstractmethod
    def triplets(self, problem, state, own_column: int, own_values: np.ndarray) -> Triplets:
        """Its whitened Jacobian rows as (row, column, value) triplets in theta's columns, rows counted from 0,
        and its whitened residuals l - f. ``own_column``: theta's column of its first free own parameter;
        ``own_values``: the state's values of its own parameters (all of them, free or held)."""
