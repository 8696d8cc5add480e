"""A results folder's camera.json, checked before its calibrations are rebuilt (export, undistort).

Every value :meth:`selfcal.calibration.Calibration.from_camera_json` uses is checked here: the file is an object
with ``cameras``, each camera an object with a ``model``; a frame camera's image size (whole pixels), pixel
size and focal length (positive), principal point (finite), its ``ap`` (``spec`` and ``coefficients``, each with a
finite ``value_px`` and an ``active`` flag) and, where given, its ``covariance`` (parameter names and a square
matrix of as many finite numbers). A defect is a BlockError naming the file and the key
(``cameras.ID.focal_mm.value``) and saying what was expected; NaN and infinity are refused with their line.
"""
from __future__ import annotations

import os

from ..errors import BlockError
from .jsonfields import array, found, integer, mapping, need, number, string
from .text import read_json

__all__ = ["read_camera_json", "frame_camera_entries"]


def read_camera_json(folder: str | os.PathLike) -> dict:
    """camera.json of a results folder: ``{"cameras": {id: {"model": ..., ...}}}``; missing or malformed:
    BlockError."""
    folder = os.fspath(folder)
    if not os.path.isdir(folder):
        raise BlockError(folder, "no such results folder")
    path = os.path.join(folder, "camera.json")
    if not os.path.isfile(path):
        raise BlockError(path, "missing: is this a results folder written by 'selfcal adjust'?")
    data = mapping(path, read_json(path, "camera.json"), "the file")
    cameras = mapping(path, need(path, data, "cameras"), "cameras")
    for camera_id, entry in cameras.items():
        key = f"cameras.{camera_id}"
        string(path, need(path, mapping(path, entry, key), "model", key), f"{key}.model")
    return data


def _frame_entry(path: str, key: str, entry: dict) -> None:
    def value(name: str) -> object:
        return need(path, entry, name, key)

    for name in ("width_px", "height_px"):
        integer(path, value(name), f"{key}.{name}")
    number(path, value("pixel_size_mm"), f"{key}.pixel_size_mm", positive=True)
    for name, positive in (("focal_mm", True), ("x0_mm", False), ("y0_mm", False)):
        where = f"{key}.{name}"
        number(path, need(path, mapping(path, value(name), where), "value", where), f"{where}.value", positive)
    ap_key = f"{key}.ap"
    ap = mapping(path, value("ap"), ap_key)
    string(path, need(path, ap, "spec", ap_key), f"{ap_key}.spec")
    coefficients = need(path, ap, "coefficients", ap_key)
    if not isinstance(coefficients, list):
        raise BlockError(path, f"'{ap_key}.coefficients' must be a list, found {found(coefficients)}")
    for k, coefficient in enumerate(coefficients):
        where = f"{ap_key}.coefficients[{k}]"
        coefficient = mapping(path, coefficient, where)
        number(path, need(path, coefficient, "value_px", where), f"{where}.value_px")
        for flag in ("active", "held"):
            if flag in coefficient and not isinstance(coefficient[flag], bool):
                raise BlockError(path, f"'{where}.{flag}' must be true or false, found {found(coefficient[flag])}")
        if "name" in coefficient:
            string(path, coefficient["name"], f"{where}.name")
        if "active" not in coefficient:
            raise BlockError(path, f"missing key '{where}.active'")
    covariance = entry.get("covariance")
    if covariance:
        where = f"{key}.covariance"
        covariance = mapping(path, covariance, where)
        names = need(path, covariance, "parameters", where)
        if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
            raise BlockError(path, f"'{where}.parameters' must be a list of parameter names, found {found(names)}")
        array(path, need(path, covariance, "matrix", where), f"{where}.matrix", (len(names), len(names)))


def frame_camera_entries(folder: str | os.PathLike) -> dict[str, dict]:
    """The frame cameras of a results folder's camera.json by id, every value they need checked."""
    data = read_camera_json(folder)
    path = os.path.join(os.fspath(folder), "camera.json")
    out = {}
    for camera_id, entry in data["cameras"].items():
        if entry["model"] == "frame":
            _frame_entry(path, f"cameras.{camera_id}", entry)
            out[camera_id] = entry
    return out
