"""The scenario x model matrix: serial and on a local Dask cluster of two workers give the same numbers."""
import numpy as np
import pytest

from selfcal.batch import CellSettings, run_matrix
from selfcal.report.compare import comparison_markdown, comparison_rows

from conftest import pruned, simulation


@pytest.fixture(scope="module")
def blocks():
    sim = simulation(seed=6, distortion="local", points_per_mm2=0.25, blunder_rate=0.002)
    return {name: pruned(sim, name) for name in ("type1", "type2")}


@pytest.mark.slow
def test_dask_matrix_equals_serial(blocks):
    settings = CellSettings()
    serial = run_matrix(blocks, ["none"], settings, scheduler=None)
    seen = []
    parallel = run_matrix(blocks, ["none"], settings, scheduler="local", n_workers=2, done=seen.append)
    assert len(seen) == 2
    assert [(c.scenario, c.model) for c in serial] == [(c.scenario, c.model) for c in parallel]
    for a, b in zip(serial, parallel):
        assert a.error is None and b.error is None
        sa, sb = a.files["summary.json"], b.files["summary.json"]
        for key in ("sigma0_px", "rmsd_chk_xy_m", "rmsd_chk_z_m", "rms_sigma_tie_xy_m", "n_obs_rejected"):
            assert sa[key] == pytest.approx(sb[key], rel=1e-9, abs=1e-12), key
        np.testing.assert_allclose(a.files["points.csv"][1][2], b.files["points.csv"][1][2], rtol=0, atol=1e-9)


def test_comparison_table_columns(blocks):
    cells = run_matrix(blocks, ["none"], CellSettings(), scheduler=None)
    rows = comparison_rows(cells)
    assert [r["scenario"] for r in rows] == ["type1", "type2"]
    assert rows[0]["gcp_chk"].count("/") == 1 and rows[0]["reduction_xy_pct"] == 0.0
    text = comparison_markdown(rows)
    assert "RMSD XY (GSD)" in text and "type2 | none" in text
