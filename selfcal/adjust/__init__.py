"""The adjustment engine: self-calibrating bundle adjustment of a block, one engine for every sensor.

>>> result = adjust(block, AdjustOptions(ap=APOptions("brown")))          # doctest: +SKIP
>>> result.sigma0_px, result.converged                          # doctest: +SKIP

:func:`adjust` (:mod:`.engine`) takes a :class:`~selfcal.block.Block` and :class:`AdjustOptions` and returns one
:class:`AdjustmentResult` (:mod:`.result`), whatever the sensor. Inside: the problem's layout (:mod:`.problem`,
:mod:`.parameters`), the kinds of observations as residual blocks (:mod:`.residuals`), the AP columns kept
(:mod:`.ap_columns`), the Schur complement on the points (:mod:`.schur`), the solver (:mod:`.solver`), robust weights
(:mod:`.robust`), cofactors and leverages (:mod:`.covariance`, :mod:`.leverage`).
"""
from typing import TYPE_CHECKING

from ..lazy import attach

#: module -> the public names it defines (imported on first use: importing one light module, the options or the
#: robust losses, does not load the engine)
_MODULES = {
    ".datum": ("behind_camera", "control_far_away", "control_on_a_line", "undetermined_points"),
    ".engine": ("adjust", "camera_models", "problem_at", "start_values"),
    ".options": ("AdjustOptions", "APOptions", "SensorOptions", "SolverOptions", "TrajectoryOptions"),
    ".parameters": ("CameraParameters", "ParameterTable", "apply_free", "parameter_table"),
    ".problem": ("Problem", "State"),
    ".result": ("AdjustmentResult", "Termination"),
    ".robust": ("LOSSES", "RobustOptions"),
    ".solver": ("IterationRecord",),
}
__getattr__, __dir__ = attach(__name__, _MODULES)

if TYPE_CHECKING:
    from .datum import behind_camera, control_far_away, control_on_a_line, undetermined_points
    from .engine import adjust, camera_models, problem_at, start_values
    from .options import AdjustOptions, APOptions, SensorOptions, SolverOptions, TrajectoryOptions
    from .parameters import CameraParameters, ParameterTable, apply_free, parameter_table
    from .problem import Problem, State
    from .result import AdjustmentResult, Termination
    from .robust import LOSSES, RobustOptions
    from .solver import IterationRecord

__all__ = ["AdjustOptions", "APOptions", "SensorOptions", "TrajectoryOptions", "AdjustmentResult", "IterationRecord",
           "RobustOptions", "SolverOptions", "LOSSES",
           "adjust", "apply_free", "start_values", "camera_models", "problem_at", "Problem", "State", "CameraParameters",
           "ParameterTable", "parameter_table", "Termination",
           "behind_camera", "control_far_away", "control_on_a_line", "undetermined_points"]
