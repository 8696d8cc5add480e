"""COLMAP sparse models (text and binary) as plain data.

Reads ``cameras``, ``images`` and ``points3D`` of a COLMAP sparse model,
``.txt`` or ``.bin`` (format of COLMAP's ``src/colmap/scene/reconstruction_io``),
and writes them in the binary format (:func:`write_colmap_bin`), with the
``stereo/`` configuration files of a dense workspace (:func:`write_stereo_config`).
Pixel convention: COLMAP puts the upper-left corner of the first pixel at
(0, 0) (the centre of the first pixel is (0.5, 0.5)), the same as selfcal's,
so image coordinates are taken as they are.

COLMAP poses map world to camera, x_cam = R(q) x_world + t, with the camera
looking along +z, x right and y down; :func:`selfcal.convert.block_from_colmap`
turns them into selfcal's exterior orientation (perspective centre and
M = R3(kappa) R2(phi) R1(omega) with the camera looking along -z, y up), and
:func:`selfcal.convert.colmap_workspace` back (R = diag(1, -1, -1) M,
t = -R C).
"""
from __future__ import annotations

import math
import os
import struct
from dataclasses import dataclass

import numpy as np

from ..errors import BlockError
from .text import read_text
from .atomic import atomic_write

__all__ = ["ColmapCamera", "ColmapModel", "read_colmap", "write_cameras_txt", "write_colmap_bin",
           "write_stereo_config", "CAMERA_MODELS", "PERSPECTIVE_MODELS"]

#: model id -> (name, parameter names)
CAMERA_MODELS = {
    0: ("SIMPLE_PINHOLE", ("f", "cx", "cy")),
    1: ("PINHOLE", ("fx", "fy", "cx", "cy")),
    2: ("SIMPLE_RADIAL", ("f", "cx", "cy", "k")),
    3: ("RADIAL", ("f", "cx", "cy", "k1", "k2")),
    4: ("OPENCV", ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")),
    5: ("OPENCV_FISHEYE", ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")),
    6: ("FULL_OPENCV", ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")),
    7: ("FOV", ("fx", "fy", "cx", "cy", "omega")),
    8: ("SIMPLE_RADIAL_FISHEYE", ("f", "cx", "cy", "k")),
    9: ("RADIAL_FISHEYE", ("f", "cx", "cy", "k1", "k2")),
    10: ("THIN_PRISM_FISHEYE", ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "sx1", "sy1")),
}
MODEL_IDS = {name: (i, params) for i, (name, params) in CAMERA_MODELS.items()}
#: models whose projection is a perspective (pinhole) one with polynomial distortion
PERSPECTIVE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV")


@dataclass(frozen=True)
class ColmapCamera:
    camera_id: int
    model: str
    width: int
    height: int
    params: dict[str, float]


@dataclass
class ColmapModel:
    """A sparse model; observations are the 2-D points that see a 3-D point."""

    cameras: dict[int, ColmapCamera]
    image_ids: np.ndarray           # (n,)
    image_names: np.ndarray         # (n,) str
    image_camera: np.ndarray        # (n,) camera id
    qvec: np.ndarray                # (n, 4) w, x, y, z
    tvec: np.ndarray                # (n, 3)
    obs_image: np.ndarray           # (m,) image id
    obs_xy: np.ndarray              # (m, 2) pixel coordinates
    obs_point: np.ndarray           # (m,) point3D id
    point_ids: np.ndarray           # (k,)
    point_xyz: np.ndarray           # (k, 3)
    point_error: np.ndarray         # (k,) mean reprojection error (px)
    point_rgb: np.ndarray | None = None     # (k, 3) uint8 colour (not read; grey where not given)


def _find(folder: str, stem: str) -> tuple[str, str]:
    for ext in (".bin", ".txt"):
        path = os.path.join(folder, stem + ext)
        if os.path.isfile(path):
            return path, ext
    raise BlockError(os.path.join(folder, stem + ".bin"), f"file not found (neither {stem}.bin nor {stem}.txt)")


def _data_lines(path: str):
    for number, line in enumerate(read_text(path).splitlines(), start=1):
        text = line.strip()
        if text and not text.startswith("#"):
            yield number, text


def _numbers(path, number, fields, kinds):
    try:
        values = [kind(f) for kind, f in zip(kinds, fields)]
    except ValueError:
        raise BlockError(path, f"malformed line: expected numbers, found '{' '.join(fields)[:80]}'", number) from None
    if not all(math.isfinite(v) and abs(v) < 2**63 for v in values):
        raise BlockError(path, f"NaN or infinite number in '{' '.join(fields)[:80]}'", number)
    return values


def _cameras_txt(path):
    cams = {}
    for number, text in _data_lines(path):
        fields = text.split()
        if len(fields) < 4:
            raise BlockError(path, "expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]", number)
        model = fields[1]
        if model not in MODEL_IDS:
            raise BlockError(path, f"unknown camera model '{model}'", number, "MODEL")
        names = MODEL_IDS[model][1]
        if len(fields) != 4 + len(names):
            raise BlockError(path, f"{model} has {len(names)} parameters, found {len(fields) - 4}", number)
        cid, width, height = _numbers(path, number, [fields[0], fields[2], fields[3]], [int, int, int])
        params = _numbers(path, number, fields[4:], [float] * len(names))
        cams[cid] = ColmapCamera(cid, model, width, height, dict(zip(names, params)))
    return cams


def _images_txt(path):
    """Two lines per image (the second, the 2-D points, may be empty); comments start with #."""
    ids, names, cams, q, t = [], [], [], [], []
    oi, oxy, op = [], [], []
    raw = list(enumerate(read_text(path).split("\n"), start=1))
    raw = [(n, line) for n, line in raw if not line.lstrip().startswith("#")]
    k = 0
    while k < len(raw):
        number, text = raw[k]
        if not text.strip():
            k += 1
            continue
        fields = text.split()
        if len(fields) < 10:
            raise BlockError(path, "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME", number)
        values = _numbers(path, number, fields[:9], [int] + [float] * 7 + [int])
        ids.append(values[0])
        q.append(values[1:5])
        t.append(values[5:8])
        cams.append(values[8])
        names.append(" ".join(fields[9:]))
        points_line = raw[k + 1] if k + 1 < len(raw) else (number + 1, "")
        k += 2
        fields = points_line[1].split()
        if len(fields) % 3:
            raise BlockError(path, "malformed POINTS2D line (expected X Y POINT3D_ID triples)", points_line[0])
        if not fields:
            continue
        arr = np.array(fields, dtype=object).reshape(-1, 3)
        try:
            xy = arr[:, :2].astype(float)
            pid = arr[:, 2].astype(np.int64)
        except (ValueError, OverflowError):
            raise BlockError(path, "malformed POINTS2D line (expected X Y POINT3D_ID triples)",
                             points_line[0]) from None
        if not np.all(np.isfinite(xy)):
            raise BlockError(path, "NaN or infinite image coordinate in the POINTS2D line", points_line[0])
        keep = pid != -1
        oi.append(np.full(int(keep.sum()), values[0]))
        oxy.append(xy[keep])
        op.append(pid[keep])
    return (np.array(ids), np.array(names, dtype=object), np.array(cams), np.array(q, float).reshape(-1, 4),
            np.array(t, float).reshape(-1, 3),
            np.concatenate(oi) if oi else np.zeros(0, np.int64),
            np.concatenate(oxy) if oxy else np.zeros((0, 2)),
            np.concatenate(op) if op else np.zeros(0, np.int64))


def _points_txt(path):
    ids, xyz, err = [], [], []
    for number, text in _data_lines(path):
        fields = text.split()
        if len(fields) < 8:
            raise BlockError(path, "expected POINT3D_ID X Y Z R G B ERROR TRACK[]", number)
        values = _numbers(path, number, fields[:8], [int, float, float, float, int, int, int, float])
        ids.append(values[0])
        xyz.append(values[1:4])
        err.append(values[7])
    return np.array(ids, np.int64), np.array(xyz, float).reshape(-1, 3), np.array(err, float)


class _Reader:
    def __init__(self, path):
        self.path = path
        with open(path, "rb") as handle:
            self.data = handle.read()
        self.pos = 0

    def read(self, fmt):
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise BlockError(self.path, f"truncated binary file at byte {self.pos}")
        values = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return values

    def count(self, record_bytes: int, what: str) -> int:
        """A uint64 count of records of at least ``record_bytes`` each, checked against the bytes left."""
        at = self.pos
        (n,) = self.read("Q")
        if n * record_bytes > len(self.data) - self.pos:
            raise BlockError(self.path, f"{n} {what} announced at byte {at}, but only {len(self.data) - self.pos} "
                                        f"bytes follow: truncated or not a COLMAP file")
        return n

    def array(self, dtype, count):
        dtype = np.dtype(dtype).newbyteorder("<")
        size = dtype.itemsize * count
        if self.pos + size > len(self.data):
            raise BlockError(self.path, f"truncated binary file at byte {self.pos}")
        out = np.frombuffer(self.data, dtype=dtype, count=count, offset=self.pos)
        self.pos += size
        return out

    def string(self):
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise BlockError(self.path, f"truncated binary file at byte {self.pos}")
        try:
            text = self.data[self.pos:end].decode("utf-8")
        except UnicodeDecodeError:
            raise BlockError(self.path, f"the image name at byte {self.pos} is not UTF-8 text") from None
        self.pos = end + 1
        return text


def _cameras_bin(path):
    r = _Reader(path)
    n = r.count(24, "cameras")
    cams = {}
    for _ in range(n):
        cid, model_id, width, height = r.read("iiQQ")
        if model_id not in CAMERA_MODELS:
            raise BlockError(path, f"unknown camera model id {model_id} (camera {cid})")
        name, names = CAMERA_MODELS[model_id]
        params = r.read("d" * len(names))
        cams[cid] = ColmapCamera(cid, name, int(width), int(height), dict(zip(names, params)))
    return cams


def _images_bin(path):
    r = _Reader(path)
    n = r.count(73, "images")
    ids, names, cams, q, t = [], [], [], [], []
    oi, oxy, op = [], [], []
    record = np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<i8")])
    for _ in range(n):
        values = r.read("I7dI")
        ids.append(values[0])
        q.append(values[1:5])
        t.append(values[5:8])
        cams.append(values[8])
        names.append(r.string())
        pts = r.array(record, r.count(24, "2-D points"))
        keep = pts["id"] != -1
        oi.append(np.full(int(keep.sum()), values[0]))
        oxy.append(np.column_stack([pts["x"][keep], pts["y"][keep]]))
        op.append(pts["id"][keep].astype(np.int64))
    return (np.array(ids), np.array(names, dtype=object), np.array(cams), np.array(q, float).reshape(-1, 4),
            np.array(t, float).reshape(-1, 3),
            np.concatenate(oi) if oi else np.zeros(0, np.int64),
            np.concatenate(oxy) if oxy else np.zeros((0, 2)),
            np.concatenate(op) if op else np.zeros(0, np.int64))


def _points_bin(path):
    r = _Reader(path)
    n = r.count(43, "3-D points")
    ids, xyz, err = np.empty(n, np.int64), np.empty((n, 3)), np.empty(n)
    for k in range(n):
        at = r.pos
        pid, x, y, z, _, _, _, e, length = r.read("Q3d3BdQ")
        if pid >= 2**63:
            raise BlockError(path, f"3-D point {k + 1} (byte {at}): id {pid} is beyond COLMAP's ids (< 2^63)")
        ids[k], xyz[k], err[k] = pid, (x, y, z), e
        r.pos += 8 * length
    return ids, xyz, err


def read_colmap(folder: str | os.PathLike) -> ColmapModel:
    """Read a COLMAP sparse model folder (binary preferred when both exist).

    Observations of points missing from points3D are an error (a corrupt model).
    """
    folder = str(folder)
    if not os.path.isdir(folder):
        raise BlockError(folder, "COLMAP model folder not found")
    cam_path, _ = _find(folder, "cameras")
    img_path, _ = _find(folder, "images")
    pts_path, _ = _find(folder, "points3D")
    cameras = _cameras_txt(cam_path) if cam_path.endswith(".txt") else _cameras_bin(cam_path)
    images = _images_txt(img_path) if img_path.endswith(".txt") else _images_bin(img_path)
    points = _points_txt(pts_path) if pts_path.endswith(".txt") else _points_bin(pts_path)
    ids, names, cams, q, t, oi, oxy, op = images
    for path, values, what in ((cam_path, [v for c in cameras.values() for v in c.params.values()], "camera parameter"),
                               (img_path, np.concatenate([q.ravel(), t.ravel(), oxy.ravel()]), "image pose or 2-D point"),
                               (pts_path, np.concatenate([points[1].ravel(), points[2].ravel()]), "3-D point")):
        values = np.asarray(values, float)
        if not np.all(np.isfinite(values)):
            raise BlockError(path, f"NaN or infinite {what} (value {int(np.flatnonzero(~np.isfinite(values))[0])} "
                                   f"of its kind in the file)")
    for cid in set(cams.tolist()) - set(cameras):
        raise BlockError(img_path, f"image refers to camera {cid}, which {os.path.basename(cam_path)} lacks")
    missing = np.setdiff1d(np.unique(op), points[0])
    if missing.size:
        raise BlockError(img_path, f"{missing.size} observed 3-D point id(s) are not in "
                                   f"{os.path.basename(pts_path)}, e.g. {missing[0]}")
    # canonical order (text and binary files list images in different orders)
    order = np.argsort(ids, kind="stable")
    obs_order = np.argsort(oi, kind="stable")
    pids, xyz, err = points
    porder = np.argsort(pids, kind="stable")
    return ColmapModel(cameras, ids[order], names[order], cams[order], q[order], t[order],
                       oi[obs_order], oxy[obs_order], op[obs_order], pids[porder], xyz[porder], err[porder])


def write_cameras_txt(path: str | os.PathLike, cameras: list[tuple[int, str, int, int, list[float]]],
                      warnings: tuple[str, ...] | list[str] = ()) -> None:
    """COLMAP's cameras.txt: one ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`` line per camera (``warnings`` as comment
    lines after the header)."""
    names = {name: params for name, params in CAMERA_MODELS.values()}
    lines = ["# Camera list with one line of data per camera:",
             "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
             f"# Number of cameras: {len(cameras)}"] + [f"# selfcal warning: {w}" for w in warnings]
    for camera_id, model, width, height, params in cameras:
        if len(params) != len(names[model]):
            raise ValueError(f"COLMAP's {model} has {len(names[model])} parameters, given {len(params)}")
        lines.append(" ".join([str(camera_id), model, str(width), str(height)] + [repr(float(p)) for p in params]))
    with atomic_write(path) as handle:
        handle.write("\n".join(lines) + "\n")


#: grey, the colour of a written 3-D point whose colour is not given
GREY = 128


def write_colmap_bin(folder: str | os.PathLike, model: ColmapModel) -> None:
    """Write ``cameras.bin``, ``images.bin`` and ``points3D.bin`` of ``model`` into ``folder`` (each atomically).

    The binary layout of COLMAP's ``reconstruction_io`` (little-endian; the reader above reads it back):
    cameras ``uint64 n`` then ``int32 id, int32 model, uint64 width, uint64 height, double params[]``;
    images ``uint64 n`` then ``uint32 id, double qw qx qy qz tx ty tz, uint32 camera, name NUL, uint64 n2d,
    (double x, double y, int64 point3D_id)[]``; points ``uint64 n`` then ``uint64 id, double xyz[3],
    uint8 rgb[3], double error, uint64 track length, (int32 image_id, int32 point2D_idx)[]``.
    An image's 2-D points are its observations in the order of ``obs_*`` (index = POINT2D_IDX); each point's
    track lists them in the same order. Pixel coordinates are written as given (COLMAP's convention:
    the upper-left corner of the first pixel at (0, 0)).
    """
    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    cams = [struct.pack("<Q", len(model.cameras))]
    for cid in sorted(model.cameras):
        cam = model.cameras[cid]
        model_id, names = MODEL_IDS[cam.model]
        cams.append(struct.pack("<iiQQ", cid, model_id, cam.width, cam.height)
                    + struct.pack("<" + "d" * len(names), *(float(cam.params[n]) for n in names)))
    with atomic_write(os.path.join(folder, "cameras.bin"), "wb", encoding=None) as handle:
        handle.write(b"".join(cams))

    obs_image = np.asarray(model.obs_image, np.int64)
    obs_point = np.asarray(model.obs_point, np.int64)
    order = np.argsort(obs_image, kind="stable")
    index_in_image = np.empty(len(obs_image), np.int64)
    record = np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<i8")])
    images = [struct.pack("<Q", len(model.image_ids))]
    for k, image_id in enumerate(model.image_ids):
        lo, hi = np.searchsorted(obs_image[order], [image_id, image_id + 1])
        rows = order[lo:hi]
        index_in_image[rows] = np.arange(len(rows))
        points2d = np.empty(len(rows), record)
        points2d["x"], points2d["y"] = model.obs_xy[rows, 0], model.obs_xy[rows, 1]
        points2d["id"] = obs_point[rows]
        images.append(struct.pack("<I7dI", int(image_id), *map(float, model.qvec[k]), *map(float, model.tvec[k]),
                                  int(model.image_camera[k]))
                      + str(model.image_names[k]).encode("utf-8") + b"\0"
                      + struct.pack("<Q", len(rows)) + points2d.tobytes())
    with atomic_write(os.path.join(folder, "images.bin"), "wb", encoding=None) as handle:
        handle.write(b"".join(images))

    track = np.dtype([("image", "<i4"), ("index", "<i4")])
    by_point = np.argsort(obs_point, kind="stable")
    starts = np.searchsorted(obs_point[by_point], model.point_ids)
    ends = np.searchsorted(obs_point[by_point], model.point_ids, side="right")
    rgb = (np.full((len(model.point_ids), 3), GREY, np.uint8) if model.point_rgb is None
           else np.asarray(model.point_rgb, np.uint8))
    points = [struct.pack("<Q", len(model.point_ids))]
    for k, point_id in enumerate(model.point_ids):
        rows = by_point[starts[k]:ends[k]]
        entries = np.empty(len(rows), track)
        entries["image"], entries["index"] = obs_image[rows], index_in_image[rows]
        points.append(struct.pack("<Q3d3BdQ", int(point_id), *map(float, model.point_xyz[k]), *map(int, rgb[k]),
                                  float(model.point_error[k]), len(rows)) + entries.tobytes())
    with atomic_write(os.path.join(folder, "points3D.bin"), "wb", encoding=None) as handle:
        handle.write(b"".join(points))


def write_stereo_config(folder: str | os.PathLike, image_names, source_images: str = "__auto__, 20") -> None:
    """The ``stereo/`` folder of a COLMAP dense workspace, as ``colmap image_undistorter`` writes it:
    ``patch-match.cfg`` (each image name, then its source images: ``__auto__, 20`` lets
    ``patch_match_stereo`` pick the 20 that share the most 3-D points), ``fusion.cfg`` (the image names)
    and the empty ``depth_maps/``, ``normal_maps/``, ``consistency_graphs/`` that the dense steps fill."""
    folder = os.fspath(folder)
    for sub in ("depth_maps", "normal_maps", "consistency_graphs"):
        os.makedirs(os.path.join(folder, sub), exist_ok=True)
    with atomic_write(os.path.join(folder, "patch-match.cfg")) as handle:
        handle.write("".join(f"{name}\n{source_images}\n" for name in image_names))
    with atomic_write(os.path.join(folder, "fusion.cfg")) as handle:
        handle.write("".join(f"{name}\n" for name in image_names))
