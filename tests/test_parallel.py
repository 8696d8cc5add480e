"""Passes over the chunks on two threads (selfcal.adjust.parallel): the same results as on one, whatever the
order in which the threads run, and the thread count a user or the batch sets."""
import threading
import time

import numpy as np
import pytest

from selfcal.adjust import parallel
from selfcal.errors import UsageError

from conftest import pruned, simulation


def test_each_thread_takes_alternate_chunks_into_sums_of_its_own(monkeypatch):
    monkeypatch.setattr(parallel, "workers", lambda: 2)
    seen = []

    def work(chunk, sums):
        if chunk == 0:
            time.sleep(0.05)                    # the other thread goes first
        seen.append(threading.get_ident())
        sums.append(chunk)
        return chunk * 10

    results, parts = parallel.over_chunks(list(range(7)), work, list)
    assert results == [0, 10, 20, 30, 40, 50, 60]
    assert parts == [[0, 2, 4, 6], [1, 3, 5]]
    assert len(set(seen)) == 2
    # on one thread: the same groups, one after the other
    monkeypatch.setattr(parallel, "workers", lambda: 1)
    seen.clear()
    results, parts = parallel.over_chunks(list(range(7)), work, list)
    assert results == [0, 10, 20, 30, 40, 50, 60]
    assert parts == [[0, 2, 4, 6], [1, 3, 5]]
    assert set(seen) == {threading.get_ident()}


def test_a_failing_chunk_raises_after_both_threads_are_done(monkeypatch):
    monkeypatch.setattr(parallel, "workers", lambda: 2)
    finished = []

    def work(chunk, _):
        if chunk == 1:
            raise ArithmeticError("chunk 1")
        time.sleep(0.02)
        finished.append(chunk)

    with pytest.raises(ArithmeticError, match="chunk 1"):
        parallel.over_chunks(list(range(6)), work, lambda: None)
    assert sorted(finished) == [0, 2, 4]        # the main thread's chunks all ran; no worker left running


def test_selfcal_threads_sets_the_threads(monkeypatch):
    monkeypatch.setenv("SELFCAL_THREADS", "1")
    assert parallel.workers() == 1
    monkeypatch.setenv("SELFCAL_THREADS", "8")
    assert parallel.workers() == parallel.MAX_WORKERS
    monkeypatch.setenv("SELFCAL_THREADS", "two")
    with pytest.raises(UsageError, match="SELFCAL_THREADS"):
        parallel.workers()


def test_an_adjustment_on_two_threads_equals_one_on_one(monkeypatch):
    """The seed-000 block with Brown APs, data snooping and the tests: the same rejections, estimate and
    redundancy numbers on two threads as on one, bit for bit (the Dask batch, one thread per worker, must
    equal the serial run)."""
    from selfcal.adjust import AdjustOptions, APOptions
    from selfcal.workflows.tested import adjust_with_tests

    block = pruned(simulation(seed=3, distortion="local+brown", points_per_mm2=1.0, blunder_rate=0.003), "type2")
    runs = {}
    for threads in ("1", "2"):
        monkeypatch.setenv("SELFCAL_THREADS", threads)
        runs[threads] = adjust_with_tests(block, AdjustOptions(ap=APOptions("brown")))
    one, two = runs["1"], runs["2"]
    assert len(one.result.problem.chunks) >= 2
    np.testing.assert_array_equal(one.rejected_rows, two.rejected_rows)
    assert one.rejected_rows.size > 0
    # the same sums in the same order (two groups of chunks, whichever thread runs them): bit for bit
    np.testing.assert_array_equal(two.result.state.points, one.result.state.points)
    np.testing.assert_array_equal(two.result.state.image, one.result.state.image)
    np.testing.assert_array_equal(two.tests.image_redundancy, one.tests.image_redundancy)
    assert two.result.sigma0_px == one.result.sigma0_px


def test_selfcal_sets_openblas_thread_timeout_unless_the_user_did():
    """Imported before NumPy (as the command line does), selfcal shortens OpenBLAS's spinning (the two
    runtimes of NumPy and SciPy wait for each other's spinning threads otherwise); a user's value stays."""
    import os
    import subprocess
    import sys

    code = "import selfcal, numpy, os; print(os.environ['OPENBLAS_THREAD_TIMEOUT'])"
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_THREAD_TIMEOUT"}
    assert subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          check=True).stdout.strip() == "12"
    env["OPENBLAS_THREAD_TIMEOUT"] = "20"
    assert subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          check=True).stdout.strip() == "20"


def test_a_pass_inside_a_pass_runs_on_its_callers_thread(monkeypatch):
    """A chunk's work that starts a pass of its own (on either thread) does not wait for the pool's one
    thread, which may be the one asking."""
    monkeypatch.setattr(parallel, "workers", lambda: 2)

    def inner(chunk, _):
        return threading.get_ident()

    def outer(chunk, _):
        threads = parallel.over_chunks(list(range(4)), inner, lambda: None)[0]
        return len(set(threads)) == 1 and threads[0] == threading.get_ident()

    results, _ = parallel.over_chunks(list(range(4)), outer, lambda: None)
    assert results == [True] * 4


def test_a_pushbroom_block_in_small_chunks_adjusts_alike_on_two_threads(monkeypatch):
    """The pushbroom sensor's predictions on two threads (the PRISM triplet cut into six chunks): the same
    adjustment as on one, bit for bit."""
    import selfcal.adjust.ordering as ordering
    from selfcal.adjust import AdjustOptions, adjust
    from selfcal.simulate.prism import prism_block, simulate_prism

    block = prism_block(simulate_prism(seed=1), seed=1)
    chunks = ordering.point_chunks
    monkeypatch.setattr(ordering, "point_chunks", lambda point_start, target: chunks(point_start, 20))
    runs = {}
    for threads in ("1", "2"):
        monkeypatch.setenv("SELFCAL_THREADS", threads)
        runs[threads] = adjust(block, AdjustOptions())
    one, two = runs["1"], runs["2"]
    assert len(one.problem.chunks) >= 4 and one.iterations == two.iterations
    np.testing.assert_array_equal(two.state.points, one.state.points)
    np.testing.assert_array_equal(two.Q_points, one.Q_points)
    assert two.sigma0_px == one.sigma0_px


def _forked_pass(queue) -> None:
    results, _ = parallel.over_chunks(list(range(6)), lambda chunk, _: chunk * chunk, lambda: None)
    queue.put(results)


def test_a_process_forked_after_a_pass_runs_passes_of_its_own(monkeypatch):
    """multiprocessing's fork (Linux's default) copies the thread pool but not its thread: the child's passes
    still finish."""
    import multiprocessing

    monkeypatch.setattr(parallel, "workers", lambda: 2)
    parallel.over_chunks(list(range(4)), lambda chunk, _: chunk, lambda: None)     # the pool and its thread exist
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    child = context.Process(target=_forked_pass, args=(queue,))
    child.start()
    child.join(timeout=60)
    if child.is_alive():
        child.kill()
    assert child.exitcode == 0, "the forked process did not finish its pass"
    assert queue.get(timeout=5) == [0, 1, 4, 9, 16, 25]
