"""A COLMAP feature database (``database.db``, SQLite) holding a sparse model's cameras, images, keypoints and
verified matches, so that ``colmap point_triangulator`` can triangulate the model's tracks again from its poses.

The tables and blobs are those of COLMAP's ``src/base/database.cc`` (3.8, the schema that later versions
migrate when they open the file; ``doc/database.rst``): ``cameras`` (params: float64 blob), ``images`` (no pose
priors), ``keypoints`` (float32 rows x 6: x, y and the identity affine shape a11 a12 a21 a22, in the model's
pixel convention, the upper-left corner of the first pixel at (0, 0)), ``matches`` and ``two_view_geometries``
(uint32 rows x 2 of keypoint indices; pair id = 2147483647 id1 + id2 with id1 < id2; the geometry's
``config`` 2, CALIBRATED: the matches are inliers of the known relative pose); ``descriptors`` stays empty
(the triangulator reads none).
"""
from __future__ import annotations

import contextlib
import os
import sqlite3

import numpy as np

from ..errors import OutputError
from .colmap import MODEL_IDS, ColmapCamera

__all__ = ["write_colmap_database", "pair_id", "MAX_NUM_IMAGES"]

#: COLMAP's kMaxNumImages: the factor of the first image id in a pair id
MAX_NUM_IMAGES = 2147483647
#: TwoViewGeometry::CALIBRATED
_CALIBRATED = 2

_SCHEMA = f"""
CREATE TABLE cameras (camera_id INTEGER PRIMARY KEY AUTOINCREMENT NOT NULL, model INTEGER NOT NULL,
    width INTEGER NOT NULL, height INTEGER NOT NULL, params BLOB, prior_focal_length INTEGER NOT NULL);
CREATE TABLE images (image_id INTEGER PRIMARY KEY AUTOINCREMENT NOT NULL, name TEXT NOT NULL UNIQUE,
    camera_id INTEGER NOT NULL, prior_qw REAL, prior_qx REAL, prior_qy REAL, prior_qz REAL, prior_tx REAL,
    prior_ty REAL, prior_tz REAL, CONSTRAINT image_id_check CHECK(image_id >= 0 and image_id < {MAX_NUM_IMAGES}),
    FOREIGN KEY(camera_id) REFERENCES cameras(camera_id));
CREATE UNIQUE INDEX index_name ON images(name);
CREATE TABLE keypoints (image_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL, cols INTEGER NOT NULL,
    data BLOB, FOREIGN KEY(image_id) REFERENCES images(image_id) ON DELETE CASCADE);
CREATE TABLE descriptors (image_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL, cols INTEGER NOT NULL,
    data BLOB, FOREIGN KEY(image_id) REFERENCES images(image_id) ON DELETE CASCADE);
CREATE TABLE matches (pair_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL, cols INTEGER NOT NULL,
    data BLOB);
CREATE TABLE two_view_geometries (pair_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL,
    cols INTEGER NOT NULL, data BLOB, config INTEGER NOT NULL, F BLOB, E BLOB, H BLOB, qvec BLOB, tvec BLOB);
"""


def pair_id(image_id1: int, image_id2: int) -> int:
    """COLMAP's pair id of two images (the smaller id first)."""
    a, b = sorted((int(image_id1), int(image_id2)))
    return MAX_NUM_IMAGES * a + b


def write_colmap_database(path: str | os.PathLike, cameras: dict[int, ColmapCamera],
                          images: list[tuple[int, str, int]], keypoints: dict[int, np.ndarray],
                          matches: dict[tuple[int, int], np.ndarray]) -> None:
    """Write the database ``path`` (written beside it and renamed into place: never half there; an SQLite error
    is an :class:`~selfcal.errors.OutputError` naming ``path``).

    ``cameras``: COLMAP camera id -> camera; ``images``: (image id, name, camera id); ``keypoints``: image id ->
    (n x 2) pixel positions; ``matches``: (image id 1, image id 2) -> (k x 2) keypoint indices, written both as
    raw matches and as the verified (inlier) matches that the mappers read."""
    path = os.fspath(path)
    tmp = path + ".partial"
    with contextlib.suppress(FileNotFoundError):
        os.unlink(tmp)
    try:
        connection = sqlite3.connect(tmp)
        try:
            connection.executescript(_SCHEMA)
            connection.executemany(
                "INSERT INTO cameras VALUES (?, ?, ?, ?, ?, ?)",
                [(cid, MODEL_IDS[cam.model][0], cam.width, cam.height,
                  np.array([cam.params[n] for n in MODEL_IDS[cam.model][1]], "<f8").tobytes(), 1)
                 for cid, cam in sorted(cameras.items())])
            connection.executemany("INSERT INTO images (image_id, name, camera_id) VALUES (?, ?, ?)",
                                   [(int(i), str(name), int(c)) for i, name, c in images])
            rows = []
            for image_id, xy in sorted(keypoints.items()):
                xy = np.asarray(xy, float).reshape(-1, 2)
                blob = np.zeros((len(xy), 6), "<f4")
                blob[:, :2], blob[:, 2], blob[:, 5] = xy, 1.0, 1.0
                rows.append((int(image_id), len(xy), 6, blob.tobytes()))
            connection.executemany("INSERT INTO keypoints VALUES (?, ?, ?, ?)", rows)
            pairs = []
            for (id1, id2), idx in sorted(matches.items()):
                idx = np.asarray(idx, np.int64).reshape(-1, 2)
                if id1 > id2:
                    id1, id2, idx = id2, id1, idx[:, ::-1]
                pairs.append((pair_id(id1, id2), len(idx), 2, np.ascontiguousarray(idx, "<u4").tobytes()))
            connection.executemany("INSERT INTO matches VALUES (?, ?, ?, ?)", pairs)
            connection.executemany("INSERT INTO two_view_geometries (pair_id, rows, cols, data, config) "
                                   f"VALUES (?, ?, ?, ?, {_CALIBRATED})", pairs)
            connection.commit()
        finally:
            connection.close()
        os.replace(tmp, path)
    except sqlite3.Error as exc:                 # a full disk, a read-only folder: the file system's words
        raise OutputError(path, str(exc)) from None
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
