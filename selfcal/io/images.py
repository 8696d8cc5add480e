"""Image files for the commands that resample images (``undistort``, ``export colmap-workspace``).

Reading and writing go through Python's own file calls and OpenCV's in-memory codecs (``cv2.imdecode``,
``cv2.imencode``), never through OpenCV's file names:

* a file name that is not UTF-8 is refused by name (:func:`check_file_name`) before any work: OpenCV's
  ``imread``/``imwrite`` take a C string and died with SIGSEGV on one (issue 46);
* an image must decode completely: ``cv2.imread`` of a JPEG cut at 40 % only warns on stderr ("Premature end
  of JPEG file") and returns the image with the missing rows grey. ``cv2.imdecode`` refuses that file with the
  OpenCV of this environment, but what OpenCV does with a short stream differs between its file and memory
  readers and between versions; JPEG and PNG files are therefore also decoded in full by Pillow, whose decoders
  raise "image file is truncated" on a short stream (``ImageFile.LOAD_TRUNCATED_IMAGES`` held off). The
  formats only OpenCV reads (TIFF variants, EXR...) rely on ``cv2.imdecode``, which refuses a TIFF cut short;
* a write that fails is the file system's error (a full disk: ENOSPC), which the atomic folder being written
  reports as an :class:`~selfcal.errors.OutputError` naming the final path; "no encoder" is said only when
  OpenCV has none for the extension.
"""
from __future__ import annotations

import io
import os

import numpy as np

from ..errors import BlockError

__all__ = ["check_file_name", "read_image", "write_image"]

#: formats whose Pillow decoder is complete enough to tell a cut file from a whole one
_PILLOW_CHECKED = {"JPEG", "MPO", "PNG"}


def shown(path) -> str:
    """A file name as it can be printed: bytes that are not UTF-8 as \\xNN."""
    return os.fsencode(os.fspath(path)).decode("utf-8", "backslashreplace")


def check_file_name(path) -> str:
    """``path`` if its name is UTF-8; else a BlockError naming it (OpenCV and many tools cannot take it)."""
    path = os.fspath(path)
    try:
        path.encode("utf-8")
    except UnicodeEncodeError:
        raw = os.fsencode(path)
        bad = next(b for b in raw if b >= 0x80)
        raise BlockError(shown(path), f"the file name is not UTF-8 (byte 0x{bad:02x}); rename the file "
                                      f"(selfcal passes no such name to OpenCV)") from None
    return path


def _complete(data: bytes, path: str) -> None:
    """Decode ``data`` in full with Pillow where it reads the format completely; a short or broken stream is a
    BlockError."""
    from PIL import Image, ImageFile, UnidentifiedImageError

    truncated, limit = ImageFile.LOAD_TRUNCATED_IMAGES, Image.MAX_IMAGE_PIXELS
    ImageFile.LOAD_TRUNCATED_IMAGES, Image.MAX_IMAGE_PIXELS = False, None
    try:
        with Image.open(io.BytesIO(data)) as image:
            if image.format not in _PILLOW_CHECKED:
                return
            image.load()
    except UnidentifiedImageError:
        return                          # a format Pillow does not read: OpenCV's decoder alone decides
    except (OSError, SyntaxError, ValueError) as exc:
        raise BlockError(path, f"does not decode completely ({exc}); the file is cut short or damaged") from None
    finally:
        ImageFile.LOAD_TRUNCATED_IMAGES, Image.MAX_IMAGE_PIXELS = truncated, limit


def read_image(path: str | os.PathLike) -> np.ndarray:
    """An image file as ``cv2.imread(path, IMREAD_UNCHANGED)`` gives it (any depth and channels), decoded
    completely; a name that is not UTF-8, an unreadable, short or damaged file: BlockError naming it."""
    import cv2

    path = check_file_name(path)
    try:
        with open(path, "rb") as handle:
            data = handle.read()
    except OSError as exc:
        raise BlockError(path, f"cannot be read ({exc.strerror})") from None
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) if data else None
    if image is None:
        raise BlockError(path, "cannot be decoded as an image (not an image, or cut short or damaged)")
    _complete(data, path)
    return image


def write_image(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an image in the format its extension names (callers write into an atomic folder)."""
    import cv2

    path = check_file_name(path)
    extension = os.path.splitext(path)[1]
    try:
        ok, encoded = cv2.imencode(extension, image)
    except cv2.error:
        ok = False
    if not ok:
        raise BlockError(path, f"OpenCV has no encoder for '{extension or 'no extension'}' images of "
                               f"{image.dtype} with {1 if image.ndim == 2 else image.shape[2]} channel(s)")
    with open(path, "wb") as handle:
        handle.write(encoded.tobytes())
