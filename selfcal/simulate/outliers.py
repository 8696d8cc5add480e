"""Wrong image observations as feature matchers make them, added to a simulated block with their truth.

A matcher's tie points (SIFT/ORB matching before gradual selection: COLMAP, ODM, Metashape exports) carry
three kinds of wrong observations, which the model does not know about:

* *small* blunders: the right feature, measured a few pixels off (4-15 px in a random direction);
* *wrong matches*: another feature that looked alike, anywhere in the frame (uniform over the image);
* *patches*: consistently wrong matches in one part of one image (repeated texture, a moving car, a shadow):
  the ``patch`` observations nearest to a random point of one image, all moved by the same vector.

:func:`contaminate` draws them reproducibly (a seed) and returns the block with the truth: which observation
rows are wrong and by how much.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..block import Block

__all__ = ["Contamination", "contaminate"]


@dataclass(frozen=True)
class Contamination:
    """Which observations (positions in the block's observations) were made wrong, and how (col, row px)."""

    index: np.ndarray               # (k,) positions in block.observations
    kind: np.ndarray                # (k,) "small", "anywhere" or "patch"
    displacement_px: np.ndarray     # (k, 2) observed minus the original measurement, (col, row)

    def __len__(self) -> int:
        return len(self.index)

    def mask(self, n: int) -> np.ndarray:
        """A bool mask over ``n`` observations: True where wrong."""
        out = np.zeros(n, bool)
        out[self.index] = True
        return out


def _frame(camera) -> tuple[float, float]:
    """(columns, rows) of a camera's images: a frame camera's width and height, a line camera's detectors and
    lines."""
    for width, height in (("width_px", "height_px"), ("columns", "rows")):
        if getattr(camera, width, None) and getattr(camera, height, None):
            return float(getattr(camera, width)), float(getattr(camera, height))
    raise ValueError(f"camera '{camera.camera_id}' states no image size: give ``frame_px``")


def contaminate(block: Block, rate: float, anywhere_share: float = 0.5, patch: int = 0, seed: int = 0,
                small_px: tuple[float, float] = (4.0, 15.0), patch_shift_px: tuple[float, float] = (20.0, 60.0),
                patch_image: int | None = None, roles: tuple[str, ...] = ("tie",)) -> tuple[Block, Contamination]:
    """``block`` with ``rate`` of its image observations of points of ``roles`` made wrong (the matched tie
    points by default: the targets of control and check points are measured by hand; their errors are the
    control tests' business): ``anywhere_share`` of them wrong matches anywhere in the frame, the rest small
    blunders of ``small_px`` in a random direction; with ``patch``, that many more observations of one image
    (``patch_image``, by default a random one), the nearest to a random one of its points, moved by one vector of
    ``patch_shift_px`` length. ``rate`` is a share of all the image observations. Observations stay inside the frame
    (a matcher measures nothing outside it)."""
    if not 0.0 <= rate < 1.0:
        raise ValueError(f"the share of wrong observations must be in [0, 1), found {rate}")
    rng = np.random.default_rng(seed)
    obs = block.observations
    n = len(obs)
    pixel = obs.pixel.copy()
    frame = {c: _frame(cam) for c, cam in block.cameras.items()}
    size = np.array([frame[c] for c in block.images.camera_id[obs.image_index]], float) if n else np.zeros((0, 2))
    eligible = np.flatnonzero(np.isin(block.points.role[obs.point_index], roles))
    wrong = rng.choice(eligible, min(int(round(rate * n)), eligible.size), replace=False)
    n_any = int(round(anywhere_share * len(wrong)))
    anywhere, small = wrong[:n_any], wrong[n_any:]
    pixel[anywhere] = rng.uniform(0.0, 1.0, (len(anywhere), 2)) * size[anywhere]
    length = rng.uniform(small_px[0], small_px[1], len(small))
    angle = rng.uniform(0.0, 2.0 * np.pi, len(small))
    pixel[small] += np.column_stack([length * np.cos(angle), length * np.sin(angle)])
    kinds = [np.full(len(anywhere), "anywhere", dtype=object), np.full(len(small), "small", dtype=object)]
    index = [anywhere, small]
    if patch:
        image = int(rng.integers(len(block.images))) if patch_image is None else int(patch_image)
        mine = np.setdiff1d(np.intersect1d(np.flatnonzero(obs.image_index == image), eligible), wrong)
        centre = pixel[rng.choice(mine)]
        near = mine[np.argsort(np.hypot(*(pixel[mine] - centre).T))[:patch]]
        direction = rng.uniform(0.0, 2.0 * np.pi)
        shift = rng.uniform(*patch_shift_px) * np.array([np.cos(direction), np.sin(direction)])
        pixel[near] += shift
        index.append(near)
        kinds.append(np.full(len(near), "patch", dtype=object))
    np.clip(pixel, 0.0, size, out=pixel)
    index_all = np.concatenate(index).astype(np.int64)
    kind = np.concatenate(kinds)
    order = np.argsort(index_all)
    truth = Contamination(index_all[order], kind[order], (pixel - obs.pixel)[index_all[order]])
    return replace(block, observations=replace(obs, pixel=pixel, ap_at_px=None)), truth
