"""One adjustment's points on a Dask cluster (issue 43 item 1; DESIGN-NOTES "The distributed adjustment").

The points of a problem are cut, in the problem's order, into one share per worker, each a run of whole assembly
chunks holding about the same number of image observations. Each share goes to its worker once, as the block of
its points and their observations; the worker arranges it as a problem of its own (:class:`PointShare`, kept in the
worker's process under a key: every later task on that worker finds it) with the client's AP models, its chunks
and its weights, and keeps everything that is per point: its AP columns, its linearisation, its damped point
blocks. In an iteration the client sends the
image, camera and trajectory unknowns with each share's points, and the shares return their part of the normal
equations (:func:`~selfcal.adjust.schur.linearise_points`) and of the reduced system
(:func:`~selfcal.adjust.schur.add_point_schur`), which the client adds and completes once
(:func:`~selfcal.adjust.schur.with_parameter_observations`, :func:`~selfcal.adjust.schur.assemble`), factorises
and solves; the shares back-substitute their points and evaluate the cost of trial states. The solver is the one of
every adjustment (:func:`selfcal.adjust.solver.solve`, through :class:`ClusterPoints`, a
:class:`~selfcal.adjust.point_side.PointSide`).

After the solve the shares stay on their workers with their last linearisation and the point inverses of the
undamped reduced system, for as long as the result (:class:`~selfcal.adjust.result.AdjustmentResult`, whose
``points`` is this side) or the cluster's context lasts. The results of the points are computed there: the client
sends each share the blocks of Q_theta its points read (:func:`~selfcal.adjust.covariance.theta_blocks`: every
image's, those of the pairs of images its points join, the camera parameters'), and the share returns its points'
cofactor blocks and its observations' leverages and whitened residuals (:meth:`ClusterPoints.point_cofactors`,
:meth:`ClusterPoints.image_leverages`, :meth:`ClusterPoints.some_point_cofactors`). Each share's chunk computes
what the client's would have, so the results equal the single process's to the rounding of Q_theta's reading.
Only the downdated start of a re-adjustment (reduced systems of up to
:data:`~selfcal.adjust.update.UPDATE_LIMIT` unknowns) brings the chunks to the client
(:meth:`ClusterPoints.gathered`).

A robust weighting is the client's (the weights follow every accepted step's residuals, of every observation, and
their scale is one for the block): the shares take the new weight factors from it (:meth:`ClusterPoints.reweighted`).
A free network's datum directions are fitted by the client from the shares' sums about the centroid of every point
(:meth:`ClusterPoints.similarity_sums`). Not on the cluster (they run in the client, as without it): sensors whose
shares are not checked yet (:data:`SENSORS`). :func:`point_side` says which.
"""
from __future__ import annotations

import contextlib
import contextvars
import uuid
import weakref
from dataclasses import dataclass, field, replace
from typing import Any, Iterator

import numpy as np

from ..errors import AdjustmentError, UsageError
from .covariance import ThetaBlocks, point_cofactors, some_point_cofactors, theta_blocks
from .datum import conditional_point_sigma, points_centroid, similarity_sums, undetermined_by_sigma
from .leverage import image_leverages
from .point_side import PointStep, geometric_blocks, point_step
from .problem import Problem, State, build_problem
from .residuals.image import reweight_observations
from .schur import (ChunkLinearisation, Linearisation, ReducedSums, SingularPoints, add_point_schur, assemble,
                    back_substitute, linearise_points, points_cost_and_residuals)

__all__ = ["on_cluster", "point_side", "ClusterPoints", "PointShare", "ShareSettings", "share_bounds", "SENSORS"]

#: the sensors whose problems a share has been checked against (tests/test_distributed.py)
SENSORS = ("frame", "frame-rolling")

#: how often (seconds) a wait for the shares' answers checks that their workers are still there
POLL_S = 2.0

#: an array argument of a share's task larger than this (bytes) is sent straight to its worker, not in the task
DIRECT_BYTES = 1 << 20


@dataclass(frozen=True)
class _Cluster:
    client: Any                     # dask.distributed.Client
    workers: tuple[str, ...]        # the worker addresses, one share each
    sides: weakref.WeakSet = field(default_factory=weakref.WeakSet)     # the point sides still open


_current: contextvars.ContextVar[_Cluster | None] = contextvars.ContextVar("selfcal_cluster", default=None)


@contextlib.contextmanager
def on_cluster(client: Any) -> Iterator[None]:
    """Every adjustment started inside (in this thread) puts its points on the workers of ``client`` (a
    :class:`dask.distributed.Client`), one share per worker, where :func:`point_side` allows it."""
    workers = tuple(sorted(client.scheduler_info()["workers"]))
    if not workers:
        raise UsageError("the Dask cluster has no workers")
    cluster = _Cluster(client, workers)
    token = _current.set(cluster)
    try:
        yield
    finally:
        _current.reset(token)
        for side in list(cluster.sides):        # the shares of the results still held: dropped with the cluster
            side.close()


def point_side(problem: Problem, block, options) -> "ClusterPoints | None":
    """The cluster's point side for this problem, or None where it runs in this process: outside
    :func:`on_cluster`, one worker's cluster, or a sensor not in :data:`SENSORS`."""
    cluster = _current.get()
    if cluster is None or len(cluster.workers) < 2:
        return None
    if any(slot.sensor.name not in SENSORS for slot in problem.sensors):
        return None
    side = ClusterPoints(cluster.client, cluster.workers, problem, block, options)
    cluster.sides.add(side)
    return side


def share_bounds(problem: Problem, n_shares: int) -> list[tuple[int, int]]:
    """``n_shares`` (at most one per chunk) runs of the problem's chunks, [c0, c1), with about the same number of
    image observations each."""
    n_chunks = len(problem.chunks)
    n = max(1, min(n_shares, n_chunks))
    ends = np.array([problem.point_start[p1] for _, p1 in problem.chunks], float)
    total = ends[-1] if n_chunks else 0.0
    cuts = [int(np.searchsorted(ends, total * k / n, side="left")) + 1 for k in range(1, n)]
    bounds: list[tuple[int, int]] = []
    start = 0
    for cut in cuts:
        cut = min(max(cut, start + 1), n_chunks - (n - len(bounds) - 1))
        bounds.append((start, cut))
        start = cut
    bounds.append((start, n_chunks))
    return bounds


def _sub_block(problem: Problem, block, p0: int, p1: int):
    """The block of the points at positions [p0, p1) of the problem's order and their observations, both in the
    problem's order (so that the share arranges them as the problem does)."""
    points = problem.point_order[p0:p1]
    o0, o1 = int(problem.point_start[p0]), int(problem.point_start[p1])
    local = np.full(len(block.points), -1, np.int64)
    local[points] = np.arange(len(points))
    observations = block.observations.take(problem.obs_order[o0:o1])
    observations = replace(observations, point_index=local[observations.point_index])
    return replace(block, points=block.points.take(points), observations=observations, folder=None)


#: the shares a worker process holds, by their key (:func:`_keep`, :func:`_call`, :func:`_drop`)
_SHARES: dict[str, "PointShare"] = {}


def _keep(key: str, *args) -> str:
    """(On a worker) build a share and keep it under ``key``."""
    _SHARES[key] = PointShare(*args)
    return key


def _call(key: str, method: str, *args):
    """(On a worker) a kept share's method."""
    share = _SHARES.get(key)
    if share is None:
        raise AdjustmentError(f"the worker no longer holds its share of the points ({key}): was it restarted?")
    return getattr(share, method)(*args)


def _worker_addresses(dask_scheduler=None) -> list[str]:
    """(On the scheduler) the workers it knows now (the client's copy of the list is refreshed only now and then)."""
    return list(dask_scheduler.workers)


def _drop(keys: list[str]) -> None:
    """(On a worker) forget the shares ``keys``."""
    for key in keys:
        _SHARES.pop(key, None)


@dataclass(frozen=True)
class ShareSettings:
    """What a share takes from the client's problem beyond its block: what the adjustment so far changed there (the
    weights of its observations, the parameters held) and the layout of theta it must reproduce."""

    chunks: list[tuple[int, int]]           # the client's chunks of the share's points, from its first position
    obs_sigma: np.ndarray                   # (m, 2) of its observations, the client's order
    obs_sigma_apriori: np.ndarray
    obs_weight: np.ndarray                  # (m,)
    image_free: np.ndarray                  # (n_images, width)
    camera_free: list[np.ndarray]           # per camera
    trajectory_free: list[np.ndarray]       # per trajectory block
    point_weights: list[np.ndarray]         # per block of observations of points: the weight of each share point
    d_offset: list[int]
    n_theta: int


class PointShare:
    """A share of a problem's points on a worker (kept there by :func:`_keep`): the problem of its points and their
    observations, arranged as the client's problem arranges them (its chunks, its weights, its camera and image
    parameters held or free), and the last linearisation and reduction of its points."""

    def __init__(self, block, options, ap_models: dict, settings: ShareSettings):
        problem = build_problem(block, options, ap_models=ap_models, point_key=np.arange(len(block.points)))
        if not np.array_equal(problem.obs_order, np.arange(len(block.observations))):
            raise AdjustmentError("a share of the points did not keep its observations' order (an image that "
                                  "observes a point twice?)")
        problem.chunks = settings.chunks
        problem._structure = None                   # (the structure follows the chunks: built on first use)
        problem.obs_sigma = settings.obs_sigma
        problem.obs_sigma_apriori = settings.obs_sigma_apriori
        problem.obs_weight = settings.obs_weight
        problem.image_free = settings.image_free
        for camera, free in zip(problem.cameras, settings.camera_free):
            camera.free[:] = free
        for block_of_share, free in zip(problem.trajectory, settings.trajectory_free):
            block_of_share.free[:] = free
        for residuals, weight in zip(problem.point_residuals, settings.point_weights):
            residuals.weight = weight[residuals.index]
        problem.d_offset = list(settings.d_offset)
        if problem.n_theta != settings.n_theta:
            raise AdjustmentError(f"a share of the points has {problem.n_theta} image and camera unknowns, the "
                                  f"client {settings.n_theta}")
        self.problem = problem
        self.lin: Linearisation | None = None
        self.v_inv: list | None = None

    def reweight(self, obs_weight: np.ndarray, point_weights: list[np.ndarray]) -> None:
        """Take the client's weight factors of its observations (a robust weighting's: their whitened rows and kept
        AP columns rescaled as the client's were) and of its observations of points."""
        reweight_observations(self.problem, obs_weight)
        for residuals, weight in zip(self.problem.point_residuals, point_weights):
            residuals.weight = weight[residuals.index]

    def pair_keys(self) -> np.ndarray:
        """The pairs of images its points join (ia * n_images + ib, ia < ib)."""
        return self.problem.structure().pair_keys

    def _state(self, theta: tuple, points: np.ndarray) -> State:
        image, cameras, extra = theta
        return State(image, cameras, points, extra)

    def linearise(self, theta: tuple, points: np.ndarray) -> Linearisation:
        self.lin = linearise_points(self.problem, self._state(theta, points))
        self.v_inv = None
        return replace(self.lin, chunks=[])

    def similarity_sums(self, points: np.ndarray, centroid: np.ndarray) -> np.ndarray:
        assert self.lin is not None
        return similarity_sums(self.problem, self.lin, points, centroid)

    def point_sigma(self) -> np.ndarray:
        assert self.lin is not None
        return conditional_point_sigma(geometric_blocks(self.problem, self.lin))

    def reduce(self, lam: float) -> ReducedSums:
        assert self.lin is not None
        sums = ReducedSums.zeros(self.problem)
        self.v_inv = add_point_schur(self.problem, self.lin.chunks, lam, sums)
        return sums

    def back_substitute(self, d_theta: np.ndarray) -> tuple[np.ndarray, PointStep]:
        assert self.lin is not None and self.v_inv is not None
        d_p = back_substitute(self.problem, self.lin, self.v_inv, d_theta)
        return d_p, point_step(d_p, self.lin.of_points("V"), self.lin.of_points("g_p"))

    def cost(self, theta: tuple, points: np.ndarray) -> float:
        return points_cost_and_residuals(self.problem, self._state(theta, points))[0]

    def chunks(self) -> tuple[list[ChunkLinearisation], list | None]:
        assert self.lin is not None
        return self.lin.chunks, self.v_inv

    # -- the results, from the last linearisation and (undamped) reduction, with the client's Q_theta's blocks --
    def point_cofactors(self, *blocks) -> np.ndarray:
        assert self.lin is not None and self.v_inv is not None
        return point_cofactors(self.problem, self.lin, self.v_inv, ThetaBlocks(*blocks))

    def some_point_cofactors(self, points: np.ndarray, *blocks) -> np.ndarray:
        assert self.lin is not None and self.v_inv is not None
        return some_point_cofactors(self.problem, self.lin, self.v_inv, ThetaBlocks(*blocks), points)

    def image_leverages(self, theta: tuple, points: np.ndarray, Q_points: np.ndarray | None, *blocks) -> tuple:
        assert self.lin is not None and self.v_inv is not None
        return image_leverages(self.problem, self._state(theta, points), self.lin, self.v_inv, ThetaBlocks(*blocks),
                               Q_points)


class ClusterPoints:
    """The point side (:class:`~selfcal.adjust.point_side.PointSide`) of a problem whose points are in shares on
    the workers of a Dask cluster (module docstring)."""

    def __init__(self, client: Any, workers: tuple[str, ...], problem: Problem, block, options):
        self.problem = problem
        bounds = share_bounds(problem, len(workers))
        ap_models = {cam.camera_id: cam.ap for cam in problem.cameras}
        self.points: list[np.ndarray] = []           # the block's points of each share, in its order
        self.offsets: list[tuple[int, int]] = []     # each share's first position and first observation
        futures = []
        for (c0, c1), worker in zip(bounds, workers):
            p0, p1 = problem.chunks[c0][0], problem.chunks[c1 - 1][1]
            o0, o1 = int(problem.point_start[p0]), int(problem.point_start[p1])
            points = problem.point_order[p0:p1]
            local = np.full(problem.n_points, -1, np.int64)
            local[points] = np.arange(len(points))
            settings = ShareSettings(
                chunks=[(a - p0, b - p0) for a, b in problem.chunks[c0:c1]], obs_sigma=problem.obs_sigma[o0:o1],
                obs_sigma_apriori=problem.obs_sigma_apriori[o0:o1], obs_weight=problem.obs_weight[o0:o1],
                image_free=problem.image_free, camera_free=[cam.free for cam in problem.cameras],
                trajectory_free=[t.free for t in problem.trajectory],
                point_weights=self._point_weights(problem, local, len(points)), d_offset=list(problem.d_offset),
                n_theta=problem.n_theta)
            key = f"selfcal-share-{uuid.uuid4().hex}"
            # (the block straight to its worker: in the task it would go through the scheduler)
            sub_block = client.scatter(_sub_block(problem, block, p0, p1), workers=[worker], direct=True, hash=False)
            # (its settings too: the weights and sigmas of its observations, 40 MB for a million)
            settings = client.scatter(settings, workers=[worker], direct=True, hash=False)
            futures.append(client.submit(_keep, key, sub_block, options, ap_models, settings, key=key,
                                         workers=[worker], allow_other_workers=False, pure=False))
            self.points.append(points)
            self.offsets.append((p0, o0))
        self.client, self.workers = client, list(workers[:len(futures)])
        self.shares = [future.key for future in futures]
        try:
            self._results(futures)
            self.share_pairs: list[np.ndarray] = self._each("pair_keys")     # each share's pairs of images
            self.pair_keys = np.unique(np.concatenate(self.share_pairs))
        except BaseException:
            self.close()                # the shares already made go too
            raise

    @staticmethod
    def _point_weights(problem: Problem, local: np.ndarray, n_points: int) -> list[np.ndarray]:
        """The weight factors of the observations of points (control coordinates, ...), per block, of every point
        of a share (``local``: each of the block's points' index in the share, -1 elsewhere); 1 where a point has
        no such observation."""
        weights = []
        for residuals in problem.point_residuals:
            full = np.ones(n_points)
            mine = local[residuals.index] >= 0
            full[local[residuals.index[mine]]] = residuals.weight[mine]
            weights.append(full)
        return weights

    def reweighted(self) -> None:
        """The shares take the client problem's weight factors (a robust weighting moved them)."""
        problem = self.problem
        arguments = []
        for points, (p0, o0) in zip(self.points, self.offsets):
            local = np.full(problem.n_points, -1, np.int64)
            local[points] = np.arange(len(points))
            o1 = o0 + int(problem.point_start[p0 + len(points)] - problem.point_start[p0])
            arguments.append((problem.obs_weight[o0:o1], self._point_weights(problem, local, len(points))))
        self._each("reweight", arguments)

    def _theta(self, state: State) -> tuple:
        return state.image, state.cameras, state.extra

    def _each(self, method: str, arguments: list[tuple] | None = None) -> list:
        """Every share's ``method`` on its worker, with its arguments (``arguments[i]`` for share i; None: none).
        An array argument of more than :data:`DIRECT_BYTES` (a share's points) goes straight to the worker."""
        self._open()
        return self._results([self._submit(i, method, arguments[i] if arguments else ())
                              for i in range(len(self.shares))], range(len(self.shares)))

    def _one(self, i: int, method: str, arguments: tuple):
        """Share i's ``method`` alone (as :meth:`_each`)."""
        return self._results([self._submit(i, method, arguments)], [i])[0]

    def _open(self) -> None:
        if not self.shares:
            raise AdjustmentError("the shares of the points are dropped: their adjustment's cluster (on_cluster) "
                                  "is closed; ask for its points' results inside it")

    def _submit(self, i: int, method: str, given: tuple):
        self._open()
        key, worker = self.shares[i], self.workers[i]
        sent = [self.client.scatter(a, workers=[worker], direct=True, hash=False)
                if isinstance(a, np.ndarray) and a.nbytes > DIRECT_BYTES else a for a in given]
        return self.client.submit(_call, key, method, *sent, workers=[worker], allow_other_workers=False, pure=False)

    def _results(self, calls: list, shares=None) -> list:
        """The answers of ``calls`` to ``shares`` (default: one to each share, in order); a share's singular points
        named by the block's numbering. A share whose worker is lost (its process killed, its machine gone) stops
        the adjustment with an AdjustmentError: its points are nowhere else."""
        answers = []
        shares = range(len(calls)) if shares is None else shares
        for call, i in zip(calls, shares):
            points, worker = self.points[i], self.workers[i]
            while True:
                try:
                    answers.append(call.result(timeout=POLL_S))
                    break
                except SingularPoints as exc:
                    raise SingularPoints(points[exc.indices]) from None
                except TimeoutError:
                    if worker not in self.client.run_on_scheduler(_worker_addresses):
                        raise AdjustmentError(f"the Dask worker {worker} holding a share of the points "
                                              f"({len(points)} points) was lost during the adjustment: it "
                                              f"stops here") from None
                except (AdjustmentError, UsageError, MemoryError):
                    raise
                except Exception as exc:            # a worker's connection closed, ...
                    raise AdjustmentError(f"the Dask worker {worker} holding a share of the points failed: "
                                          f"{type(exc).__name__}: {exc}") from exc
        return answers

    def linearise(self, state: State) -> Linearisation:
        theta = self._theta(state)
        parts = self._each("linearise", [(theta, state.points[points]) for points in self.points])
        lin = parts[0]
        for part in parts[1:]:
            lin.cost += part.cost
            lin.U_ee += part.U_ee
            lin.U_ed += part.U_ed
            lin.U_dd += part.U_dd
            lin.g_theta += part.g_theta
        return lin

    def undetermined(self, ratio: float) -> np.ndarray:
        sigma = np.full(self.problem.n_points, np.inf)
        for points, part in zip(self.points, self._each("point_sigma")):
            sigma[points] = part
        return undetermined_by_sigma(sigma, ratio)

    def similarity_sums(self, state: State) -> np.ndarray:
        centroid = points_centroid(state.points)
        parts = self._each("similarity_sums", [(state.points[points], centroid) for points in self.points])
        return np.sum(parts, axis=0)

    def reduce(self, lin: Linearisation, lam: float, dense: bool) -> tuple:
        sums = ReducedSums(lin.U_ee.copy(), np.zeros((len(self.pair_keys),) + lin.U_ee.shape[1:]), self.pair_keys,
                           lin.U_ed.copy(), lin.U_dd.copy(), lin.g_theta.copy())
        for part in self._each("reduce", [(lam,)] * len(self.shares)):
            sums.add(part)
        return assemble(self.problem, lin, sums, lam, dense), sums.g

    def back_substitute(self, d_theta: np.ndarray) -> tuple[np.ndarray, PointStep]:
        d_p = np.zeros((self.problem.n_points, 3))
        g_dot = diag_dot = max_sigma = 0.0
        for points, (part, step) in zip(self.points, self._each("back_substitute",
                                                                             [(d_theta,)] * len(self.shares))):
            d_p[points] = part
            g_dot += step.g_dot
            diag_dot += step.diag_dot
            max_sigma = max(max_sigma, step.max_sigma)
        return d_p, PointStep(g_dot, diag_dot, max_sigma)

    def cost(self, state: State) -> tuple[float, np.ndarray | None]:
        theta = self._theta(state)
        return float(sum(self._each("cost", [(theta, state.points[points]) for points in self.points]))), None

    def gathered(self, lin: Linearisation) -> tuple[Linearisation, list | None]:
        chunks: list[ChunkLinearisation] = []
        v_inv: list | None = []
        for points, (p0, o0), (parts, inverses) in zip(self.points, self.offsets,
                                                        self._each("chunks")):
            for ch in parts:
                chunks.append(replace(ch, p0=ch.p0 + p0, p1=ch.p1 + p0, o0=ch.o0 + o0, o1=ch.o1 + o0,
                                      points=points[ch.points]))
            if inverses is None or v_inv is None:
                v_inv = None
            else:
                v_inv += inverses
        return replace(lin, chunks=chunks), v_inv

    def _blocks(self, Q, i: int) -> tuple:
        """Share i's :class:`~selfcal.adjust.covariance.ThetaBlocks` of ``Q`` (Q_theta), as its task's arguments:
        the image blocks of its own pairs of images."""
        blocks = theta_blocks(Q, self.problem, self.share_pairs[i])
        return blocks.compact, blocks.Q_diag, blocks.Q_pair, blocks.Q_dd, blocks.Q_ed

    def point_cofactors(self, Q) -> np.ndarray:
        out = np.zeros((self.problem.n_points, 3, 3))
        arguments = [self._blocks(Q, i) for i in range(len(self.shares))]
        for points, part in zip(self.points, self._each("point_cofactors", arguments)):
            out[points] = part
        return out

    def some_point_cofactors(self, Q, points: np.ndarray) -> np.ndarray:
        out = np.full((len(points), 3, 3), np.nan)
        position = np.full(self.problem.n_points, -1, np.int64)
        share = np.full(self.problem.n_points, -1, np.int64)
        for i, mine in enumerate(self.points):
            position[mine], share[mine] = np.arange(len(mine)), i
        for i in np.unique(share[points]):                  # only the shares that hold the points asked for
            asked = np.flatnonzero(share[points] == i)
            out[asked] = self._one(int(i), "some_point_cofactors", (position[points[asked]],) + self._blocks(Q, i))
        return out

    def image_leverages(self, state: State, Q, Q_points: np.ndarray | None) -> tuple:
        m = self.problem.n_image_observations
        h, r = np.zeros((m, 2)), np.zeros((m, 2))
        points_out = np.zeros((self.problem.n_points, 3, 3)) if Q_points is None else Q_points
        theta = self._theta(state)
        arguments = [(theta, state.points[points], None if Q_points is None else Q_points[points]) + self._blocks(Q, i)
                     for i, points in enumerate(self.points)]
        for points, (_, o0), (h_share, r_share, Qp) in zip(self.points, self.offsets,
                                                           self._each("image_leverages", arguments)):
            h[o0:o0 + len(h_share)], r[o0:o0 + len(r_share)] = h_share, r_share
            points_out[points] = Qp
        return h, r, points_out

    def close(self) -> None:
        """Let the workers drop their shares (a worker already gone has nothing to drop)."""
        keys, self.shares = self.shares, []
        try:
            self.client.run(_drop, keys, workers=self.workers)
        except Exception:              # noqa: BLE001 - a lost worker's shares went with it
            pass
