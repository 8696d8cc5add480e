"""Read and write the block folder of DESIGN.md §3.

``read_block(folder)`` returns a validated :class:`~selfcal.block.Block`; every
defect raises :class:`~selfcal.errors.BlockError` with file, line and column.
Structural conditions that real blocks have (a tie point seen once, ...) are not
errors: :func:`selfcal.block.prune` removes them and records them.
"""
from __future__ import annotations

import itertools
import math
import os
import re
import tomllib
from typing import Any, Callable

import numpy as np
import tomli_w

from ..block import ROLES, AttitudeSamples, Block, Dropped, Ephemeris, Images, InitialAP, Observations, Points, prune
from ..errors import BlockError
from .atomic import atomic_folder, atomic_write
from ..sensors import SENSORS, sensor_of
from .sensor_files import SENSOR_FILE_READERS
from .text import read_text
from .table import NUM, OPT_NUM, STR, Column, read_table, read_table_chunks, write_table

__all__ = ["read_block", "write_block", "IMAGE_COLUMNS", "GNSS_SIGMA_COLUMNS", "IMU_SIGMA_COLUMNS", "POINT_COLUMNS", "OBSERVATION_COLUMNS", "EPHEMERIS_COLUMNS",
           "ATTITUDE_COLUMNS"]

IMAGE_COLUMNS = [
    Column("image_id"), Column("camera_id"), Column("strip_id"),
    Column("time_s", OPT_NUM),
    Column("X0", OPT_NUM), Column("Y0", OPT_NUM), Column("Z0", OPT_NUM),
    Column("omega_deg", OPT_NUM), Column("phi_deg", OPT_NUM), Column("kappa_deg", OPT_NUM),
    Column("sensor_file", STR, required=False),
] + [Column(name, OPT_NUM, required=False) for name in (
    "sigma_gnss_X_m", "sigma_gnss_Y_m", "sigma_gnss_Z_m", "sigma_imu_omega_deg", "sigma_imu_phi_deg",
    "sigma_imu_kappa_deg")]
#: optional images.csv columns: each image's own a-priori sigma of its GNSS / IMU observation (empty: block.toml's)
GNSS_SIGMA_COLUMNS = ("sigma_gnss_X_m", "sigma_gnss_Y_m", "sigma_gnss_Z_m")
IMU_SIGMA_COLUMNS = ("sigma_imu_omega_deg", "sigma_imu_phi_deg", "sigma_imu_kappa_deg")
POINT_COLUMNS = [
    Column("point_id"), Column("role"),
    Column("X", OPT_NUM), Column("Y", OPT_NUM), Column("Z", OPT_NUM),
    Column("sigma_xy_m", OPT_NUM), Column("sigma_z_m", OPT_NUM),
]
EPHEMERIS_COLUMNS = [
    Column("camera_id"), Column("time_s", NUM),
    Column("X", NUM), Column("Y", NUM), Column("Z", NUM), Column("VX", NUM), Column("VY", NUM), Column("VZ", NUM),
]
ATTITUDE_COLUMNS = [Column("camera_id"), Column("time_s", NUM),
                    Column("q1", NUM), Column("q2", NUM), Column("q3", NUM), Column("q4", NUM)]
OBSERVATION_COLUMNS = [
    Column("image_id"), Column("point_id"),
    Column("col_px", NUM), Column("row_px", NUM),
    Column("sigma_px", OPT_NUM, required=False),
]

# block.toml schema: key -> (type, required). Types: "str", "int", "pos" (> 0),
# "num", "nonneg" (>= 0), "count" (an integer >= 0), "bool", "vec3pos" (three numbers > 0), "vec3" (three finite
# numbers), "intlist", "pairlist".
_TOP_KEYS = {"name": ("str", False), "crs": ("str", False), "datum": ("str", False)}
#: a camera's block.toml keys come from its sensor (selfcal.sensors: Sensor.camera_type, Sensor.camera_keys)
_CAMERA_MODELS = {name: (sensor.camera_type, sensor.camera_keys) for name, sensor in SENSORS.items()
                  if sensor.selectable}
_SECTIONS = {
    "terrain": {"dem": ("str", False), "height_m": ("num", False)},
    "observations": {"image_sigma_px": ("pos", True)},
    "gnss": {"sigma_m": ("vec3pos", True), "lever_arm_m": ("vec3", False)},
    "imu": {"sigma_deg": ("vec3pos", True), "boresight_deg": ("vec3", False)},
}


def _key_line(text: str, section: str | None, key: str | None) -> int | None:
    """Line of ``key = ...`` inside ``[section]`` of a TOML text (best effort); ``key`` None: of the
    ``[section]`` header."""
    current = None
    for number, raw in enumerate(text.splitlines(), start=1):
        stripped = raw.split("#", 1)[0].strip()
        match = re.fullmatch(r"\[\s*([^\]]+?)\s*\]", stripped)
        if match:
            current = match.group(1).replace('"', "").replace(" ", "")
            if key is None and current == section:
                return number
            continue
        if key is not None and current == section and re.match(rf"{re.escape(key)}\s*=", stripped):
            return number
    return None


def _check_value(path, text, section, key, value, kind):
    where = f"{section}.{key}" if section else key
    def fail(reason):
        # the line is searched for only to report a defect (BAL's 49 cameras: 0.38 s for every key)
        raise BlockError(path, reason, _key_line(text, section, key), where)
    if kind == "str":
        if not isinstance(value, str):
            fail(f"must be a string, found {value!r}")
        return value
    if kind == "int":
        if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
            fail(f"must be a positive integer, found {value!r}")
        return value
    if kind == "count":
        if not isinstance(value, int) or isinstance(value, bool) or value < 0:
            fail(f"must be an integer 0 or more, found {value!r}")
        return value
    if kind == "bool":
        if not isinstance(value, bool):
            fail(f"must be true or false, found {value!r}")
        return value
    if kind == "intlist":
        if not isinstance(value, list) or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0
                                                  for v in value) or sorted(set(value)) != value:
            fail(f"must be a list of increasing positive column numbers, found {value!r}")
        return tuple(value)
    if kind == "pairlist":
        if not isinstance(value, list) or not all(
                isinstance(v, list) and len(v) == 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                            and math.isfinite(x) for x in v) for v in value):
            fail(f"must be a list of [along, across] pixel pairs, found {value!r}")
        return tuple((float(a), float(b)) for a, b in value)
    if kind in ("vec3pos", "vec3"):
        if (not isinstance(value, list) or len(value) != 3
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
            fail(f"must be a list of three numbers, found {value!r}")
        if kind == "vec3" and not all(math.isfinite(v) for v in value):
            fail(f"all three values must be finite, found {value!r}")
        if kind == "vec3pos" and not all(math.isfinite(v) and v > 0 for v in value):
            fail(f"all three values must be positive and finite, found {value!r}")
        return tuple(float(v) for v in value)
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        fail(f"must be a number, found {value!r}")
    value = float(value)
    if not math.isfinite(value):
        fail("must be finite")
    if kind == "pos" and value <= 0:
        fail(f"must be positive, found {value}")
    if kind == "nonneg" and value < 0:
        fail(f"must not be negative, found {value}")
    return value


def _check_table(path, text, section, table, schema):
    values = {}
    for key, value in table.items():
        if key not in schema:
            known = ", ".join(schema)
            raise BlockError(path, f"unknown key (known: {known})", _key_line(text, section, key),
                             f"{section}.{key}" if section else key)
        values[key] = _check_value(path, text, section, key, value, schema[key][0])
    for key, (_, required) in schema.items():
        if required and key not in table:
            raise BlockError(path, "missing key", _key_line(text, section, None),
                             f"{section}.{key}" if section else key)
    return values


def _initial_ap(path, text, section, table) -> InitialAP:
    """`[cameras.ID.initial_ap]`: ``model`` (an AP spec) and one number per coefficient, in pixels."""
    if not isinstance(table, dict):
        raise BlockError(path, "must be a table: model = \"brown\" and one number per coefficient",
                         _key_line(text, section.rsplit(".", 1)[0], "initial_ap"), section)
    if not isinstance(table.get("model"), str):
        raise BlockError(path, "missing key 'model' (the AP model of the initial values, e.g. \"brown\")",
                         _key_line(text, section, None), f"{section}.model")
    names = [k for k in table if k not in ("model", "sigma_px")]
    values = [_check_value(path, text, section, k, table[k], "num") for k in names]
    sigma = _check_value(path, text, section, "sigma_px", table["sigma_px"], "nonneg") if "sigma_px" in table \
        else None
    return InitialAP(table["model"], tuple(names), tuple(values), sigma)


def _read_settings(folder: str) -> dict:
    path = os.path.join(folder, "block.toml")
    if not os.path.isfile(path):
        raise BlockError(path, "file not found")
    text = read_text(path)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        match = re.search(r"line (\d+)", str(exc))
        raise BlockError(path, f"not valid TOML: {exc}", int(match.group(1)) if match else None) from None

    known = set(_TOP_KEYS) | {"cameras"} | set(_SECTIONS)
    for key in doc:
        if key not in known:
            line = _key_line(text, None, key) or _key_line(text, key, None)
            raise BlockError(path, f"unknown key (known: {', '.join(sorted(known))})", line, key)
    settings = _check_table(path, text, None, {k: v for k, v in doc.items() if k in _TOP_KEYS}, _TOP_KEYS)
    if settings.get("datum", "control") not in ("control", "free"):
        raise BlockError(path, f"datum must be \"control\" or \"free\", found {settings['datum']!r}",
                         _key_line(text, None, "datum"), "datum")
    cameras = doc.get("cameras")
    if not isinstance(cameras, dict) or not cameras:
        raise BlockError(path, "at least one [cameras.ID] table is required", None, "cameras")
    settings["cameras"] = {}
    for camera_id, table in cameras.items():
        section = f"cameras.{camera_id}"
        if not isinstance(table, dict):
            raise BlockError(path, "must be a table", _key_line(text, "cameras", camera_id), section)
        model = table.get("model")
        if model not in _CAMERA_MODELS:
            raise BlockError(path, f"camera model {model!r} is not supported (known: "
                                   f"{', '.join(repr(m) for m in _CAMERA_MODELS)})",
                             _key_line(text, section, "model"), f"{section}.model")
        cls, keys = _CAMERA_MODELS[model]
        sensor = SENSORS[model]
        initial = table.get("initial_ap") if "initial_ap" in sensor.camera_tables else None
        plain = {k: v for k, v in table.items() if not (k == "initial_ap" and initial is not None)}
        values = _check_table(path, text, section, plain, keys)
        values.pop("model")
        for key, reason in sensor.check_camera(values):
            raise BlockError(path, reason, _key_line(text, section, key.split(".")[0]), f"{section}.{key}")
        if initial is not None:
            values["initial_ap"] = _initial_ap(path, text, f"{section}.initial_ap", initial)
        settings["cameras"][camera_id] = cls(camera_id=camera_id, **values)
    if "observations" not in doc:
        raise BlockError(path, "missing table [observations] (image_sigma_px)", None, "observations")
    for section, schema in _SECTIONS.items():
        if section in doc:
            if not isinstance(doc[section], dict):
                raise BlockError(path, "must be a table", _key_line(text, None, section), section)
            settings[section] = _check_table(path, text, section, doc[section], schema)
    return settings


def _read_telemetry(folder: str, cameras: dict) -> tuple[Ephemeris, AttitudeSamples]:
    """ephemeris.csv and attitude.csv of the pushbroom cameras: known cameras, times increasing,
    enough samples per camera, unit quaternions."""
    pushbroom = [c for c, cam in cameras.items() if SENSORS[cam.model].needs_telemetry]
    out = []
    for name, columns in (("ephemeris.csv", EPHEMERIS_COLUMNS), ("attitude.csv", ATTITUDE_COLUMNS)):
        table = read_table(os.path.join(folder, name), columns)
        for value, line in zip(table["camera_id"], table.line):
            if value not in pushbroom:
                raise BlockError(table.path, f"unknown pushbroom camera '{value}' (block.toml has: "
                                             f"{', '.join(pushbroom)})", int(line), "camera_id")
        for camera in pushbroom:
            mine = np.flatnonzero(table["camera_id"] == camera)
            if mine.size < 8:
                raise BlockError(table.path, f"camera '{camera}' has {mine.size} samples; at least 8 are needed "
                                             f"for the polynomial fit", None, "camera_id")
            back = np.flatnonzero(np.diff(table["time_s"][mine]) <= 0)
            if back.size:
                raise BlockError(table.path, "times of a camera must increase", int(table.line[mine[back[0] + 1]]),
                                 "time_s")
        out.append(table)
    eph, att = out
    q = np.column_stack([att["q1"], att["q2"], att["q3"], att["q4"]])
    bad = np.flatnonzero(np.abs(np.linalg.norm(q, axis=1) - 1.0) > 1e-6)
    if bad.size:
        raise BlockError(att.path, f"not a unit quaternion (norm {np.linalg.norm(q[bad[0]]):.9f})",
                         int(att.line[bad[0]]), "q1")
    return (Ephemeris(eph["camera_id"], eph["time_s"], np.column_stack([eph["X"], eph["Y"], eph["Z"]]),
                      np.column_stack([eph["VX"], eph["VY"], eph["VZ"]])),
            AttitudeSamples(att["camera_id"], att["time_s"], q))


def _unique_ids(table, column: str) -> dict[str, int]:
    index: dict[str, int] = {}
    for i, (value, line) in enumerate(zip(table[column], table.line)):
        if value == "":
            raise BlockError(table.path, "empty id", int(line), column)
        if value in index:
            first = int(table.line[index[value]])
            raise BlockError(table.path, f"duplicated id '{value}' (first on line {first})", int(line), column)
        index[value] = i
    return index


def _read_images(folder: str, cameras: dict) -> tuple[Images, dict[str, int], dict]:
    table = read_table(os.path.join(folder, "images.csv"), IMAGE_COLUMNS)
    files = _sensor_files(folder, table, cameras)
    index = _unique_ids(table, "image_id")
    for value, line in zip(table["camera_id"], table.line):
        if value not in cameras:
            raise BlockError(table.path, f"unknown camera '{value}' (block.toml has: {', '.join(cameras)})",
                             int(line), "camera_id")
    angles = np.column_stack([table["omega_deg"], table["phi_deg"], table["kappa_deg"]])
    images = Images(
        image_id=table["image_id"],
        camera_id=table["camera_id"],
        strip_id=table["strip_id"],
        time_s=table["time_s"],
        position_m=np.column_stack([table["X0"], table["Y0"], table["Z0"]]),
        attitude_rad=np.radians(angles),
        line=table.line,
        gnss_sigma_m=_own_sigmas(table, GNSS_SIGMA_COLUMNS),
        imu_sigma_rad=_own_sigmas(table, IMU_SIGMA_COLUMNS, np.radians),
    )
    return images, index, files


def _own_sigmas(table, names, convert=lambda v: v) -> np.ndarray | None:
    """(n, 3) the images' own a-priori sigmas from the optional columns ``names`` (NaN where empty), or None
    when none of them is in the file; every given value must be positive."""
    if not any(name in table for name in names):
        return None
    values = np.column_stack([table[name] if name in table else np.full(len(table), np.nan) for name in names])
    bad = np.argwhere(~np.isnan(values) & (values <= 0))
    if bad.size:
        i, k = bad[0]
        raise BlockError(table.path, f"sigma must be positive, found {values[i, k]}", int(table.line[i]), names[k])
    return convert(values)


def _sensor_files(folder: str, table, cameras: dict) -> dict:
    """image id -> (path of its sensor_file, line) for the images whose camera model reads one; a missing or
    unexpected sensor_file is an error naming its line."""
    files = {}
    given = table["sensor_file"] if "sensor_file" in table else np.full(len(table.line), "", dtype=object)
    for image_id, camera_id, name, line in zip(table["image_id"], table["camera_id"], given, table.line):
        model = cameras[camera_id].model if camera_id in cameras else None
        if model in SENSOR_FILE_READERS:
            if not name:
                raise BlockError(table.path, f"a {model} image names its sensor description in column sensor_file",
                                 int(line), "sensor_file")
            path = name if os.path.isabs(name) else os.path.join(folder, name)
            if not os.path.isfile(path):
                raise BlockError(table.path, f"sensor file not found: {path}", int(line), "sensor_file")
            files[str(image_id)] = (path, int(line))
        elif name:
            raise BlockError(table.path, f"a {model} camera takes no sensor_file", int(line), "sensor_file")
    return files


def _read_points(folder: str) -> tuple[Points, dict[str, int]]:
    table = read_table(os.path.join(folder, "points.csv"), POINT_COLUMNS)
    index = _unique_ids(table, "point_id")
    xyz = np.column_stack([table["X"], table["Y"], table["Z"]])
    sxy, sz = table["sigma_xy_m"], table["sigma_z_m"]
    # the rows checked one by one from the first that any check could refuse (the same first defect, in line order)
    role_of = table["role"]
    missing = np.isnan(xyz)
    controlled = np.isin(role_of, ("gcp", "chk"))
    suspect = (~np.isin(role_of, list(ROLES)) | (controlled & missing.any(axis=1))
               | (missing.any(axis=1) & ~missing.all(axis=1))
               | ((role_of == "gcp") & (np.isnan(sxy) | np.isnan(sz)))
               | ~(np.isnan(sxy) | (sxy > 0)) | ~(np.isnan(sz) | (sz > 0)))
    first = int(np.argmax(suspect)) if suspect.any() else len(role_of)
    for i in range(first, len(role_of)):
        role, line = role_of[i], int(table.line[i])
        if role not in ROLES:
            raise BlockError(table.path, f"role must be one of {', '.join(ROLES)}, found '{role}'", line, "role")
        if role in ("gcp", "chk"):
            for k, name in enumerate("XYZ"):
                if math.isnan(xyz[i, k]):
                    raise BlockError(table.path, f"a {role} needs reference coordinates", line, name)
        if role == "tie" and np.isnan(xyz[i]).any() and not np.isnan(xyz[i]).all():
            raise BlockError(table.path, "give all of X, Y, Z for a tie point, or none", line, "X")
        if role == "gcp":
            for value, name in ((sxy[i], "sigma_xy_m"), (sz[i], "sigma_z_m")):
                if math.isnan(value) or value <= 0:
                    raise BlockError(table.path, "a gcp needs a positive a-priori sigma", line, name)
        for value, name in ((sxy[i], "sigma_xy_m"), (sz[i], "sigma_z_m")):
            if not math.isnan(value) and value <= 0:
                raise BlockError(table.path, f"sigma must be positive, found {value}", line, name)
    points = Points(
        point_id=table["point_id"],
        role=table["role"].astype(str).astype(object),
        xyz_m=xyz,
        sigma_m=np.column_stack([sxy, sxy, sz]),
        line=table.line,
    )
    return points, index


def _indices(chunk, image_index: dict, point_index: dict) -> tuple[np.ndarray, np.ndarray]:
    """The image and point index of every observation of a chunk of observations.csv; an id that images.csv or
    points.csv does not hold is a BlockError on the first row that has one."""
    n = len(chunk)
    img = np.fromiter(map(image_index.get, chunk["image_id"], itertools.repeat(-1, n)), np.int64, n)
    pt = np.fromiter(map(point_index.get, chunk["point_id"], itertools.repeat(-1, n)), np.int64, n)
    unknown = np.flatnonzero((img < 0) | (pt < 0))
    if unknown.size:
        k = unknown[0]
        name, what, where = ("image_id", "image", "images.csv") if img[k] < 0 else ("point_id", "point", "points.csv")
        raise BlockError(chunk.path, f"unknown {what} '{chunk[name][k]}' (not in {where})", int(chunk.line[k]), name)
    return img, pt


def _read_observations(folder, images, image_index, point_index, cameras, default_sigma):
    """observations.csv read a chunk at a time (:func:`~selfcal.io.table.read_table_chunks`): its ids become
    indices as each chunk comes, so that the file's texts are never all held."""
    path = os.path.join(folder, "observations.csv")
    parts: dict[str, list] = {"img": [], "pt": [], "col": [], "row": [], "sigma": [], "line": []}
    has_sigma = False
    for chunk in read_table_chunks(path, OBSERVATION_COLUMNS):
        img, pt = _indices(chunk, image_index, point_index)
        has_sigma = "sigma_px" in chunk
        for name, values in (("img", img), ("pt", pt), ("col", chunk["col_px"]), ("row", chunk["row_px"]),
                             ("sigma", chunk["sigma_px"] if has_sigma else np.zeros(0)), ("line", chunk.line)):
            parts[name].append(values)
    img, pt, col, row, given, line = (np.concatenate(parts.pop(name))
                                      for name in ("img", "pt", "col", "row", "sigma", "line"))
    n = len(line)
    point_ids: list | None = None

    def point_id(k: int) -> str:
        nonlocal point_ids
        if point_ids is None:
            point_ids = list(point_index)
        return point_ids[pt[k]]

    image_ids = images.image_id
    pair = img * (len(point_index) + 1) + pt
    ordered = np.sort(pair)
    if (ordered[1:] == ordered[:-1]).any():
        del ordered
        order = np.argsort(pair, kind="stable")
        dup = np.flatnonzero(pair[order][1:] == pair[order][:-1])
        first, second = order[dup[0]], order[dup[0] + 1]
        raise BlockError(path,
                         f"duplicated observation of point '{point_id(int(second))}' in image "
                         f"'{image_ids[img[second]]}' (first on line {line[first]})",
                         int(line[second]), "point_id")
    del pair, ordered
    width = np.array([cameras[c].width_px for c in images.camera_id], float)[img]
    height = np.array([cameras[c].height_px for c in images.camera_id], float)[img]
    outside_col = (col < -0.5) | (col > width + 0.5)
    outside = outside_col | (row < -0.5) | (row > height + 0.5)
    per_image = np.bincount(img, minlength=len(images.image_id))
    outside_per_image = np.bincount(img, weights=outside, minlength=len(images.image_id))
    unit_mistake = np.flatnonzero(outside_per_image > 0.5 * per_image)
    messages = []
    if unit_mistake.size:
        # most of an image's observations outside its frame: a unit mistake (mm, normalised), not blunders
        first_out = int(np.flatnonzero(outside & (img == unit_mistake[0]))[0])
        name, values, limit = ("col_px", col, width) if outside_col[first_out] else ("row_px", row, height)
        raise BlockError(path,
                         f"{values[first_out]:g} px is outside the image (0 .. {limit[first_out]:g} px), and so are "
                         f"{int(outside_per_image[unit_mistake[0]])} of the {per_image[unit_mistake[0]]} observations "
                         f"of image '{images.image_id[unit_mistake[0]]}': are the units pixels?",
                         int(line[first_out]), name)
    for k in np.flatnonzero(outside).tolist():
        messages.append(f"dropped observation of point '{point_id(k)}' in image '{image_ids[img[k]]}' "
                        f"(observations.csv line {line[k]}): ({col[k]:g}, {row[k]:g}) px is outside the "
                        f"{width[k]:g} x {height[k]:g} px frame")
    sigma = np.full(n, default_sigma)
    if has_sigma:
        bad = np.flatnonzero(~np.isnan(given) & (given <= 0))
        if bad.size:
            raise BlockError(path, f"sigma must be positive, found {given[bad[0]]}", int(line[bad[0]]), "sigma_px")
        sigma = np.where(np.isnan(given), default_sigma, given)
    keep = slice(None) if not outside.any() else ~outside          # no copies of every array for nothing
    observations = Observations(image_index=img[keep], point_index=pt[keep], pixel=np.column_stack([col, row])[keep],
                                sigma_px=sigma[keep], line=line[keep])
    return observations, Dropped(observations_outside_frame=len(messages), messages=tuple(messages))


def read_block(folder: str | os.PathLike, min_gcp: int = 3) -> Block:
    """Read, validate and prune a block folder.

    Raises
    ------
    BlockError
        For every defect of the input (file, line, column and reason).
    """
    folder = str(folder)
    if not os.path.isdir(folder):
        raise BlockError(folder, "block folder not found")
    settings = _read_settings(folder)
    cameras = settings["cameras"]
    images, image_index, files = _read_images(folder, cameras)
    points, point_index = _read_points(folder)
    image_sigma = settings["observations"]["image_sigma_px"]
    image_models = {image_id: SENSOR_FILE_READERS[cameras[camera_id].model](files[image_id][0])
                    for image_id, camera_id in zip(images.image_id, images.camera_id) if image_id in files}
    for camera_id, camera in list(cameras.items()):
        mine = [image_models[i] for i, c in zip(images.image_id, images.camera_id) if c == camera_id and i in image_models]
        try:
            cameras[camera_id] = SENSORS[camera.model].configure_camera(camera, mine)
        except ValueError as exc:
            raise BlockError(os.path.join(folder, "images.csv"), f"camera '{camera_id}': {exc}", None,
                             "sensor_file") from None
    observations, dropped = _read_observations(folder, images, image_index, point_index, cameras, image_sigma)
    gnss = settings.get("gnss", {}).get("sigma_m")
    imu = settings.get("imu", {}).get("sigma_deg")
    ephemeris = attitude = None
    sensors = {c.model: sensor_of(c) for c in cameras.values()}
    if len({s.object_frame for s in sensors.values()}) > 1:
        raise BlockError(os.path.join(folder, "block.toml"), "a block's cameras share one object frame: "
                         f"{', '.join(sensors)} do not mix", None, "cameras")
    if any(s.needs_telemetry for s in sensors.values()):
        ephemeris, attitude = _read_telemetry(folder, cameras)
        missing = np.flatnonzero(np.isnan(images.time_s))
        if missing.size:
            raise BlockError(os.path.join(folder, "images.csv"), "a pushbroom image needs the time of its first "
                             "line", int(images.line[missing[0]]), "time_s")
    _check_rolling(folder, images, cameras)
    terrain = settings.get("terrain", {})
    dem = terrain.get("dem")
    if dem is not None:
        dem = dem if os.path.isabs(dem) else os.path.join(folder, dem)
        if not os.path.isfile(dem):
            raise BlockError(os.path.join(folder, "block.toml"), f"DEM file not found: {dem}", None, "terrain.dem")
    if gnss is not None:
        _require_trajectory(folder, images, ("X0", "Y0", "Z0"), images.position_m, "gnss")
    if imu is not None:
        _require_trajectory(folder, images, ("omega_deg", "phi_deg", "kappa_deg"), images.attitude_rad, "imu")
    for section, own, names in (("gnss", images.gnss_sigma_m, GNSS_SIGMA_COLUMNS),
                                ("imu", images.imu_sigma_rad, IMU_SIGMA_COLUMNS)):
        if section not in settings and own is not None and np.isfinite(own).any():
            i, k = np.argwhere(np.isfinite(own))[0]
            raise BlockError(os.path.join(folder, "images.csv"), f"an image's own sigma of its {section.upper()} "
                             f"observation, but block.toml has no [{section}] (its observations and default sigma)",
                             int(images.line[i]), names[k])
    block = Block(
        name=settings.get("name", os.path.basename(os.path.abspath(folder))),
        crs=settings.get("crs", "local"),
        cameras=cameras,
        images=images,
        points=points,
        observations=observations,
        image_sigma_px=image_sigma,
        gnss_sigma_m=gnss,
        imu_sigma_deg=imu,
        gnss_lever_arm_m=settings.get("gnss", {}).get("lever_arm_m"),
        imu_boresight_deg=settings.get("imu", {}).get("boresight_deg"),
        datum=settings.get("datum", "control"),
        ephemeris=ephemeris,
        attitude=attitude,
        dem_path=dem,
        terrain_height_m=terrain.get("height_m"),
        image_models=image_models or None,
        image_files={k: v[0] for k, v in files.items()} or None,
        dropped=dropped,
        folder=folder,
    )
    # blocks of seed 001's sensors are used as read: mono restitution needs check points seen in one image
    if not any(s.sensor_models for s in sensors.values()):
        block = prune(block, min_points_per_image=min(s.min_points_per_image for s in sensors.values()), copy=False)
    n_gcp = int(np.sum(block.points.role == "gcp"))
    absolute = all(s.object_frame == "ECEF" for s in sensors.values())     # the images carry the datum
    if block.datum == "control" and not block.has_trajectory and not absolute and n_gcp < min_gcp:
        raise BlockError(os.path.join(folder, "points.csv"),
                         f"only {n_gcp} usable gcp (observed in at least one image); at least {min_gcp} "
                         f"are needed to fix the datum when block.toml has no [gnss] or [imu] (or set "
                         f"datum = \"free\" for a relative network)",
                         None, "role")
    if len(block.images) == 0:
        raise BlockError(os.path.join(folder, "observations.csv"),
                         "no image has enough observed points to be oriented")
    return block


def _check_rolling(folder, images, cameras) -> None:
    """The images of a rolling-shutter camera have times, and each of its strips two images with positions and
    times (their velocity comes from them, selfcal.sensors.rolling); with ``readout_rotation``, attitudes too."""
    path = os.path.join(folder, "images.csv")
    for camera_id, camera in cameras.items():
        if not getattr(camera, "rolling_shutter", False):
            continue
        mine = np.flatnonzero(images.camera_id == camera_id)
        untimed = mine[np.isnan(images.time_s[mine])]
        if untimed.size:
            raise BlockError(path, f"camera '{camera_id}' has shutter = \"rolling\": each of its images needs its "
                                   f"time (of its middle line), the velocity during the readout comes from the times "
                                   f"and positions of its strip", int(images.line[untimed[0]]), "time_s")
        needs = [("position", images.position_m, "X0")]
        if camera.readout_rotation:
            needs.append(("attitude", images.attitude_rad, "omega_deg"))
        for strip in dict.fromkeys(images.strip_id[mine].tolist()):
            members = mine[images.strip_id[mine] == strip]
            for what, values, column in needs:
                given = members[np.isfinite(values[members]).all(axis=1)]
                if len(np.unique(images.time_s[given])) < 2:
                    raise BlockError(path, f"camera '{camera_id}' has shutter = \"rolling\": strip '{strip}' needs "
                                           f"two images with a {what} at different times (the velocity during the "
                                           f"readout comes from them)", int(images.line[members[0]]), column)


def _require_trajectory(folder, images, names, values, section):
    missing = np.isnan(values).any(axis=1)
    if missing.all():
        raise BlockError(os.path.join(folder, "images.csv"),
                         f"block.toml has [{section}] but no image has {', '.join(names)}", None, names[0])


# ---------------------------------------------------------------------------- writing

def _toml_value(value):
    """Plain TOML data: NumPy scalars as Python numbers, tuples as lists."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, str):
        return value
    if isinstance(value, (tuple, list, np.ndarray)):
        return [_toml_value(v) for v in value]
    if isinstance(value, (int, np.integer)):
        return int(value)
    return float(value)


def block_toml_document(block: Block) -> dict:
    """block.toml as a dict, in the order of DESIGN.md §3."""
    doc: dict[str, Any] = {"name": block.name, "crs": block.crs}
    if block.datum != "control":
        doc["datum"] = block.datum
    cameras = doc["cameras"] = {}
    for camera in block.cameras.values():
        entry = cameras[camera.camera_id] = {"model": camera.model}
        for key in _CAMERA_MODELS[camera.model][1]:
            value = getattr(camera, key, None) if key != "model" else None
            if value is not None:
                entry[key] = _toml_value(value)
        initial = getattr(camera, "initial_ap", None)
        if initial is not None:
            entry["initial_ap"] = {"model": initial.spec,
                                   **({} if initial.sigma_px is None else {"sigma_px": _toml_value(initial.sigma_px)}),
                                   **{n: _toml_value(v) for n, v in zip(initial.names, initial.values_px)}}
    doc["observations"] = {"image_sigma_px": _toml_value(block.image_sigma_px)}
    if block.dem_path is not None or block.terrain_height_m is not None:
        terrain = doc["terrain"] = {}
        if block.dem_path is not None:
            terrain["dem"] = os.path.basename(block.dem_path)
        if block.terrain_height_m is not None:
            terrain["height_m"] = _toml_value(block.terrain_height_m)
    if block.gnss_sigma_m is not None:
        gnss = doc["gnss"] = {"sigma_m": _toml_value(block.gnss_sigma_m)}
        if block.gnss_lever_arm_m is not None:
            gnss["lever_arm_m"] = _toml_value(block.gnss_lever_arm_m)
    if block.imu_sigma_deg is not None:
        imu = doc["imu"] = {"sigma_deg": _toml_value(block.imu_sigma_deg)}
        if block.imu_boresight_deg is not None:
            imu["boresight_deg"] = _toml_value(block.imu_boresight_deg)
    return doc


def block_toml_text(block: Block) -> str:
    """block.toml written by tomli-w: any camera id or AP name (spaces, quotes, brackets) round-trips."""
    return tomli_w.dumps(block_toml_document(block))


def write_block(block: Block, folder: str | os.PathLike, source: str | None = None,
                say: Callable[[str], None] | None = None) -> None:
    """Write a block folder (atomically: the folder appears complete or not at all).

    With ``source`` (the file or folder an importer read), the folder is read back with :func:`read_block` before
    it appears: a block the reader would refuse is never written, and the BlockError names ``source``. ``say``
    receives a line as the reading back begins (a second or more for 300,000 observations).
    """
    with atomic_folder(folder) as tmp:
        _write_block_files(block, tmp, os.path.abspath(folder))
        if source is not None:
            if say is not None:
                say(f"reading {folder} back as selfcal adjust will ...")
            try:
                read_block(tmp)
            except BlockError as exc:
                name = os.path.relpath(exc.path, tmp) if os.path.abspath(exc.path).startswith(tmp) else exc.path
                where = name + (f", line {exc.line}" if exc.line is not None else "") + \
                    (f", column '{exc.column}'" if exc.column is not None else "")
                raise BlockError(source, f"cannot be imported: the block's {where} would be refused "
                                         f"({exc.reason})") from None


def _write_block_files(block: Block, tmp: str, folder: str) -> None:
    """The files of the block folder ``folder``, written into the existing folder ``tmp`` (sensor files are named
    relative to ``folder``)."""
    with atomic_write(os.path.join(tmp, "block.toml")) as handle:
        handle.write(block_toml_text(block))
    im = block.images
    deg = np.degrees(im.attitude_rad)
    with atomic_write(os.path.join(tmp, "images.csv")) as handle:
        columns = [im.image_id, im.camera_id, im.strip_id, im.time_s, im.position_m[:, 0], im.position_m[:, 1],
                   im.position_m[:, 2], deg[:, 0], deg[:, 1], deg[:, 2]]
        formats = ["", "", "", ".4f", ".6f", ".6f", ".6f", ".10f", ".10f", ".10f"]
        header = [c.name for c in IMAGE_COLUMNS][:len(columns)]
        if block.image_files:
            columns.append(np.array([os.path.relpath(block.image_files[i], folder) if i in block.image_files
                                     else "" for i in im.image_id], dtype=object))
            formats.append("")
            header.append("sensor_file")
        for own, names, convert in ((im.gnss_sigma_m, GNSS_SIGMA_COLUMNS, lambda v: v),
                                    (im.imu_sigma_rad, IMU_SIGMA_COLUMNS, np.degrees)):
            if own is not None and np.isfinite(own).any():
                columns += list(convert(own).T)
                formats += [".6f" if names is GNSS_SIGMA_COLUMNS else ".8f"] * 3
                header += list(names)
        write_table(handle, header, columns, formats)
    pt = block.points
    with atomic_write(os.path.join(tmp, "points.csv")) as handle:
        write_table(handle, [c.name for c in POINT_COLUMNS],
                    [pt.point_id, pt.role, pt.xyz_m[:, 0], pt.xyz_m[:, 1], pt.xyz_m[:, 2],
                     pt.sigma_m[:, 0], pt.sigma_m[:, 2]],
                    ["", "", ".6f", ".6f", ".6f", ".4f", ".4f"])
    ob = block.observations
    with atomic_write(os.path.join(tmp, "observations.csv")) as handle:
        columns = [im.image_id[ob.image_index], pt.point_id[ob.point_index], ob.pixel[:, 0], ob.pixel[:, 1]]
        header = ["image_id", "point_id", "col_px", "row_px"]
        formats = ["", "", ".6f", ".6f"]
        if np.any(ob.sigma_px != block.image_sigma_px):
            columns.append(ob.sigma_px)
            header.append("sigma_px")
            formats.append(".4f")
        write_table(handle, header, columns, formats)
    if block.ephemeris is not None:
        e = block.ephemeris
        with atomic_write(os.path.join(tmp, "ephemeris.csv")) as handle:
            write_table(handle, [c.name for c in EPHEMERIS_COLUMNS],
                        [e.camera_id, e.time_s, *e.position_m.T, *e.velocity_m_s.T],
                        ["", ".6f", ".4f", ".4f", ".4f", ".6f", ".6f", ".6f"])
    if block.attitude is not None:
        a = block.attitude
        with atomic_write(os.path.join(tmp, "attitude.csv")) as handle:
            write_table(handle, [c.name for c in ATTITUDE_COLUMNS], [a.camera_id, a.time_s, *a.quaternion.T],
                        ["", ".6f", ".15f", ".15f", ".15f", ".15f"])
