"""OpenSfM (and OpenDroneMap) reconstructions: ``reconstruction.json`` and ``tracks.csv``, as plain data.

Conventions (OpenSfM's doc/source/geometry.rst, "Coordinate Systems" and "Camera Models"):

* a shot's pose maps world to camera, x_cam = R x_world + t, R given as ``rotation`` (an angle-axis vector,
  radians) and t as ``translation``; the camera looks along +z with x right and y down;
* cameras are in *normalized image coordinates*: origin at the image centre, x right, y down, the larger image
  dimension 1. ``focal`` (``focal_x``, ``focal_y``) and ``c_x``, ``c_y`` are in these units;
* pixel coordinates (origin at the centre of the upper-left pixel) are n * max(w, h) + (w - 1) / 2, so with
  selfcal's convention (origin at the pixel's corner) col = x_n * max(w, h) + w / 2, row = y_n * max(w, h) + h / 2;
* ``tracks.csv`` (version header ``OPENSFM_TRACKS_VERSION_v2``, tab separated) holds per row the image, track
  id, feature id, the feature's normalized x and y, scale, r g b, segmentation and instance (v1 has no
  segmentation/instance, v0 neither scale). A track id names a point of ``reconstruction.json``.

The conversion to pixels and to selfcal's camera frame is :mod:`selfcal.convert.uav`'s.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import TypeGuard

import numpy as np

from ..errors import BlockError
from .text import read_json, read_text

__all__ = ["OpenSfmCamera", "OpenSfmReconstruction", "OpenSfmTracks", "read_reconstruction", "read_tracks",
           "CAMERA_PARAMETERS", "KNOWN_PARAMETERS", "check_camera_numbers"]

#: projection type -> parameters it needs (normalized units)
CAMERA_PARAMETERS = {
    "perspective": ("focal", "k1", "k2"),
    "simple_radial": ("focal_x", "focal_y", "c_x", "c_y", "k1"),
    "radial": ("focal_x", "focal_y", "c_x", "c_y", "k1", "k2"),
    "brown": ("focal_x", "focal_y", "c_x", "c_y", "k1", "k2", "k3", "p1", "p2"),
}


#: fields of a tracks.csv line by version (OpenSfM's io: v1 added the feature scale, v2 segmentation and instance)
TRACK_FIELDS = {
    "v0": ("image", "track_id", "feature_id", "x", "y", "r", "g", "b"),
    "v1": ("image", "track_id", "feature_id", "x", "y", "scale", "r", "g", "b"),
    "v2": ("image", "track_id", "feature_id", "x", "y", "scale", "r", "g", "b", "segmentation", "instance"),
}


@dataclass(frozen=True)
class OpenSfmCamera:
    camera_id: str
    projection_type: str
    width: int
    height: int
    params: dict                  # the CAMERA_PARAMETERS of its type (normalized units)


@dataclass(frozen=True)
class OpenSfmReconstruction:
    path: str
    cameras: dict                 # camera id -> OpenSfmCamera
    shot_ids: np.ndarray          # (n,) image names
    shot_camera: np.ndarray       # (n,) camera id
    rotation: np.ndarray          # (n, 3) angle-axis, world -> camera
    translation: np.ndarray       # (n, 3)
    point_ids: np.ndarray         # (k,) track ids
    point_xyz: np.ndarray         # (k, 3)
    n_reconstructions: int        # how many the file holds (the first is read)


@dataclass(frozen=True)
class OpenSfmTracks:
    path: str
    image: np.ndarray             # (m,)
    track_id: np.ndarray          # (m,)
    xy_normalized: np.ndarray     # (m, 2) x right, y down, the larger image dimension 1
    line: np.ndarray              # (m,)


def _positive_int(value: object) -> TypeGuard[int]:
    """A JSON integer above zero (not a boolean, which Python counts as an int)."""
    return isinstance(value, int) and not isinstance(value, bool) and value > 0


def _number(path, value, where) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise BlockError(path, f"{where}: {value!r} is not a number")
    return float(value)


def _vector(path, value, where, n=3) -> list[float]:
    if not isinstance(value, list) or len(value) != n:
        raise BlockError(path, f"{where}: expected a list of {n} numbers, found {value!r}"[:200])
    return [_number(path, v, where) for v in value]


#: every camera parameter OpenSfM writes (a value of one that its projection type does not use is still checked)
KNOWN_PARAMETERS = ("focal", "focal_x", "focal_y", "c_x", "c_y", "k1", "k2", "k3", "k4", "p1", "p2")


def check_camera_numbers(path: str, camera: dict, where: str) -> None:
    """Every parameter of an OpenSfM camera object is a finite number, the focal lengths positive: a text where
    a number belongs is an error even where the projection type does not use it (``"focal": "abc"``)."""
    for name in KNOWN_PARAMETERS:
        if name in camera:
            value = _number(path, camera[name], f"{where}, '{name}'")
            if name.startswith("focal") and not value > 0:
                raise BlockError(path, f"{where}, '{name}': the focal length must be positive, found {value!r}")


def read_reconstruction(path: str | os.PathLike) -> OpenSfmReconstruction:
    """The first reconstruction of an OpenSfM ``reconstruction.json``."""
    path = os.fspath(path)
    data = read_json(path, "OpenSfM reconstruction")
    if isinstance(data, dict):
        data = [data]
    if not isinstance(data, list) or not data or not isinstance(data[0], dict):
        raise BlockError(path, "expected a list of reconstructions (objects with cameras, shots and points)")
    rec = data[0]
    for key in ("cameras", "shots", "points"):
        if not isinstance(rec.get(key), dict):
            raise BlockError(path, f"the reconstruction has no '{key}' object")
    cameras = {}
    for cid, cam in rec["cameras"].items():
        where = f"camera '{cid}'"
        if not isinstance(cam, dict):
            raise BlockError(path, f"{where} is not an object")
        kind = cam.get("projection_type", "perspective")
        if kind not in CAMERA_PARAMETERS:
            raise BlockError(path, f"{where}: projection type '{kind}' is not a perspective model selfcal takes "
                                   f"({', '.join(CAMERA_PARAMETERS)})")
        width, height = cam.get("width"), cam.get("height")
        if not (_positive_int(width) and _positive_int(height)):
            raise BlockError(path, f"{where}: width and height must be positive integers, found {[width, height]}")
        params = {}
        for name in CAMERA_PARAMETERS[kind]:
            if name not in cam:
                if name.startswith(("k", "p")):
                    params[name] = 0.0
                    continue
                raise BlockError(path, f"{where} ({kind}) has no '{name}'")
            params[name] = _number(path, cam[name], f"{where}, '{name}'")
        check_camera_numbers(path, cam, where)
        cameras[cid] = OpenSfmCamera(cid, kind, width, height, params)
    ids, cams, rot, trans = [], [], [], []
    for sid, shot in rec["shots"].items():
        where = f"shot '{sid}'"
        if not isinstance(shot, dict):
            raise BlockError(path, f"{where} is not an object")
        if shot.get("camera") not in cameras:
            raise BlockError(path, f"{where}: camera {shot.get('camera')!r} is not among the reconstruction's cameras")
        ids.append(sid)
        cams.append(shot["camera"])
        rot.append(_vector(path, shot.get("rotation"), f"{where}, 'rotation'"))
        trans.append(_vector(path, shot.get("translation"), f"{where}, 'translation'"))
    if not ids:
        raise BlockError(path, "the reconstruction has no shots")
    pids, xyz = [], []
    for pid, point in rec["points"].items():
        if not isinstance(point, dict):
            raise BlockError(path, f"point '{pid}' is not an object")
        pids.append(str(pid))
        xyz.append(_vector(path, point.get("coordinates"), f"point '{pid}', 'coordinates'"))
    return OpenSfmReconstruction(path, cameras, np.array(ids, object), np.array(cams, object),
                                 np.array(rot, float), np.array(trans, float), np.array(pids, object),
                                 np.array(xyz, float).reshape(-1, 3), len(data))


def read_tracks(path: str | os.PathLike) -> OpenSfmTracks:
    """An OpenSfM ``tracks.csv`` (v0, v1 or v2; tab separated)."""
    path = os.fspath(path)
    text = read_text(path, "OpenSfM tracks file")
    lines = text.splitlines()
    first, version = 0, "v0"
    if lines and lines[0].startswith("OPENSFM_TRACKS_VERSION"):
        first, version = 1, lines[0].rsplit("_", 1)[-1].strip()
    if version not in TRACK_FIELDS:
        raise BlockError(path, f"unknown tracks version '{lines[0].strip()}' (known: "
                               f"{', '.join('OPENSFM_TRACKS_VERSION_' + v for v in TRACK_FIELDS)})", 1)
    names = TRACK_FIELDS[version]
    if text and not text.endswith("\n"):
        raise BlockError(path, "the last line has no line end: a truncated file?", len(lines))
    image, track, xy, numbers_ = [], [], [], []
    for number, line in enumerate(lines[first:], start=first + 1):
        if not line.strip():
            continue
        fields = line.split("\t")
        if len(fields) != len(names):
            raise BlockError(path, f"expected the {len(names)} tab-separated fields of tracks {version} "
                                   f"({', '.join(names)}), found {len(fields)}", number)
        values = []
        for name, field in zip(names[2:], fields[2:]):
            try:
                values.append(float(field))
            except ValueError:
                raise BlockError(path, f"'{field}' is not a number", number, name) from None
        x, y = values[1], values[2]
        if not (math.isfinite(x) and math.isfinite(y)):
            raise BlockError(path, "NaN or infinite feature coordinate", number)
        image.append(fields[0])
        track.append(fields[1])
        xy.append((x, y))
        numbers_.append(number)
    if not image:
        raise BlockError(path, "no feature in the tracks file")
    return OpenSfmTracks(path, np.array(image, object), np.array(track, object), np.array(xy, float),
                         np.array(numbers_, np.int64))
