"""OpenCV camera files (cv::FileStorage YAML) and undistortion maps (NumPy .npz).

The YAML is what ``cv2.FileStorage(path, cv2.FILE_STORAGE_READ)`` reads and what
OpenCV's own calibration samples write: ``camera_matrix`` and
``distortion_coefficients`` as ``!!opencv-matrix``, plus the image size, the
distortion model and how far the OpenCV model is from selfcal's.
"""
from __future__ import annotations

import os

import numpy as np

from ..errors import BlockError
from .atomic import atomic_write

__all__ = ["opencv_yaml_text", "write_opencv_yaml", "write_undistortion_maps", "read_undistortion_maps",
           "read_image", "write_image"]


def _matrix(name: str, values: np.ndarray) -> list[str]:
    values = np.atleast_2d(np.asarray(values, float))
    data = ", ".join(repr(float(v)) for v in values.ravel())
    return [f"{name}: !!opencv-matrix", f"   rows: {values.shape[0]}", f"   cols: {values.shape[1]}",
            "   dt: d", f"   data: [ {data} ]"]


def opencv_yaml_text(camera, source: str = "") -> str:
    """The YAML text of an :class:`selfcal.calibration.OpenCVCamera`."""
    lines = ["%YAML:1.0", "---",
             f"image_width: {camera.width_px}", f"image_height: {camera.height_px}"]
    lines += _matrix("camera_matrix", camera.camera_matrix)
    lines += _matrix("distortion_coefficients", camera.distortion[None, :])
    lines += [f'distortion_model: "{camera.model}"',
              f"misfit_rms_px: {camera.misfit_rms_px!r}",
              f"misfit_max_px: {camera.misfit_max_px!r}"]
    if source:
        lines.append(f'source: "{source}"')
    return "\n".join(lines) + "\n"


def write_opencv_yaml(camera, path: str | os.PathLike, source: str = "") -> None:
    with atomic_write(path) as handle:
        handle.write(opencv_yaml_text(camera, source))


def write_undistortion_maps(path: str | os.PathLike, map_x: np.ndarray, map_y: np.ndarray,
                            camera_matrix: np.ndarray, camera_id: str) -> None:
    """``map_x``, ``map_y`` (float32, height x width) for ``cv2.remap`` and the ideal camera matrix."""
    with atomic_write(path, mode="wb", encoding=None) as handle:
        np.savez_compressed(handle, map_x=map_x, map_y=map_y, camera_matrix=camera_matrix,
                            camera_id=np.array(camera_id))


def read_undistortion_maps(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    with np.load(path) as data:
        return data["map_x"], data["map_y"], data["camera_matrix"]


def read_image(path: str | os.PathLike) -> np.ndarray:
    """An image file as OpenCV reads it (any depth and channels); unreadable: BlockError."""
    import cv2

    image = cv2.imread(os.fspath(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise BlockError(os.fspath(path), "cannot be read as an image")
    return image


def write_image(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an image in the format its extension names (callers write into an atomic folder)."""
    import cv2

    if not cv2.imwrite(os.fspath(path), image):
        raise BlockError(os.fspath(path), "OpenCV cannot write this file (unknown extension?)")
