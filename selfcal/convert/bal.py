"""BAL: every camera becomes a ``bal`` camera of its own with one image; image coordinates (centred, y up) become
pixel positions on a frame just large enough to hold the camera's observations."""
from __future__ import annotations

import numpy as np

from ..block import BalCamera, Block, Images, Observations, Points

def bal_behind_camera(problem) -> np.ndarray:
    """Observations (bool over the file's) whose point lies behind its camera; BAL's formula
    p = -P/P_z still gives them a residual, fitted by a mirrored projection; COLMAP's cost
    function would ignore them."""
    from ..sensors.bal import behind_camera

    return behind_camera(problem.points[problem.obs_point], problem.cameras[problem.obs_camera, :6])


def block_from_bal(problem, image_sigma_px: float = 1.0, name: str = "bal") -> Block:
    """A block from a BAL problem (:class:`selfcal.io.bal.BalProblem`), one camera and image per BAL camera."""
    from ..sensors.bal import eop_from_params

    n_cam = len(problem.cameras)
    cameras, widths, heights = {}, np.zeros(n_cam), np.zeros(n_cam)
    for k in range(n_cam):
        sel = problem.obs_camera == k
        half_w = np.ceil(np.max(np.abs(problem.obs_xy[sel, 0]), initial=1.0)) + 1.0
        half_h = np.ceil(np.max(np.abs(problem.obs_xy[sel, 1]), initial=1.0)) + 1.0
        widths[k], heights[k] = 2 * half_w, 2 * half_h
        f, k1, k2 = problem.cameras[k, 6:9]
        cameras[f"cam{k}"] = BalCamera(f"cam{k}", int(widths[k]), int(heights[k]), float(f), float(k1), float(k2))
    position, opk = eop_from_params(problem.cameras[:, :6])
    images = Images(
        image_id=np.array([f"img{k}" for k in range(n_cam)], dtype=object),
        camera_id=np.array([f"cam{k}" for k in range(n_cam)], dtype=object),
        strip_id=np.full(n_cam, "", dtype=object),
        time_s=np.full(n_cam, np.nan),
        position_m=position,
        attitude_rad=opk,
        line=np.arange(1, n_cam + 1),
    )
    n_pt = len(problem.points)
    points = Points(point_id=np.array([f"p{k}" for k in range(n_pt)], dtype=object),
                    role=np.full(n_pt, "tie", dtype=object), xyz_m=problem.points.copy(),
                    sigma_m=np.full((n_pt, 3), np.nan), line=np.arange(1, n_pt + 1))
    cam = problem.obs_camera
    pixel = np.column_stack([problem.obs_xy[:, 0] + widths[cam] / 2, heights[cam] / 2 - problem.obs_xy[:, 1]])
    m = len(cam)
    observations = Observations(cam.copy(), problem.obs_point.copy(), pixel, np.full(m, image_sigma_px),
                                np.arange(1, m + 1))
    return Block(name=name, crs="local", cameras=cameras, images=images, points=points,
                 observations=observations, image_sigma_px=image_sigma_px, datum="free")


#: a control coordinate with this sigma (m) is as good as free: jigsaw's radius=no holds a Free point's radius only
