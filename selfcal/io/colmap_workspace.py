"""The files of a COLMAP dense workspace (``selfcal export colmap-workspace``; its content:
:mod:`selfcal.workflows.export_workspace`): the images found for a block, and the workspace written in one atomic
step from the undistorted images, the sparse model and selfcal's two files beside it."""
from __future__ import annotations

import csv
import json
import os
from dataclasses import replace
from typing import Iterable

import numpy as np

from ..errors import BlockError
from .atomic import atomic_folder, atomic_write
from .colmap import write_colmap_bin, write_stereo_config
from .colmap_database import write_colmap_database
from .images import write_image
from .results import to_jsonable

__all__ = ["find_images", "write_workspace", "ORIGIN_FILE", "POINTS_FILE", "DATABASE_FILE", "TRIANGULATOR_INPUT"]

#: the workspace file that says where the model's coordinates are (object = model + origin_m)
ORIGIN_FILE = "selfcal_origin.json"
#: the workspace file that names each 3-D point's selfcal point id
POINTS_FILE = "selfcal_points.csv"
#: the feature database of ``colmap point_triangulator`` (the model's 2-D points as keypoints, its tracks as matches)
DATABASE_FILE = "database.db"
#: the model that ``colmap point_triangulator --input_path`` takes: the cameras and poses, no 2-D or 3-D points
TRIANGULATOR_INPUT = os.path.join("sparse", "triangulator_input")


def find_images(folder: str, image_ids) -> tuple[dict[str, str], list[str]]:
    """image id -> file name in ``folder`` (relative; the id itself, which may hold sub-folders as COLMAP image
    names do, else the one file of the folder whose name without extension is the id), and the folder's
    files that belong to no image."""
    if not os.path.isdir(folder):
        raise BlockError(folder, "--images: no such folder")
    root = os.path.realpath(folder)
    files = sorted(f for f in os.listdir(folder) if os.path.isfile(os.path.join(folder, f)))
    by_stem: dict[str, list[str]] = {}
    for f in files:
        by_stem.setdefault(os.path.splitext(f)[0], []).append(f)
    found = {}
    for image_id in image_ids:
        path = os.path.realpath(os.path.join(folder, image_id))
        if os.path.commonpath([path, root]) == root and os.path.isfile(path):
            found[image_id] = image_id
        elif image_id in by_stem:
            if len(by_stem[image_id]) > 1:
                raise BlockError(os.path.join(folder, by_stem[image_id][0]),
                                 f"image {image_id}: {len(by_stem[image_id])} files could be it "
                                 f"({', '.join(by_stem[image_id])}); keep one")
            found[image_id] = by_stem[image_id][0]
    used = set(found.values())
    return found, [f for f in files if f not in used]


def write_workspace(out: str, model, images: Iterable[tuple[str, np.ndarray]], origin: dict,
                    points: Iterable[tuple[int, str, str]], features: tuple[dict, dict]) -> None:
    """Write the workspace ``out`` atomically (all of it, or nothing, :func:`selfcal.io.atomic.atomic_folder`):
    ``images`` (name, pixels) under ``images/`` as they come (a generator: one image in memory at a time), then
    the sparse ``model`` (:func:`selfcal.io.colmap.write_colmap_bin`; it is written after the last image has
    been taken, so the images' generator may complete it: the points' colours), ``origin`` as
    ``sparse/selfcal_origin.json``, ``points`` (point3D_id, point_id, role) as ``sparse/selfcal_points.csv``,
    the stereo configuration of the model's images, and what ``colmap point_triangulator`` takes:
    ``database.db`` with ``features`` (keypoints, matches: :func:`selfcal.io.colmap_database.write_colmap_database`)
    and ``sparse/triangulator_input/`` (the model's cameras and poses without 2-D or 3-D points)."""
    with atomic_folder(out) as tmp:
        os.makedirs(os.path.join(tmp, "images"))
        for name, pixels in images:
            target = os.path.join(tmp, "images", name)
            os.makedirs(os.path.dirname(target), exist_ok=True)
            write_image(target, pixels)
        sparse = os.path.join(tmp, "sparse")
        write_colmap_bin(sparse, model)
        with atomic_write(os.path.join(sparse, ORIGIN_FILE)) as handle:
            json.dump(to_jsonable(origin | {"points_file": POINTS_FILE}), handle, indent=2)
            handle.write("\n")
        with atomic_write(os.path.join(sparse, POINTS_FILE)) as handle:
            table = csv.writer(handle, lineterminator="\n")
            table.writerow(["point3D_id", "point_id", "role"])
            table.writerows(points)
        write_stereo_config(os.path.join(tmp, "stereo"), list(model.image_names))
        keypoints, matches = features
        write_colmap_database(os.path.join(tmp, DATABASE_FILE), model.cameras,
                              list(zip(model.image_ids.tolist(), model.image_names, model.image_camera.tolist())),
                              keypoints, matches)
        empty = replace(model, obs_image=np.zeros(0, np.int64), obs_xy=np.zeros((0, 2)),
                        obs_point=np.zeros(0, np.int64), point_ids=np.zeros(0, np.int64),
                        point_xyz=np.zeros((0, 3)), point_error=np.zeros(0), point_rgb=None)
        write_colmap_bin(os.path.join(tmp, TRIANGULATOR_INPUT), empty)
