"""Bundle Adjustment in the Large (BAL) problem files (Agarwal et al. 2010).

Format (grail.cs.washington.edu/projects/bal): a header ``n_cameras n_points
n_observations``; one line per observation ``camera point x y`` (image
coordinates centred on the image, x right, y up, in pixels); then 9 numbers
per camera (rotation vector, translation, f, k1, k2) and 3 per point, one
number per line (whitespace of any kind is accepted).
"""
from __future__ import annotations

import io
import os
import re
from dataclasses import dataclass

import numpy as np

from ..errors import BlockError
from .text import is_number, read_text

__all__ = ["BalProblem", "read_bal"]


@dataclass(frozen=True)
class BalProblem:
    cameras: np.ndarray         # (n_cameras, 9): r (3), t (3), f, k1, k2
    points: np.ndarray          # (n_points, 3)
    obs_camera: np.ndarray      # (m,)
    obs_point: np.ndarray       # (m,)
    obs_xy: np.ndarray          # (m, 2)


def read_bal(path: str | os.PathLike) -> BalProblem:
    """Read a BAL problem; a defect is a BlockError naming the line."""
    path = str(path)
    if not os.path.isfile(path):
        raise BlockError(path, "file not found")
    size = os.path.getsize(path)
    with io.StringIO(read_text(path, "BAL problem")) as handle:
        header = handle.readline()
        try:
            n_cam, n_pt, n_obs = (int(v) for v in header.split())
        except ValueError:
            raise BlockError(path, "the first line must hold n_cameras n_points n_observations", 1) from None
        if min(n_cam, n_pt, n_obs) <= 0:
            raise BlockError(path, "the counts of the first line must be positive", 1)
        # the shortest file the counts can describe: 'c p x y' lines of 8 bytes, parameters of 2 ('0' and a
        # line end); checked before anything of their size is allocated (a count of 10^12 asked for 29 TiB)
        least = len(header) + 8 * n_obs + 2 * (9 * n_cam + 3 * n_pt)
        if least > size:
            raise BlockError(path, f"the header's counts ({n_cam} cameras, {n_pt} points, {n_obs} observations) need "
                                   f"at least {least} bytes; the file has {size}", 1)
        obs = np.zeros((n_obs, 4))
        obs_line = np.zeros(n_obs, np.int64)
        number, k = 1, 0
        while k < n_obs:
            line = handle.readline()
            number += 1
            if not line:
                raise BlockError(path, f"the file ends after {k} of {n_obs} observations", number)
            fields = line.split()
            if not fields:
                continue
            if len(fields) != 4:
                raise BlockError(path, f"expected 'camera point x y', found '{line.strip()[:60]}'", number)
            try:
                obs[k] = [float(f) for f in fields]
            except ValueError:
                raise BlockError(path, f"not a number in '{line.strip()[:60]}'", number) from None
            if not np.all(np.isfinite(obs[k])):
                raise BlockError(path, f"NaN or infinite value in '{line.strip()[:60]}'", number)
            obs_line[k] = number
            k += 1
        rest_text = handle.read()
    rest = rest_text.split()
    need = 9 * n_cam + 3 * n_pt

    def line_of(k: int) -> int:
        """The file line of parameter ``k`` (0-based) of the block after the observations."""
        for n, match in enumerate(re.finditer(r"\S+", rest_text)):
            if n == k:
                return number + 1 + rest_text.count("\n", 0, match.start())
        return number + 1 + rest_text.count("\n")

    def owner(k: int) -> str:
        return f"camera {k // 9}" if k < 9 * n_cam else f"point {(k - 9 * n_cam) // 3}"

    if len(rest) != need:
        where = line_of(need) if len(rest) > need else number + 1 + rest_text.rstrip().count("\n")
        raise BlockError(path, f"expected {need} camera and point parameters after the observations, found "
                               f"{len(rest)}", where)
    try:
        values = np.array(rest, dtype=float)
    except ValueError:
        k = next(k for k, v in enumerate(rest) if not is_number(v))
        raise BlockError(path, f"'{rest[k][:40]}' is not a number (parameter {k + 1} after the observations, "
                               f"{owner(k)})", line_of(k)) from None
    if not np.all(np.isfinite(values)):
        k = int(np.flatnonzero(~np.isfinite(values))[0])
        raise BlockError(path, f"NaN or infinite value '{rest[k]}' (parameter {k + 1} after the observations, "
                               f"{owner(k)})", line_of(k))
    index = obs[:, :2]
    wrong = np.any((index != np.round(index)) | (np.abs(index) > 2**53), axis=1)
    if wrong.any():
        raise BlockError(path, "camera and point indices must be integers", int(obs_line[np.argmax(wrong)]))
    cam, pt = obs[:, 0].astype(np.int64), obs[:, 1].astype(np.int64)
    outside = np.flatnonzero((cam < 0) | (cam >= n_cam) | (pt < 0) | (pt >= n_pt))
    if outside.size:
        raise BlockError(path, f"observation refers to camera {cam[outside[0]]} / point {pt[outside[0]]} outside "
                               f"the header's counts", int(obs_line[outside[0]]))
    return BalProblem(values[:9 * n_cam].reshape(n_cam, 9), values[9 * n_cam:].reshape(n_pt, 3), cam, pt,
                      obs[:, 2:4].copy())
