"""OpenCV camera files (cv::FileStorage YAML, XML or JSON) and undistortion maps (NumPy .npz).

The camera file is written and read by OpenCV's own ``cv2.FileStorage`` (the format follows the extension:
``.yaml``/``.yml``, ``.xml``, ``.json``), so any id or text round-trips: ``camera_matrix`` and
``distortion_coefficients`` (OpenCV's pixel convention: the centre of the first pixel at (0, 0)), the image
size, the distortion model, how far the OpenCV model is from selfcal's, and, where the calibration has a
covariance, ``parameter_names`` with ``parameter_sigma`` (1 x n) and ``parameter_covariance`` (n x n) of
(fx, fy, cx, cy, distortion coefficients...) propagated through the fit.
"""
from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np

from ..errors import BlockError
from .atomic import atomic_write
from .images import read_image, write_image  # noqa: F401 - their home before issue 46

if TYPE_CHECKING:
    from ..calibration import OpenCVCamera
    from .calibration_files import ToolCalibration

__all__ = ["OPENCV_EXTENSIONS", "opencv_file_text", "write_opencv_file", "read_opencv_calibration",
           "write_undistortion_maps", "read_undistortion_maps", "read_image", "write_image"]

#: extension -> the FileStorage format it selects
OPENCV_EXTENSIONS = (".yaml", ".yml", ".xml", ".json")

#: OpenCV's distortion coefficients in order, as named in parameter_names
DISTORTION_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4")


def _extension(path) -> str:
    ext = os.path.splitext(os.fspath(path))[1].lower()
    if ext not in OPENCV_EXTENSIONS:
        raise BlockError(os.fspath(path), f"OpenCV FileStorage writes {', '.join(OPENCV_EXTENSIONS)}; the "
                                          f"extension selects the format")
    return ext


def opencv_file_text(camera: OpenCVCamera, ext: str = ".yaml", source: str = "", camera_id: str = "",
                     covariance: np.ndarray | None = None) -> str:
    """The FileStorage text of an :class:`selfcal.calibration.OpenCVCamera` (``ext`` selects the format)."""
    import cv2

    storage = cv2.FileStorage(ext, cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    storage.write("image_width", int(camera.width_px))
    storage.write("image_height", int(camera.height_px))
    storage.write("camera_matrix", np.asarray(camera.camera_matrix, float))
    storage.write("distortion_coefficients", np.asarray(camera.distortion, float).reshape(1, -1))
    storage.write("distortion_model", camera.model)
    storage.write("misfit_rms_px", float(camera.misfit_rms_px))
    storage.write("misfit_max_px", float(camera.misfit_max_px))
    if camera_id:
        storage.write("camera_id", camera_id)
    if source:
        storage.write("source", source)
    if covariance is not None:
        names = ("fx", "fy", "cx", "cy") + DISTORTION_NAMES[:len(camera.distortion)]
        covariance = np.asarray(covariance, float)
        storage.write("parameter_names", " ".join(names))
        storage.write("parameter_sigma", np.sqrt(np.clip(np.diag(covariance), 0, None)).reshape(1, -1))
        storage.write("parameter_covariance", covariance)
    return storage.releaseAndGetString()


def write_opencv_file(camera: OpenCVCamera, path: str | os.PathLike, source: str = "", camera_id: str = "",
                      covariance: np.ndarray | None = None) -> None:
    text = opencv_file_text(camera, _extension(path), source, camera_id, covariance)
    with atomic_write(path) as handle:
        handle.write(text)


def read_opencv_calibration(path: str | os.PathLike) -> ToolCalibration:
    """An OpenCV camera file (any FileStorage format) as a
    :class:`selfcal.io.calibration_files.ToolCalibration` (tool ``opencv``; values fx, fy, cx, cy and the
    distortion coefficients by OpenCV's names; the model from ``distortion_model`` or the count)."""
    import cv2

    from .calibration_files import ToolCalibration
    path = os.fspath(path)
    try:
        storage = cv2.FileStorage(path, cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        raise BlockError(path, f"OpenCV FileStorage cannot read it: {exc.err}") from None
    try:
        if not storage.isOpened():
            raise BlockError(path, "OpenCV FileStorage cannot read it")
        K = storage.getNode("camera_matrix").mat()
        dist = storage.getNode("distortion_coefficients").mat()
        width_node = storage.getNode("image_width")
        height_node = storage.getNode("image_height")
        if K is None or K.shape != (3, 3):
            raise BlockError(path, "camera_matrix (3 x 3) is missing")
        if width_node.empty() or height_node.empty():
            raise BlockError(path, "image_width and image_height are missing (the size the calibration is for)")
        width, height = int(width_node.real()), int(height_node.real())
        dist = np.zeros(0) if dist is None else dist.ravel().astype(float)
        model_node = storage.getNode("distortion_model")
        model = model_node.string() if not model_node.empty() and model_node.isString() else ""
        camera_id_node = storage.getNode("camera_id")
        camera_id = camera_id_node.string() if not camera_id_node.empty() else ""
    finally:
        storage.release()
    if not np.all(np.isfinite(K)) or not np.all(np.isfinite(dist)):
        raise BlockError(path, "camera_matrix or distortion_coefficients hold a value that is not finite")
    if abs(K[0, 1]) > 1e-9 * abs(K[0, 0]):
        raise BlockError(path, "camera_matrix has a skew term; selfcal reads OpenCV cameras without skew")
    by_count = {0: "opencv4", 4: "opencv4", 5: "plumb_bob", 8: "rational", 12: "thin_prism", 14: "thin_prism"}
    if len(dist) not in by_count or len(dist) == 14 and np.any(dist[12:]):
        raise BlockError(path, f"{len(dist)} distortion coefficients: OpenCV models with 4, 5, 8 or 12 are read")
    counts = {"opencv4": 4, "plumb_bob": 5, "rational": 8, "thin_prism": 12}
    if model not in counts or counts[model] != len(dist):
        model = by_count[len(dist)]
    dist = np.concatenate([dist, np.zeros(counts[model] - len(dist))])[:counts[model]]
    values = {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2])}
    values.update({name: float(v) for name, v in zip(DISTORTION_NAMES, dist)})
    return ToolCalibration("opencv", model, values, width, height, camera_id=camera_id)


def write_undistortion_maps(path: str | os.PathLike, map_x: np.ndarray, map_y: np.ndarray,
                            camera_matrix: np.ndarray, camera_id: str) -> None:
    """``map_x``, ``map_y`` (float32, height x width) for ``cv2.remap`` and the ideal camera matrix."""
    with atomic_write(path, mode="wb", encoding=None) as handle:
        np.savez_compressed(handle, map_x=map_x, map_y=map_y, camera_matrix=camera_matrix,
                            camera_id=np.array(camera_id))


def read_undistortion_maps(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    with np.load(path) as data:
        return data["map_x"], data["map_y"], data["camera_matrix"]
