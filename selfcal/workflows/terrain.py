"""Terrain heights as observations (issue 42): which tie points take them, and what the tests made of them.

The adjustment's terrain rows (:mod:`selfcal.adjust.residuals.terrain`) observe the tie points that
:class:`~selfcal.block.TerrainObservations` names. :func:`name_terrain_points` names them once, before the first
adjustment: every tie point whose start value (as the block gives it, or intersected from its rays) lies on the DEM;
the others are counted as off the DEM. From then on the set only shrinks, by data snooping's rejections.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..adjust import AdjustOptions
from ..block import Block
from ..errors import UsageError

__all__ = ["name_terrain_points", "terrain_notes", "check_terrain_block", "REJECTED_SHARE_NOTE"]

#: a note says the DEM may be on another datum when data snooping rejects more than this share of its heights
REJECTED_SHARE_NOTE = 0.5


def check_terrain_block(block: Block) -> None:
    """UsageError (exit 2) when the block's points cannot take terrain observations (frame cameras in a projected
    or local CRS, a planetary body), saying why."""
    from ..adjust.residuals.terrain import terrain_frame_problem
    from ..sensors import sensor_of
    frames = {sensor_of(c).object_frame for c in block.cameras.values()}
    frame = frames.pop() if len(frames) == 1 else "block"
    why = terrain_frame_problem(block, frame)
    if why is not None:
        raise UsageError(why)


def name_terrain_points(block: Block, options: AdjustOptions) -> Block:
    """``block`` with its terrain observations' tie points named (unchanged without terrain observations or when
    they are named already): those whose start values (:func:`selfcal.adjust.start_values`) lie on the DEM."""
    terrain = block.terrain_observations
    if terrain is None or terrain.point_ids is not None:
        return block
    from ..adjust import start_values
    from ..adjust.residuals.terrain import terrain_candidates
    check_terrain_block(block)
    state = start_values(block, options)
    on_dem = terrain_candidates(block, terrain.dem, state.points)
    tie = np.flatnonzero(np.asarray(block.points.role) == "tie")
    ids = np.asarray(block.points.point_id)
    off = np.setdiff1d(tie, on_dem)
    return replace(block, terrain_observations=replace(
        terrain, point_ids=tuple(str(p) for p in ids[on_dem]), off_dem=tuple(str(p) for p in ids[off])))


def terrain_notes(block: Block, rejected: list[tuple[str, float]]) -> list[str]:
    """The notes of the final result on the terrain observations: how many were used, off the DEM and rejected."""
    terrain = block.terrain_observations
    if terrain is None:
        return []
    named = len(terrain.point_ids or ())
    notes = [f"terrain observations: {named - len(terrain.rejected)} tie points' heights from the DEM "
             f"{terrain.source or '(in memory)'} (sigma {terrain.sigma_m:.3g} m a priori), {len(terrain.off_dem)} "
             f"tie points off the DEM, {len(rejected)} heights rejected by data snooping"]
    if named and len(rejected) > REJECTED_SHARE_NOTE * named:
        notes.append(f"data snooping rejected {len(rejected)} of the {named} terrain heights: more than "
                     f"{REJECTED_SHARE_NOTE:.0%} is no changed area but a DEM that does not fit (heights over the "
                     f"geoid taken as ellipsoidal? another epoch?) or a sigma too small (estimate it with "
                     f"--variance-components)")
    return notes


def readmissible_terrain(result, critical: float) -> list[str]:
    """The rejected terrain heights (point ids) that fit ``result``: the test of each left-out height against the
    adjustment without it, w = (H - h) / sqrt(sigma^2 + sigma_h^2) with the point's height sigma from its cofactor
    block (a-priori unit weight, as Baarda's w), within ``critical``. This is the w-test the height would have in
    the adjustment with it, so a height rejected in a batch round only because the others pulled the block (a
    large biased area tilts a weakly controlled block) is taken back once they are out."""
    from ..adjust.residuals.terrain import TerrainHeights
    terrain = result.block.terrain_observations
    if terrain is None or not terrain.rejected:
        return []
    points = result.block.points
    index = np.flatnonzero(np.isin(points.point_id, list(terrain.rejected)) & (np.asarray(points.role) == "tie"))
    if not index.size:
        return []
    rows = TerrainHeights(index, terrain.dem, terrain.sigma_m)
    r, J = rows.rows(result.state.points[index])
    q = np.einsum("nij,njk,nik->ni", J, result.Q_points[index], J)[:, 0]
    w = r[:, 0] / np.sqrt(1.0 + q)
    return [str(p) for p in points.point_id[index[np.abs(w) <= critical]]]
