"""OpenCV camera files (cv::FileStorage YAML, XML or JSON) and undistortion maps (NumPy .npz).

The camera file is written by OpenCV's own ``cv2.FileStorage`` (the format follows the extension:
``.yaml``/``.yml``, ``.xml``, ``.json``) and read by :mod:`selfcal.io.opencv_storage`, which checks every value
before it is used (``cv2.FileStorage`` aborts the process on some broken files), so any id or text round-trips: ``camera_matrix`` and
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
#: no camera has a side of more pixels than this; a larger image_width is a broken file
MAX_IMAGE_SIDE_PX = 1_000_000


def _extension(path) -> str:
    ext = os.path.splitext(os.fspath(path))[1].lower()
    if ext not in OPENCV_EXTENSIONS:
        raise BlockError(os.fspath(path), f"OpenCV FileStorage writes {', '.join(OPENCV_EXTENSIONS)}; the "
                                          f"extension selects the format")
    return ext


def opencv_file_text(camera: OpenCVCamera, ext: str = ".yaml", source: str = "", camera_id: str = "",
                     covariance: np.ndarray | None = None, warning: str = "") -> str:
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
    if warning:
        storage.write("selfcal_warning", warning)
    if covariance is not None:
        names = ("fx", "fy", "cx", "cy") + DISTORTION_NAMES[:len(camera.distortion)]
        covariance = np.asarray(covariance, float)
        storage.write("parameter_names", " ".join(names))
        storage.write("parameter_sigma", np.sqrt(np.clip(np.diag(covariance), 0, None)).reshape(1, -1))
        storage.write("parameter_covariance", covariance)
    return storage.releaseAndGetString()


def write_opencv_file(camera: OpenCVCamera, path: str | os.PathLike, source: str = "", camera_id: str = "",
                      covariance: np.ndarray | None = None, warning: str = "") -> None:
    text = opencv_file_text(camera, _extension(path), source, camera_id, covariance, warning)
    with atomic_write(path) as handle:
        handle.write(text)


def _whole_positive(path: str, nodes: dict, key: str) -> int:
    node = nodes.get(key)
    if node is None:
        raise BlockError(path, f"{key} is missing (image_width and image_height: the size the calibration is for)",
                         column=key)
    value = node.value
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if not isinstance(value, int) or not 0 < value <= MAX_IMAGE_SIDE_PX:
        raise BlockError(path, f"{key} must be a whole number of pixels 1..{MAX_IMAGE_SIDE_PX}, found {value!r}"[:200],
                         node.line, key)
    return value


def _string(path: str, nodes: dict, key: str) -> str:
    node = nodes.get(key)
    if node is None:
        return ""
    if not isinstance(node.value, (str, int, float)) or isinstance(node.value, bool):
        raise BlockError(path, f"{key} must be a text, found a map or a list", node.line, key)
    return str(node.value)


def read_opencv_calibration(path: str | os.PathLike) -> ToolCalibration:
    """An OpenCV camera file (any FileStorage format) as a
    :class:`selfcal.io.calibration_files.ToolCalibration` (tool ``opencv``; values fx, fy, cx, cy and the
    distortion coefficients by OpenCV's names; the model from ``distortion_model`` or the count).

    The file is parsed and checked by :mod:`selfcal.io.opencv_storage`, never by ``cv2.FileStorage`` (which
    aborts the process on some broken files)."""
    from .calibration_files import ToolCalibration
    from .opencv_storage import Matrix, read_file_storage
    path = os.fspath(path)
    nodes = read_file_storage(path)
    k_node = nodes.get("camera_matrix")
    if k_node is None:
        raise BlockError(path, "camera_matrix (3 x 3) is missing", column="camera_matrix")
    if not isinstance(k_node.value, Matrix) or k_node.value.values.shape != (3, 3):
        found = k_node.value.values.shape if isinstance(k_node.value, Matrix) else "no opencv-matrix"
        raise BlockError(path, f"camera_matrix must be a 3 x 3 opencv-matrix, found {found}", k_node.line,
                         "camera_matrix")
    K = k_node.value.values
    if not (K[0, 0] > 0 and K[1, 1] > 0) or np.any(np.abs(K[[1, 2, 2], [0, 0, 1]]) > 1e-9 * K[0, 0]) \
            or abs(K[2, 2] - 1) > 1e-9:
        raise BlockError(path, "camera_matrix must be [fx 0 cx; 0 fy cy; 0 0 1] with fx, fy > 0", k_node.line,
                         "camera_matrix")
    if abs(K[0, 1]) > 1e-9 * abs(K[0, 0]):
        raise BlockError(path, "camera_matrix has a skew term; selfcal reads OpenCV cameras without skew",
                         k_node.line, "camera_matrix")
    width, height = (_whole_positive(path, nodes, key) for key in ("image_width", "image_height"))
    d_node = nodes.get("distortion_coefficients")
    if d_node is not None and not isinstance(d_node.value, Matrix):
        raise BlockError(path, "distortion_coefficients must be an opencv-matrix (1 x n)", d_node.line,
                         "distortion_coefficients")
    dist = np.zeros(0) if d_node is None or not isinstance(d_node.value, Matrix) else d_node.value.values.ravel()
    model, camera_id = _string(path, nodes, "distortion_model"), _string(path, nodes, "camera_id")
    by_count = {0: "opencv4", 4: "opencv4", 5: "plumb_bob", 8: "rational", 12: "thin_prism", 14: "thin_prism"}
    if len(dist) not in by_count or len(dist) == 14 and np.any(dist[12:]):
        raise BlockError(path, f"{len(dist)} distortion coefficients: OpenCV models with 4, 5, 8 or 12 are read",
                         d_node.line if d_node is not None else None, "distortion_coefficients")
    counts = {"opencv4": 4, "plumb_bob": 5, "rational": 8, "thin_prism": 12}
    if model not in counts or counts[model] != len(dist):
        model = by_count[len(dist)]
    dist = np.concatenate([dist, np.zeros(counts[model] - len(dist))])[:counts[model]]
    values = {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2])}
    values.update({name: float(v) for name, v in zip(DISTORTION_NAMES, dist)})
    return ToolCalibration("opencv", model, values, width, height, camera_id=camera_id)


def write_undistortion_maps(path: str | os.PathLike, map_x: np.ndarray, map_y: np.ndarray,
                            camera_matrix: np.ndarray, camera_id: str) -> None:
    """``map_x``, ``map_y`` (float32, height x width) for ``cv2.remap`` and the ideal camera matrix. Stored without
    compression: deflate shrinks float32 maps by a fifth only (96 to 76 MB per 6000 x 4000 map) and took 3.4-3.8 s
    per map, 17 s for the pair on a loaded machine, against 0.1 s stored."""
    with atomic_write(path, mode="wb", encoding=None) as handle:
        np.savez(handle, map_x=map_x, map_y=map_y, camera_matrix=camera_matrix,
                            camera_id=np.array(camera_id))


def read_undistortion_maps(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    with np.load(path) as data:
        return data["map_x"], data["map_y"], data["camera_matrix"]
