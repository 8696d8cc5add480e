"""One adjustment with its points on a Dask cluster (issue 43 item 1, `selfcal.adjust.distributed`): the same
estimates, sigmas, residuals and tests as in one process, the shares' parts adding up to the whole problem's."""
from __future__ import annotations

import contextlib

import numpy as np
import pytest

from conftest import pruned, simulation
from selfcal.adjust import AdjustOptions, APOptions, RobustOptions, adjust, distributed
from selfcal.adjust.engine import problem_at
from selfcal.adjust.schur import ReducedSums, add_point_schur, linearise_points
from selfcal.stats import SnoopingOptions
from selfcal.stats.snooping import image_w
from selfcal.workflows.tested import adjust_with_tests


@pytest.fixture(scope="module")
def client():
    from dask.distributed import Client, LocalCluster
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                           env={"SELFCAL_THREADS": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"})
    client = Client(cluster)
    yield client
    client.close()
    cluster.close()


def _block():
    """Seed 000's Type 2 block (GNSS/IMU with strip shift and drift) at 2 points per mm² (46,000 rays: four
    assembly chunks, so that the two shares, chunks 0-1 and 2-3, add in another order than the single process's
    two threads, chunks 0 and 2 and chunks 1 and 3) with 0.3 % blunders and a Brown lens."""
    return pruned(simulation(seed=7, distortion="brown", points_per_mm2=2.0, blunder_rate=0.003), "type2")


@contextlib.contextmanager
def on_the_cluster(client):
    """:func:`distributed.on_cluster`, yielding the number of shares of every cluster point side made inside."""
    made: list[int] = []
    original = distributed.ClusterPoints.__init__

    def counted(self, *args, **kwargs):
        original(self, *args, **kwargs)
        made.append(len(self.shares))
    distributed.ClusterPoints.__init__ = counted
    try:
        with distributed.on_cluster(client):
            yield made
    finally:
        distributed.ClusterPoints.__init__ = original


def _relative(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.max(np.abs(a - b)) / np.max(np.abs(a)))


def test_share_bounds_cut_the_chunks_into_even_runs():
    problem, _ = problem_at(_block(), AdjustOptions(ap=APOptions("brown")))
    assert len(problem.chunks) == 4
    bounds = distributed.share_bounds(problem, 2)
    assert bounds == [(0, 2), (2, 4)]
    assert distributed.share_bounds(problem, 9) == [(k, k + 1) for k in range(4)]      # at most one per chunk
    assert distributed.share_bounds(problem, 1) == [(0, 4)]
    ends = [int(problem.point_start[problem.chunks[c1 - 1][1]]) for _, c1 in bounds]
    assert ends[-1] == problem.n_image_observations and 0.4 < ends[0] / ends[-1] < 0.6


def test_the_shares_parts_add_up_to_the_whole_problems(client):
    """Each share, arranged on its worker from its points' block, gives its part of the normal equations and of
    the reduced system; their sums equal the whole problem's (to the rounding of the order of the sums)."""
    block = _block()
    options = AdjustOptions(ap=APOptions("brown"))
    problem, state = problem_at(block, options)
    side = distributed.ClusterPoints(client, tuple(sorted(client.scheduler_info()["workers"])), problem, block,
                                     options)
    whole = linearise_points(problem, state)
    summed = side.linearise(state)
    for name in ("U_ee", "U_ed", "U_dd", "g_theta"):
        assert _relative(getattr(whole, name), getattr(summed, name)) < 1e-12, name
    assert summed.cost == pytest.approx(whole.cost, rel=1e-13)
    # the reduced system's sums over the image pairs
    reference = ReducedSums.zeros(problem)
    add_point_schur(problem, whole.chunks, 0.0, reference)
    parts = ReducedSums(np.zeros_like(reference.diag), np.zeros_like(reference.off), side.pair_keys,
                        np.zeros_like(reference.S_ed), np.zeros_like(reference.S_dd), np.zeros_like(reference.g))
    for part in side._each("reduce", [(0.0,)] * len(side.shares)):
        parts.add(part)
    assert np.array_equal(parts.pair_keys, reference.pair_keys)
    for name in ("diag", "off", "S_ed", "S_dd", "g"):
        assert _relative(getattr(reference, name), getattr(parts, name)) < 1e-12, name
    # the gathered chunks are the whole problem's, point for point
    gathered, v_inv = side.gathered(whole)
    assert len(gathered.chunks) == len(whole.chunks) and v_inv is not None and len(v_inv) == len(whole.chunks)
    for mine, theirs in zip(whole.chunks, gathered.chunks):
        assert (mine.p0, mine.p1, mine.o0, mine.o1) == (theirs.p0, theirs.p1, theirs.o0, theirs.o1)
        assert np.array_equal(mine.points, theirs.points)
        np.testing.assert_allclose(theirs.V, mine.V, rtol=1e-13, atol=0)
        np.testing.assert_allclose(theirs.w_e, mine.w_e, rtol=1e-13, atol=0)
    side.close()


def test_a_tested_adjustment_on_the_cluster_equals_the_single_process(client):
    """Data snooping on top, with a Brown lens and GNSS/IMU: every parameter, its sigma, every residual and w-test
    and the rejected observations equal the single process's to 1e-9 relative."""
    block = _block()
    options = AdjustOptions(ap=APOptions("brown"))
    one = adjust_with_tests(block, options, SnoopingOptions())
    with on_the_cluster(client) as made:
        two = adjust_with_tests(block, options, SnoopingOptions())
    assert made and set(made) == {2}                 # every solve ran on two shares
    assert len(one.rejected_rows) > 20
    np.testing.assert_array_equal(np.sort(one.rejected_rows), np.sort(two.rejected_rows))
    r1, r2 = one.result, two.result
    assert r1.iterations == r2.iterations
    assert _relative(r1.state.points, r2.state.points) < 1e-9
    theta1, theta2 = r1.problem.pack(r1.state), r2.problem.pack(r2.state)
    assert np.max(np.abs(theta1 - theta2) / np.maximum(np.abs(theta1), 1e-3)) < 1e-9
    sigma1, sigma2 = r1.parameters().sigma, r2.parameters().sigma
    free = np.isfinite(sigma1) & (sigma1 > 0)
    assert np.max(np.abs(sigma1[free] / sigma2[free] - 1.0)) < 1e-9
    assert _relative(r1.residuals, r2.residuals) < 1e-9
    # the w-tests that snooping reads (an observation without redundancy, r clamped at 1e-12, has a w of rounding
    # noise times 1e6 in either run: not controlled, snooping sets it to 0)
    controlled = SnoopingOptions().min_redundancy
    a, b = image_w(one.tests, controlled), image_w(two.tests, controlled)
    assert (a > 0).sum() > 0.9 * len(a) and np.max(np.abs(a - b)) < 1e-9 * np.max(a)
    for name in ("image_redundancy", "control_w", "parameter_w"):
        a, b = getattr(one.tests, name), getattr(two.tests, name)
        assert np.max(np.abs(a - b), initial=0.0) < 1e-9 * np.max(np.abs(a), initial=1.0), name
    assert r1.sigma0_px == pytest.approx(r2.sigma0_px, rel=1e-12)


def test_the_points_results_are_computed_on_the_workers_and_dropped_with_the_cluster(client, monkeypatch):
    """The points' cofactors, the image leverages and one point's cofactor come from the shares, without their
    linearisation brought to the client, and equal one process's to 1e-9; the shares stay on the workers while the
    result asks for them and go with the cluster's context, after which the result says so."""
    from selfcal.errors import AdjustmentError
    block = _block()
    options = AdjustOptions(ap=APOptions("brown"))
    one = adjust(block, options)
    brought = []
    monkeypatch.setattr(distributed.ClusterPoints, "gathered", lambda self, lin: brought.append(lin))
    with on_the_cluster(client) as made:
        two = adjust(block, options)
        assert set(made) == {2} and isinstance(two.points, distributed.ClusterPoints)
        h2, v2 = two.image_leverages()              # (the points' cofactors come out of the same pass)
        some = two.some_point_cofactors(np.array([5, 0, len(block.points) - 1]))
        assert sum(client.run(lambda: len(distributed._SHARES)).values()) == 2
    assert not brought
    h1, v1 = one.image_leverages()
    assert np.max(np.abs(h1 - h2)) < 1e-9 and _relative(v1, v2) < 1e-9
    Q1, Q2 = one.Q_points, two.Q_points
    scale = np.sqrt(np.einsum("pii->pi", Q1))
    assert np.max(np.abs(Q1 - Q2) / (scale[:, :, None] * scale[:, None, :])) < 1e-9
    np.testing.assert_array_equal(some, Q2[[5, 0, len(block.points) - 1]])
    # the context closed: the workers hold no share, and a question the shares must answer is refused
    assert sum(client.run(lambda: len(distributed._SHARES)).values()) == 0
    two.point_cofactor_blocks = None
    with pytest.raises(AdjustmentError, match="shares of the points are dropped"):
        two.Q_points


def test_what_stays_in_the_client(client, monkeypatch):
    """A sensor whose shares are not checked (distributed.SENSORS) and no cluster at all keep their points in this
    process."""
    block = _block()
    problem, _ = problem_at(block, AdjustOptions())
    assert distributed.point_side(problem, block, AdjustOptions()) is None       # outside on_cluster
    with distributed.on_cluster(client):
        side = distributed.point_side(problem, block, AdjustOptions())
        assert isinstance(side, distributed.ClusterPoints)
        side.close()
        unchecked = problem.sensors[0].sensor
        monkeypatch.setattr(type(unchecked), "name", "not-checked")
        assert distributed.point_side(problem, block, AdjustOptions()) is None


def test_a_robust_adjustment_on_the_cluster_equals_the_single_process(client):
    """The robust weights are the client's (one scale for the block); the shares take them at every update. The
    weights amplify the sums' rounding (a weight on the loss's steep flank moves by 1e-8 with a residual's rounding of
    1e-12, and the estimate with it): equal to 1e-8 here, against the 1e-9 of the adjustment with fixed weights."""
    block = pruned(simulation(seed=8, distortion="brown", points_per_mm2=2.0, blunder_rate=0.05), "type1")
    options = AdjustOptions(ap=APOptions("brown"))
    one = adjust(block, options, robust=RobustOptions())
    with distributed.on_cluster(client):
        two = adjust(block, options, robust=RobustOptions())
    assert len(one.robust.history) >= 3 and len(one.robust.history) == len(two.robust.history)
    assert np.sum(one.robust.image < 0.1) > 0.02 * len(one.robust.image)       # the blunders lost their weight
    assert np.max(np.abs(one.robust.image - two.robust.image)) < 1e-6
    assert one.iterations == two.iterations
    assert _relative(one.state.points, two.state.points) < 1e-8
    assert _relative(one.residuals, two.residuals) < 1e-8
    assert one.sigma0_px == pytest.approx(two.sigma0_px, rel=1e-8)


def _table(path) -> tuple[np.ndarray, np.ndarray]:
    """The numeric columns of a results CSV, and the unit of each value's last printed digit."""
    import csv
    with open(path, newline="") as handle:
        rows = [row for row in csv.reader(handle) if row and not row[0].startswith("#")]
    header, body = rows[0], rows[1:]
    values, units = [], []
    for j in range(len(header)):
        try:
            values.append([float(row[j]) if row[j] != "" else np.nan for row in body])
        except ValueError:
            continue
        units.append([10.0 ** -len(row[j].partition(".")[2]) if "e" not in row[j].lower() else 0.0 for row in body])
    return np.array(values, float), np.array(units, float)


def test_selfcal_adjust_on_a_local_cluster_writes_the_single_process_results(tmp_path, monkeypatch):
    """``selfcal adjust --scheduler local:2``: the same results folder, to the printed digits; a scheduler that
    cannot be reached, or a malformed one, is exit 2 before any work, and no results folder."""
    from front_door import run_main
    from selfcal.io import write_block
    from selfcal.workflows import cluster
    folder = tmp_path / "block"
    write_block(pruned(simulation(seed=9, distortion="brown", points_per_mm2=0.5, blunder_rate=0.002), "type3"),
                str(folder))
    quick = ["--no-report", "--no-control-loo", "--no-half-block", "--ap", "brown"]
    code, err = run_main(["adjust", folder, "--out", tmp_path / "one", *quick])
    assert code == 0, err
    code, err = run_main(["adjust", folder, "--out", tmp_path / "two", *quick, "--scheduler", "local:2"])
    assert code == 0, err
    assert "starting a local Dask cluster of 2 worker processes" in err
    # every number as printed, or one unit of its last digit off (a rounding that the sums' order flipped: a w-test's
    # MDB of 4876.474 px against 4876.475 px, of an observation without redundancy)
    for name in ("points.csv", "residuals.csv", "parameters.csv", "images.csv"):
        (a, unit), (b, _) = _table(tmp_path / "one" / name), _table(tmp_path / "two" / name)
        assert a.shape == b.shape and a.size
        same = (np.abs(a - b) <= 1e-9 * np.abs(a) + 1.01 * unit) | (np.isnan(a) & np.isnan(b))
        assert same.all(), name
    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT_S", 1.0)
    code, err = run_main(["adjust", folder, "--out", tmp_path / "three", "--scheduler", "tcp://127.0.0.1:9"])
    assert code == 2 and "cannot reach the Dask scheduler at tcp://127.0.0.1:9" in err
    assert not (tmp_path / "three").exists()
    code, err = run_main(["adjust", folder, "--out", tmp_path / "four", "--scheduler", "local:0"])
    assert code == 2 and "--scheduler local:N needs a whole number of workers" in err
    assert not (tmp_path / "four").exists()


def test_a_worker_lost_mid_iteration_stops_the_adjustment_with_its_name():
    """A worker killed after the first iteration: the adjustment stops with an AdjustmentError naming it (its share's
    points are nowhere else), within seconds of the scheduler noticing, not a hang."""
    import os
    import signal
    import time

    import dask
    from dask.distributed import Client, LocalCluster
    from selfcal.errors import AdjustmentError
    block = _block()
    with dask.config.set({"distributed.comm.timeouts.connect": "3s"}):
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                               env={"SELFCAL_THREADS": "1"})
        client = Client(cluster)
        try:
            pids = client.run(os.getpid)
            victim = sorted(pids)[1]

            def kill_after_the_first_iteration(record) -> None:
                if record.iteration == 1:
                    os.kill(pids[victim], signal.SIGKILL)
            t0 = time.perf_counter()
            with distributed.on_cluster(client), pytest.raises(AdjustmentError) as raised:
                adjust(block, AdjustOptions(ap=APOptions("brown")), progress=kill_after_the_first_iteration)
            assert f"the Dask worker {victim} holding a share of the points" in str(raised.value)
            assert time.perf_counter() - t0 < 60
        finally:
            client.close()
            cluster.close()


def test_a_rolling_shutter_block_on_the_cluster_equals_the_single_process(client):
    """The rolling shutter's sensor (its readout estimated with the Brown lens): the same estimates and residuals."""
    from selfcal.block import prune
    from selfcal.simulate import simulate_uav
    block = prune(simulate_uav(seed=2, distortion="brown", points_per_mm2=2.0, rolling_shutter_ms=30.0,
                               flight="serpentine").blocks["type2"])
    assert {camera.sensor for camera in block.cameras.values()} == {"frame-rolling"}
    options = AdjustOptions(ap=APOptions("brown"))
    one = adjust(block, options)
    problem, _ = problem_at(block, options)
    with distributed.on_cluster(client):
        side = distributed.point_side(problem, block, options)
        assert isinstance(side, distributed.ClusterPoints) and len(side.shares) == 2
        side.close()
        two = adjust(block, options)
    assert "readout" in one.problem.cameras[0].names
    assert _relative(np.concatenate(one.state.cameras), np.concatenate(two.state.cameras)) < 1e-9
    assert _relative(one.state.points, two.state.points) < 1e-9
    assert _relative(one.residuals, two.residuals) < 1e-9


def test_a_free_network_on_the_cluster_equals_the_single_process(client):
    """A tie-point network without control (datum free: the minimum-norm solution, its seven datum directions
    fitted from the shares' sums about the centroid of every point): the same estimates, residuals and sigmas."""
    from dataclasses import replace

    from selfcal.block import leave_out, prune
    block = simulation(seed=7, distortion="brown", points_per_mm2=2.0).blocks["type1"]
    block = prune(replace(leave_out(block, points=block.points.role != "tie"), datum="free"))
    options = AdjustOptions(ap=APOptions("brown"))
    one = adjust(block, options)
    with on_the_cluster(client) as made:
        two = adjust(block, options)
    assert made and set(made) == {2} and one.converged and two.converged
    assert one.iterations == two.iterations
    assert _relative(one.state.points, two.state.points) < 1e-9
    assert _relative(one.state.image, two.state.image) < 1e-9
    assert _relative(one.residuals, two.residuals) < 1e-9
    sigma1, sigma2 = one.parameters().sigma, two.parameters().sigma
    free = np.isfinite(sigma1) & (sigma1 > 0)
    assert np.max(np.abs(sigma1[free] / sigma2[free] - 1.0)) < 1e-9
