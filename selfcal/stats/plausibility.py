"""Whether an adjustment's solution is a solution: a block that collapsed is a failure, never "converged".

Least squares can converge to an absurd state when the data cannot hold it: matcher tie points full of
wrong observations, a principal distance left free over flat ground without camera positions. Two signs,
for every sensor:

* object points behind the cameras that observe them (:func:`selfcal.adjust.datum.behind_camera`), for sensors
  that are central projections (``Sensor.central_projection``): a block folded through its projection centres
  (a central projection fits a point's mirror image), cameras on or under the terrain they look at;
* a camera parameter that moved further than its sensor says it can (``Parameter.plausible``: a frame camera's
  principal distance by half of itself; the principal distance of a real camera is known to that), or, with
  an a-priori sigma, by more than :data:`PRIOR_SIGMAS` of it.
"""
from __future__ import annotations

import numpy as np

__all__ = ["collapse", "PRIOR_SIGMAS", "BEHIND_SHARE"]

#: a parameter with an a-priori sigma is absurd beyond this many of its sigmas from its start
PRIOR_SIGMAS = 10.0
#: more than this share of the image observations behind their cameras (or 10 of them) is a collapse
BEHIND_SHARE = 0.005


def collapse(result) -> str | None:
    """Why the solution of ``result`` (an :class:`~selfcal.adjust.AdjustmentResult`) is absurd, or None."""
    from ..adjust import behind_camera
    problem, state, block = result.problem, result.state, result.block
    reasons = []
    for cam, values, slot in zip(problem.cameras, state.cameras, _slots(problem)):
        for i, parameter in enumerate(slot.sensor.camera_parameters):
            start, now, sigma = cam.prior_value[i], values[i], cam.prior_sigma[i]
            if not cam.free[i] or not np.isfinite(start):
                continue
            moved = abs(now - start)
            if np.isfinite(sigma) and sigma > 0 and moved > PRIOR_SIGMAS * sigma:
                reasons.append(f"camera '{cam.camera_id}': {parameter.name} moved from {start:.6g} {parameter.unit} "
                               f"(start) to {now:.6g} {parameter.unit}, {moved / sigma:.0f} times its a-priori sigma")
            elif parameter.plausible is not None and moved > parameter.plausible * abs(start):
                reasons.append(f"camera '{cam.camera_id}': {parameter.name} moved from {start:.6g} {parameter.unit} "
                               f"(start) to {now:.6g} {parameter.unit}, more than {parameter.plausible:.0%} of itself")
    behind = behind_camera(problem, state)
    for slot in problem.sensors:
        if not slot.sensor.central_projection:       # (a line scanner's rays say nothing of sides here)
            behind[slot.observations] = False
    if behind.sum() > max(10, BEHIND_SHARE * len(behind)):
        points = np.unique(problem.obs_point[behind])
        names = ", ".join(f"'{block.points.point_id[p]}'" for p in points[:5])
        reasons.append(f"{int(behind.sum())} image observations of {points.size} points lie behind their cameras at "
                       f"the solution (e.g. {names}): cameras on or under what they look at")
    if not reasons:
        return None
    return ("the adjustment collapsed: " + "; ".join(reasons) + ". The data do not hold the block here (gross "
            "errors, or a parameter the block cannot determine: give the camera's principal distance an a-priori "
            "sigma, camera positions, or more control)")


def _slots(problem) -> list:
    """The sensor slot of each camera of ``problem``."""
    out = []
    for k in range(len(problem.cameras)):
        image = int(np.flatnonzero(problem.image_camera == k)[0])
        out.append(next(s for s in problem.sensors if image in set(s.images.tolist())))
    return out
