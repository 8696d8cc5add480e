"""Foreign models (read by :mod:`selfcal.io`) turned into selfcal blocks, and results into foreign models: the
conventions of each source are translated here, once, one module per source.

* :mod:`.colmap`: a COLMAP sparse model (poses, cameras, distortion as initial ``brown`` APs, control by a 3-D
  similarity); :mod:`.workspace`: a results folder as a COLMAP dense workspace's sparse model;
* :mod:`.bal`: Bundle Adjustment in the Large; :mod:`.isis`: ISIS control networks with usgscsm/ALE ISDs;
* :mod:`.uav`: PAT-B, Pix4D, OpenSfM and Metashape markers; :mod:`.gnss`: camera GNSS/attitude from the images;
* :mod:`.calibration`: another tool's camera calibration as a block camera;
* :mod:`.labels`: control labels joined to measured points (exact, then the normalisations real files need);
  :mod:`.control`: control checked against the block's own position (X and Y, latitude and longitude swapped),
  also by ``selfcal adjust`` before any work.
"""
from .bal import bal_behind_camera, block_from_bal
from .calibration import camera_from_calibration
from .colmap import (DEFAULT_GCP_LIST_SIGMA_M, DEFAULT_PIXEL_SIZE_MM, MAX_RAY_MISS_DEG, MEASUREMENT_MISS_SIGMAS,
                     PLAN_ONLY_SIGMA_Z_M, block_from_colmap, colmap_distortion_as_brown, colmap_undistort)
from .isis import FREE_SIGMA_M, adjusted_network, block_from_isis
from .workspace import (FALLBACK_GREY, WORKSPACE_ROLES, ColmapWorkspace, PointColours, RollingShutters, colmap_workspace,
                        image_rgb_at, keypoints_and_matches)

__all__ = ["block_from_colmap", "colmap_undistort", "colmap_distortion_as_brown", "block_from_bal",
           "bal_behind_camera", "block_from_isis", "adjusted_network", "camera_from_calibration", "colmap_workspace", "ColmapWorkspace",
           "RollingShutters",
           "WORKSPACE_ROLES", "FALLBACK_GREY", "PointColours", "image_rgb_at", "keypoints_and_matches",
           "PLAN_ONLY_SIGMA_Z_M", "FREE_SIGMA_M", "MEASUREMENT_MISS_SIGMAS", "MAX_RAY_MISS_DEG",
           "DEFAULT_PIXEL_SIZE_MM", "DEFAULT_GCP_LIST_SIGMA_M"]
