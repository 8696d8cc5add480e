"""``selfcal plan`` (issue 43 item 2): the prediction against a measured run, the too-large block, --json, bad input."""
import json
import subprocess
import sys
import textwrap

import pytest

from conftest import run_cli

#: the predicted peak of the small block within this share of the measured one (issue 43 asks 20 % of the larger
#: blocks in benchmarks/bench_plan.py; this block is mostly the process's own base)
PEAK_TOLERANCE = 0.20

PLAN_KEYS = {"sizes", "ap_model", "workflow_peak_mb", "factorisation", "covariance", "band_width", "memory_mb", "peak_mb", "seconds",
             "seconds_per_iteration", "machine_speed", "available_mb"}
SIZE_KEYS = {"n_images", "n_cameras", "n_points", "n_observations", "image_width", "n_camera_parameters", "n_ap",
             "n_extra", "image_pairs", "band_images", "factor_blocks", "factor_block_flops", "n_theta"}


def _strip_block(tmp_path_factory, points_per_mm2: float):
    """The 28-image strip block of benchmarks/bench_plan.py (Type 3 control) written as a block folder."""
    from selfcal.block import prune
    from selfcal.io import write_block
    from selfcal.simulate import simulate_uav

    sim = simulate_uav(seed=1, distortion="none", points_per_mm2=points_per_mm2, n_strips=4, images_per_strip=7)
    folder = tmp_path_factory.mktemp("plan") / "block"
    write_block(prune(sim.blocks["type3"]), folder)
    return folder


@pytest.fixture(scope="module")
def block_folder(tmp_path_factory):
    """The 28-image strip block at 0.5 tie points per mm^2."""
    return _strip_block(tmp_path_factory, 0.5)


@pytest.fixture(scope="module")
def dense_block_folder(tmp_path_factory):
    """The same block at 1.75 tie points per mm^2 (39,982 observations): a block whose peak is mostly the WAPs'."""
    return _strip_block(tmp_path_factory, 1.75)


MEASURE = textwrap.dedent("""
    import json, resource, sys
    import selfcal
    from selfcal.adjust import AdjustOptions, APOptions, adjust
    from selfcal.allocator import keep_freed_memory
    from selfcal.io import read_block
    keep_freed_memory()
    result = adjust(read_block(sys.argv[1]), AdjustOptions(ap=APOptions(sys.argv[2])))
    result.Q_points
    result.image_sigma(), result.point_covariance()
    # this process's own peak: /proc's VmHWM is the peak of its address space since the exec; getrusage's ru_maxrss
    # also keeps the peak of the process it was forked from (Linux carries it over the exec), which in a test run is
    # pytest's, 1 GB after tests/test_cli.py
    with open("/proc/self/status") as status:
        hwm_kb = next(float(line.split()[1]) for line in status if line.startswith("VmHWM:"))
    print(json.dumps({"peak_mb": hwm_kb / 1024.0,
                      "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}))
""")


@pytest.mark.parametrize("ap, folder", [("none", "block_folder"), ("wavelet:db4", "dense_block_folder")])
def test_predicted_peak_matches_a_measured_adjustment(block_folder, request, ap, folder):
    """AP model none, and the 254 WAPs of db4 on 9x6, whose points' couplings with the AP columns the constants
    fitted without APs left out (their plan was 0.64 of the dense block's measured peak, 0.61-0.74 on the others).
    The plan is of a process whose Numba kernels are in the cache: a first run after an install compiles them,
    which added 33-137 MB to these blocks' db4 peaks (0.79-0.80 of the measured); a run on the small block first
    fills the cache, as any earlier run would."""
    from selfcal.io import read_block
    from selfcal.workflows.plan import plan_block

    block = request.getfixturevalue(folder)
    plan = plan_block(read_block(block), ap=ap, probe=False)
    assert plan.factorisation == "dense" and plan.covariance == "dense-inverse"
    assert (plan.memory_mb["ap_couplings"] > 0) == (ap != "none")
    subprocess.run([sys.executable, "-c", MEASURE, str(block_folder), ap], capture_output=True, text=True, check=True)
    out = subprocess.run([sys.executable, "-c", MEASURE, str(block), ap], capture_output=True, text=True,
                         check=True)
    measured = json.loads(out.stdout.strip().splitlines()[-1])["peak_mb"]
    assert abs(plan.peak_mb / measured - 1.0) <= PEAK_TOLERANCE, (plan.peak_mb, measured)


def test_paths_follow_the_engine():
    """The factorisation and covariance the plan names are the engine's choices for the sizes given."""
    from selfcal.stats.plan import BlockSizes, plan_adjustment

    def sizes(n_images, band):
        return BlockSizes(n_images=n_images, n_cameras=1, n_points=20 * n_images, n_observations=400 * n_images,
                          image_width=6, n_camera_parameters=3, n_ap=0, n_extra=0, image_pairs=18 * n_images,
                          band_images=band, factor_blocks=40 * n_images, factor_block_flops=2000.0 * n_images)
    assert plan_adjustment(sizes(200, 20)).factorisation == "dense"
    wide = plan_adjustment(sizes(2000, 60), cholmod=True)
    assert (wide.factorisation, wide.covariance) == ("cholmod", "selected-inverse")
    narrow = plan_adjustment(sizes(2000, 3), cholmod=True)          # n w^2 = 12003 * 24^2 < 1e9
    assert narrow.factorisation == "banded"
    no_band = plan_adjustment(sizes(2000, 1500), cholmod=True)       # wider than a quarter: no band
    assert (no_band.factorisation, no_band.covariance) == ("cholmod", "dense-inverse")
    assert no_band.memory_mb["covariance"] > 8 * wide.memory_mb["covariance"]


def test_plan_prints_the_table_and_json(block_folder, capsys):
    assert run_cli("plan", str(block_folder), "--ap", "none") == 0
    out = capsys.readouterr().out
    assert "peak / total" in out and "dense factorisation" in out
    assert run_cli("plan", str(block_folder), "--ap", "none", "--json") == 0
    document = json.loads(capsys.readouterr().out)
    assert document["command"] == "plan" and document["exit_code"] == 0
    figures = document["figures"]
    assert PLAN_KEYS <= set(figures)
    assert SIZE_KEYS <= set(figures["sizes"])
    assert set(figures["memory_mb"]) == {"base", "observations", "ap_columns", "ap_couplings", "reduced_system",
                                         "covariance"}
    assert abs(sum(figures["memory_mb"].values()) - figures["peak_mb"]) < 1e-6
    assert figures["sizes"]["n_images"] == 28


def test_default_ap_plans_the_widest_candidate(block_folder):
    """Without --ap a frame block's default is auto:none,brown: the plan takes brown's system (the larger)."""
    from selfcal.io import read_block
    from selfcal.workflows.plan import plan_block

    block = read_block(block_folder)
    default = plan_block(block, probe=False)
    assert default.ap_model == "brown (the widest of auto:none,brown)"
    assert default.sizes.n_ap > plan_block(block, ap="none", probe=False).sizes.n_ap == 0


def test_too_large_block_exits_2_before_any_work(block_folder, capsys, monkeypatch):
    import selfcal.workflows.plan as plan_module

    monkeypatch.setattr(plan_module, "available_mb", lambda: 50.0)
    assert run_cli("plan", str(block_folder), "--ap", "none", "--json") == 2
    captured = capsys.readouterr()
    assert "the machine has 0.0 GB available" in captured.err and "the block needs about 0." in captured.err
    document = json.loads(captured.out)
    assert document["exit_code"] == 2 and document["outcome"] is None and "the block needs about" in document["error"]
    # the plan it refused, part by part
    figures = document["figures"]
    assert figures["available_mb"] == 50.0 and figures["workflow_peak_mb"] > figures["peak_mb"] > 50.0
    assert abs(sum(figures["memory_mb"].values()) - figures["peak_mb"]) < 1e-6 * figures["peak_mb"]
    # room for one adjustment (about 200 MB) but not for selfcal adjust's default tests (about 340 MB)
    monkeypatch.setattr(plan_module, "available_mb", lambda: 280.0)
    assert run_cli("plan", str(block_folder), "--ap", "none") == 2
    captured = capsys.readouterr()
    assert "(selfcal adjust with its default tests)" in captured.err and captured.out == ""


def test_a_cluster_plan_gives_each_workers_peak_and_checks_the_local_ones(block_folder, capsys, monkeypatch):
    """``selfcal plan --scheduler local:2``: each worker's peak (its base and its share of the observations, fitted on
    benchmarks/bench_distributed.py's workers) beside the client's, one process's less what the shares hold for it;
    a local cluster's workers count against this machine's memory, a scheduler's elsewhere do not."""
    import selfcal.workflows.plan as plan_module

    assert run_cli("plan", str(block_folder), "--ap", "none", "--scheduler", "local:2", "--json") == 0
    figures = json.loads(capsys.readouterr().out)["figures"]
    share = figures["sizes"]["n_observations"] / 2
    assert figures["workers"] == 2 and figures["scheduler"] == "local:2"
    assert figures["worker_peak_mb"] == pytest.approx(203.4 + 705.0 * share / 2 ** 20, rel=1e-9)
    assert figures["worker_workflow_peak_mb"] == pytest.approx(203.4 + 2 * 705.0 * share / 2 ** 20, rel=1e-9)
    shed = 39.4 + 442.0 * 2 * share / 2 ** 20
    assert figures["client_peak_mb"] == pytest.approx(figures["peak_mb"] - shed, rel=1e-9)
    assert figures["client_workflow_peak_mb"] == figures["workflow_peak_mb"]
    assert run_cli("plan", str(block_folder), "--ap", "none", "--scheduler", "local:2") == 0
    table = capsys.readouterr().out
    assert "each worker" in table and "client" in table
    # room for the client's tested workflow, not for it and two local workers beside it
    room = figures["client_workflow_peak_mb"] + figures["worker_workflow_peak_mb"]
    monkeypatch.setattr(plan_module, "available_mb", lambda: room)
    assert run_cli("plan", str(block_folder), "--ap", "none", "--scheduler", "local:2") == 2
    assert "and 2 local workers of" in capsys.readouterr().err
    assert run_cli("plan", str(block_folder), "--ap", "none") == 0
    capsys.readouterr()
    assert run_cli("plan", str(block_folder), "--scheduler", "local:x") == 2
    assert "--scheduler local:N needs a whole number of workers" in capsys.readouterr().err
    for address in ("tcp://", "tcp://host", "localhost:99999", "xyz"):      # refused as written, before any connection
        assert run_cli("plan", str(block_folder), "--scheduler", address) == 2
        assert f"a scheduler's address with its port (tcp://host:8786), found '{address}'" in capsys.readouterr().err


def test_missing_block_folder_exits_2_naming_it(tmp_path, capsys):
    missing = tmp_path / "no-such-block"
    assert run_cli("plan", str(missing)) == 2
    err = capsys.readouterr().err
    assert str(missing) in err and "not found" in err
