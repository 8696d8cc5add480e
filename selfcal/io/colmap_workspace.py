"""The files of a COLMAP dense workspace (``selfcal export colmap-workspace``; its content:
:mod:`selfcal.workflows.export_workspace`): the images found for a block, and the workspace written in one atomic
step from the undistorted images, the sparse model and selfcal's two files beside it."""
from __future__ import annotations

import csv
import json
import os
from typing import Iterable

import numpy as np

from ..errors import BlockError
from .atomic import atomic_folder, atomic_write
from .colmap import write_colmap_bin, write_stereo_config
from .images import write_image
from .results import to_jsonable

__all__ = ["find_images", "write_workspace", "ORIGIN_FILE", "POINTS_FILE"]

#: the workspace file that says where the model's coordinates are (object = model + origin_m)
ORIGIN_FILE = "selfcal_origin.json"
#: the workspace file that names each 3-D point's selfcal point id
POINTS_FILE = "selfcal_points.csv"


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
                    points: Iterable[tuple[int, str, str]]) -> None:
    """Write the workspace ``out`` atomically (all of it, or nothing, :func:`selfcal.io.atomic.atomic_folder`):
    ``images`` (name, pixels) under ``images/`` as they come (a generator: one image in memory at a time), the
    sparse ``model`` (:func:`selfcal.io.colmap.write_colmap_bin`), ``origin`` as ``sparse/selfcal_origin.json``,
    ``points`` (point3D_id, point_id, role) as ``sparse/selfcal_points.csv`` and the stereo configuration of the
    model's images."""
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
