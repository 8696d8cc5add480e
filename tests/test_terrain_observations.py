"""Terrain heights from a DEM as observations of tie points (issue 42 item 2; DESIGN-NOTES "Terrain as
observations"): the heights they improve, the variance component that finds the DEM's noise, data snooping that
flags a biased area, the agreement of the DEM's interpolation with GDAL's, nothing changed without them, the CLI."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from conftest import run_cli
from selfcal.adjust import AdjustOptions, RobustOptions, SensorOptions
from selfcal.block import TerrainObservations
from selfcal.geometry.earth import geodetic_from_ecef
from selfcal.geometry.terrain import GridDem
from selfcal.simulate.prism import TRUE_FOCAL_MM, dem_grid, prism_block, simulate_prism
from selfcal.stats import SnoopingOptions, VarianceOptions
from selfcal.workflows.seed001 import choose_gcps, with_focal
from selfcal.workflows.tested import adjust_with_tests

M6 = AdjustOptions(sensor=SensorOptions(model="M6"))


def _tie_block(sim, n_gcp: int = 3):
    """The simulated PRISM triplet with ``n_gcp`` control points, every tenth other point a check point and the
    rest tie points without coordinates (the simulator makes every non-control point a check point); the true
    focal lengths (the focal-length step of seed 001 is not what is tested here)."""
    block = with_focal(prism_block(sim), TRUE_FOCAL_MM)
    gcps = choose_gcps(block, n_gcp)
    role = np.full(len(block.points), "tie", object)
    role[np.arange(len(role)) % 10 == 5] = "chk"
    role[gcps] = "gcp"
    xyz = np.where((role == "tie")[:, None], np.nan, block.points.xyz_m)
    return replace(block, points=replace(block.points, role=role, xyz_m=xyz))


def _noisy_dem(sim, sigma_cell_m: float, seed: int = 7) -> GridDem:
    dem = dem_grid(sim)
    rng = np.random.default_rng(seed)
    return GridDem(dem.heights_m + rng.normal(0.0, sigma_cell_m, dem.heights_m.shape), dem.transform)


def _tie_height_errors(sim, tested) -> np.ndarray:
    result = tested.result
    tie = np.flatnonzero(result.block.points.role == "tie")
    truth = sim.points_ecef[[sim.point_ids.index(p) for p in result.block.points.point_id[tie]]]
    return geodetic_from_ecef(result.state.points[tie])[2] - geodetic_from_ecef(truth)[2]


@pytest.fixture(scope="module")
def triplet():
    sim = simulate_prism(seed=3, n_points=400)
    return sim, _tie_block(sim)


def _heights_with_and_without(sim, block, surface, sigma_m: float):
    """The tie points' height errors without and with ``surface``'s heights as observations at ``sigma_m`` (variance
    components estimated): RMS without, RMS with, the tested adjustment with them, the terrain rows, the estimated
    sigma of the terrain group and the true RMS of the surface's heights at the observed tie points."""
    without = adjust_with_tests(block, M6, snooping=None, robust=None)
    terrain = replace(block, terrain_observations=TerrainObservations(surface, sigma_m))
    tested = adjust_with_tests(terrain, M6, snooping=None, robust=None, variance=VarianceOptions())
    rms0, rms1 = (float(np.sqrt(np.mean(_tie_height_errors(sim, t) ** 2))) for t in (without, tested))
    rows = tested.result.problem.terrain
    lat, lon, h = geodetic_from_ecef(sim.points_ecef)
    index = [sim.point_ids.index(p) for p in tested.result.block.points.point_id[rows.index]]
    true_sigma = float(np.sqrt(np.mean((surface(np.degrees(lat), np.degrees(lon)) - h)[index] ** 2)))
    estimated = {c.group: c for c in tested.variance_components}["terrain"].sigma_aposteriori[0]
    return rms0, rms1, tested, rows, estimated, true_sigma


def test_terrain_heights_improve_the_tie_points_and_their_variance_component_finds_the_dem_noise(triplet):
    sim, block = triplet
    dem = _noisy_dem(sim, 2.0)                       # 2 m per cell: about 1.3 m at a point, bilinearly
    rms0, rms1, tested, rows, estimated, true_sigma = _heights_with_and_without(sim, block, dem, 1.0)   # 1 m given
    components = {c.group: c for c in tested.variance_components}
    print(f"tie heights RMS {rms0:.3f} m without, {rms1:.3f} m with {len(rows)} terrain heights; terrain sigma "
          f"estimated {estimated:.3f} m, true {true_sigma:.3f} m; image scale {components['image'].scale:.3f}")
    assert tested.result.converged and len(rows) > 300
    assert rms1 < 0.6 * rms0                         # measured 1.83 -> 0.81 m
    assert abs(components["image"].scale - 1.0) < 0.1 and abs(tested.result.sigma0_px / 0.3 - 1.0) < 0.1
    assert components["terrain"].estimated and abs(estimated / true_sigma - 1.0) < 0.2


def test_data_snooping_flags_a_biased_patch_of_the_dem():
    # 0.1 px: the rays fix a tie point's height to about 0.4 m; a 5 m error of a height with sigma 0.5 m is then
    # beyond its minimal detectable blunder (at 0.3 px the rays' 1.1 m alone make that about 5.7 m)
    sim = simulate_prism(seed=3, n_points=400, image_sigma_px=0.1)
    block = _tie_block(sim)
    dem = _noisy_dem(sim, 0.5)
    lat, lon, _ = geodetic_from_ecef(sim.points_ecef)
    lat, lon = np.degrees(lat), np.degrees(lon)
    lat0, lat1 = np.quantile(lat, [0.25, 0.65])
    lon0, lon1 = np.quantile(lon, [0.2, 0.6])
    a, _, c, _, e, f = dem.transform
    rows, cols = dem.heights_m.shape
    cell_lat, cell_lon = f + e * (np.arange(rows) + 0.5), c + a * (np.arange(cols) + 0.5)
    patch = ((cell_lat >= lat0) & (cell_lat <= lat1))[:, None] & ((cell_lon >= lon0) & (cell_lon <= lon1))[None, :]
    biased = GridDem(dem.heights_m + 5.0 * patch, dem.transform)
    bias = biased(lat, lon) - dem(lat, lon)            # at each point: 5 inside, 0 outside, between on the rim
    terrain = replace(block, terrain_observations=TerrainObservations(biased, 0.5))
    where = {p: k for k, p in enumerate(sim.point_ids)}
    # least squares, and the robust cleaning first as selfcal adjust does by default (which must not cut the rays
    # of the patch's points instead: its adjustment leaves the terrain heights out)
    for robust in (None, RobustOptions()):
        tested = adjust_with_tests(terrain, M6, snooping=SnoopingOptions(), robust=robust)
        observed = tested.result.block.terrain_observations.point_ids
        flagged = {p for p, _ in tested.terrain_rejected}
        inside = [p for p in observed if bias[where[p]] > 5.0 - 1e-9]
        outside = [p for p in observed if abs(bias[where[p]]) < 1e-9]
        hit = sum(p in flagged for p in inside) / len(inside)
        false = sum(p in flagged for p in outside) / len(outside)
        print(f"{'robust, ' if robust else ''}patch: {sum(p in flagged for p in inside)} of {len(inside)} flagged "
              f"({100 * hit:.1f} %); elsewhere {sum(p in flagged for p in outside)} of {len(outside)} "
              f"({100 * false:.1f} %); rims left out: {len(observed) - len(inside) - len(outside)}; "
              f"{len(tested.rejected_rows)} image observations rejected")
        assert len(inside) >= 30 and len(outside) >= 200
        assert hit >= 0.9 and false <= 0.02 and len(tested.rejected_rows) < 10
    assert tested.result.problem.terrain is not None
    kept = set(tested.result.block.points.point_id[tested.result.problem.terrain.index])
    assert not kept & flagged                          # rejected: no row in the final adjustment
    from selfcal.io.results import results_from_files
    from selfcal.report import render_report, result_files
    files = result_files(terrain, tested)
    header, columns, _ = files["terrain.csv"]
    status = dict(zip(columns[0], columns[header.index("status")]))
    assert {p for p, s in status.items() if s == "rejected"} == flagged
    assert files["summary.json"]["terrain_observations"]["n_rejected"] == len(flagged)
    html = render_report(results_from_files(files))["report.html"]
    assert "terrain-rejected" in html and "Terrain as observations" in html


def test_dem_heights_agree_with_gdal_bilinear_interpolation(tmp_path):
    """Our bilinear interpolation between cell centres against GDAL's warper (rasterio.warp.reproject with
    bilinear resampling onto a finer grid at odd offsets: its kernel unscaled, each output cell the interpolation
    at its centre), the GeoTIFF written by selfcal.io.dem.write_dem and read back by read_dem."""
    import rasterio
    from rasterio.transform import Affine
    from rasterio.warp import Resampling, reproject

    from selfcal.io.dem import read_dem, write_dem
    rng = np.random.default_rng(1)
    heights = rng.uniform(100.0, 900.0, (60, 80)).astype(np.float32).astype(float)
    write_dem(tmp_path / "dem.tif", GridDem(heights, (0.01, 0.0, 5.0, 0.0, -0.008, 45.0)))
    dem = read_dem(tmp_path / "dem.tif")
    dx, dy = 0.0037, -0.0029                                  # output cells: about a third of the DEM's
    x0, y0 = 5.0 + 0.005 + 0.00123, 45.0 - 0.004 - 0.00071   # inside the outermost cell centres, at odd offsets
    cols, rows = int(0.78 / dx), int(0.464 / -dy)
    gdal = np.full((rows, cols), np.nan)
    with rasterio.open(tmp_path / "dem.tif") as source:
        reproject(rasterio.band(source, 1), gdal, dst_transform=Affine(dx, 0.0, x0, 0.0, dy, y0),
                  dst_crs=source.crs, resampling=Resampling.bilinear, dst_nodata=np.nan)
    lon = x0 + dx * (np.arange(cols) + 0.5)
    lat = y0 + dy * (np.arange(rows) + 0.5)
    ours = dem(lat[:, None], lon[None, :])
    half = GridDem(dem.heights_m, (0.01, 0.0, 5.005, 0.0, -0.008, 45.0))(lat[:, None], lon[None, :])
    diff = float(np.max(np.abs(gdal - ours)))
    print(f"{gdal.size} heights: largest difference from GDAL's bilinear {diff:.2e} m; with the grid half a cell "
          f"off {float(np.max(np.abs(gdal - half))):.1f} m")
    assert np.isfinite(gdal).all() and diff < 1e-6
    assert np.max(np.abs(gdal - half)) > 10.0        # the test sees the half-pixel convention


def test_terrain_rows_jacobian_matches_finite_differences():
    from selfcal.adjust.residuals.terrain import TerrainHeights
    from selfcal.geometry.earth import ecef_from_geodetic
    sim = simulate_prism(seed=3, n_points=28)
    dem = dem_grid(sim)
    lat, lon, h = geodetic_from_ecef(sim.points_ecef)
    points = ecef_from_geodetic(lat, lon, h + 3.0)
    rows = TerrainHeights(np.arange(len(points)), dem, 0.7)
    r, J = rows.whitened_rows(points)
    assert np.allclose(r[:, 0], -3.0 / 0.7, atol=0.05)
    step = 0.01
    numeric = np.stack([(rows.whitened_rows(points + step * np.eye(3)[k])[0]
                         - rows.whitened_rows(points - step * np.eye(3)[k])[0])[:, 0] / (2 * step)
                        for k in range(3)], -1)
    assert np.allclose(-numeric, J[:, 0], atol=1e-4 * np.abs(J).max())    # J = df/dX, r = (l - f) / sigma


def test_without_terrain_observations_nothing_changes(triplet):
    from selfcal.adjust.problem import build_problem
    from selfcal.adjust.residuals import RESIDUALS
    from selfcal.report import result_files
    _, block = triplet
    assert block.terrain_observations is None
    problem = build_problem(block, M6)
    kinds = [type(b).__name__ for b in problem.residuals]
    assert "TerrainHeights" not in kinds and problem.terrain is None
    assert list(RESIDUALS) == ["control", "terrain", "priors", "trajectory"]
    assert kinds == [type(b).__name__ for name, build in RESIDUALS.items() if name != "terrain"
                     for b in build(block, problem, _settings())]
    tested = adjust_with_tests(block, M6, robust=None)
    assert tested.tests.terrain_w.size == 0 and tested.terrain_rejected == []
    files = result_files(block, tested)
    assert "terrain.csv" not in files and "terrain_observations" not in files["summary.json"]
    assert not any(n.startswith("terrain") for n in tested.result.notes)


def _settings():
    from selfcal.adjust.residuals import ResidualSettings
    return ResidualSettings("ECEF")


@pytest.fixture(scope="module")
def block_folder(tmp_path_factory):
    """A PRISM triplet (100 points: 5 GCPs, a third of the others check points, the rest tie points) written as
    a block folder with its DEM (block.toml [terrain] dem), and the same DEM in UTM."""
    from selfcal.io.block_folder import write_block
    from selfcal.io.dem import write_dem
    folder = tmp_path_factory.mktemp("terrain")
    sim = simulate_prism(seed=3, n_points=100)
    block = prism_block(sim)
    role = np.asarray(block.points.role).copy()
    role[(role == "chk") & (np.arange(len(role)) % 3 != 0)] = "tie"
    xyz = np.where((role == "tie")[:, None], np.nan, block.points.xyz_m)
    block = replace(block, points=replace(block.points, role=role, xyz_m=xyz))
    write_block(block, folder / "triplet")
    write_dem(folder / "triplet" / "dem.tif", dem_grid(sim, 0.001))
    return folder


def test_cli_adjust_with_terrain_observations(block_folder, capsys):
    out = block_folder / "results"
    code = run_cli("adjust", str(block_folder / "triplet"), "--out", str(out), "--terrain-observations",
                   "--terrain-sigma-m", "1", "--variance-components", "--no-report", "--quiet")
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    terrain = summary["terrain_observations"]
    assert terrain["dem"].endswith("dem.tif") and terrain["sigma_apriori_m"] == 1.0 and terrain["n_used"] > 30
    groups = {g["group"]: g for g in summary["variance_components"]["groups"]}
    assert groups["terrain"]["n_observations"] == terrain["n_used"]
    lines = (out / "terrain.csv").read_text().splitlines()
    assert lines[0] == "point_id,status,lat_deg,lon_deg,h_m,dem_h_m,v_m,sigma_m,redundancy,w"
    assert len(lines) - 1 == terrain["n_used"] + terrain["n_rejected"] + terrain["n_off_dem"]
    roles = dict(line.split(",")[:2] for line in (out / "points.csv").read_text().splitlines()[1:])
    assert all(roles[line.split(",")[0]] == "tie" for line in lines[1:])          # no control, no check point


def test_cli_terrain_observations_refuse_what_they_cannot_use(block_folder, tmp_path, capsys):
    import rasterio
    from rasterio.transform import Affine
    block = str(block_folder / "triplet")
    assert run_cli("adjust", block, "--out", str(tmp_path / "a"), "--terrain-observations",
                   str(tmp_path / "missing.tif"), "--terrain-sigma-m", "1", "--quiet") == 2
    assert "missing.tif" in capsys.readouterr().err
    utm = tmp_path / "utm.tif"
    with rasterio.open(utm, "w", driver="GTiff", width=4, height=4, count=1, dtype="float32", crs="EPSG:32654",
                       transform=Affine(30.0, 0.0, 500000.0, 0.0, -30.0, 4000000.0)) as target:
        target.write(np.zeros((4, 4), np.float32), 1)
    assert run_cli("adjust", block, "--out", str(tmp_path / "b"), "--terrain-observations", str(utm),
                   "--terrain-sigma-m", "1", "--quiet") == 2
    err = capsys.readouterr().err
    assert "utm.tif" in err and "EPSG:4326" in err
    assert run_cli("adjust", block, "--out", str(tmp_path / "c"), "--terrain-observations", "--quiet") == 2
    assert "--terrain-sigma-m" in capsys.readouterr().err
    code = run_cli("adjust", block, "--out", str(tmp_path / "d"), "--terrain-observations", "--terrain-sigma-m", "1",
                   "--terrain-datum", "egm96", "--quiet")
    err = capsys.readouterr().err
    if code == 2:                                    # (PROJ without the EGM96 grid: offline, the usual case)
        assert "us_nga_egm96_15.tif" in err and "dem.tif" in err
    else:
        assert code == 0


def test_cli_terrain_observations_refuse_a_frame_block(tmp_path, capsys):
    from conftest import pruned, simulation
    from selfcal.io.block_folder import write_block
    from selfcal.io.dem import write_dem
    write_block(pruned(simulation(1), "type3"), tmp_path / "frame")
    write_dem(tmp_path / "dem.tif", GridDem(np.zeros((3, 3)), (0.1, 0.0, 5.0, 0.0, -0.1, 45.0)))
    assert run_cli("adjust", str(tmp_path / "frame"), "--out", str(tmp_path / "out"), "--terrain-observations",
                   str(tmp_path / "dem.tif"), "--terrain-sigma-m", "1", "--quiet") == 2
    assert "need points in ECEF" in capsys.readouterr().err


# --- a ground point cloud as the terrain (issue 42 item 2 (b)) ---------------------------------------------------

def _cloud_over(sim, n: int, noise_m: float, seed: int = 11):
    """``n`` ground points spread over the scene (and 0.02 degrees around it) on the simulated terrain, with
    ``noise_m`` of height noise each: (lat_deg, lon_deg, h_m)."""
    lat, lon, _ = geodetic_from_ecef(sim.points_ecef)
    lat, lon = np.degrees(lat), np.degrees(lon)
    rng = np.random.default_rng(seed)
    cloud_lat = rng.uniform(lat.min() - 0.02, lat.max() + 0.02, n)
    cloud_lon = rng.uniform(lon.min() - 0.02, lon.max() + 0.02, n)
    return cloud_lat, cloud_lon, sim.dem(cloud_lat, cloud_lon) + rng.normal(0.0, noise_m, n)


def test_cloud_surface_follows_the_terrain():
    from selfcal.geometry.cloud import CloudSurface
    from selfcal.geometry.earth import ecef_from_geodetic
    from selfcal.simulate.prism import AnalyticDem
    terrain = AnalyticDem()                            # a lidar-like cloud: 40,000 points on 11 x 9 km (50 m apart)
    rng = np.random.default_rng(2)
    lat = terrain.lat0_deg + rng.uniform(-0.05, 0.05, 40_000)
    lon = terrain.lon0_deg + rng.uniform(-0.05, 0.05, 40_000)
    h = terrain(lat, lon)
    surface = CloudSurface(lat, lon, h)
    sim = type("Sim", (), {"dem": terrain})
    q_lat, q_lon = rng.uniform(lat.min() + 0.03, lat.max() - 0.03, 400), rng.uniform(lon.min() + 0.03,
                                                                                       lon.max() - 0.03, 400)
    height = np.abs(surface(q_lat, q_lon) - sim.dem(q_lat, q_lon)).max()
    step = 1e-6
    slope = np.stack([(sim.dem(q_lat + step, q_lon) - sim.dem(q_lat - step, q_lon)) / (2 * step),
                      (sim.dem(q_lat, q_lon + step) - sim.dem(q_lat, q_lon - step)) / (2 * step)])
    fitted = np.stack(surface.gradient(q_lat, q_lon))
    print(f"cloud of 40,000 points (gap {surface.max_gap_m:.0f} m): heights within {height:.3f} m of the terrain, "
          f"slopes within {np.abs(fitted - slope).max() / np.abs(slope).max():.1%} of the steepest")
    assert height < 0.1 and np.abs(fitted - slope).max() < 0.05 * np.abs(slope).max()
    assert surface.covers(q_lat, q_lon).all() and not surface.covers(np.array([lat.max() + 0.1]),
                                                                      np.array([lon.mean()])).any()
    ecef = CloudSurface.from_ecef(ecef_from_geodetic(np.radians(lat), np.radians(lon), h))
    assert np.allclose(ecef(q_lat, q_lon), surface(q_lat, q_lon), atol=1e-6)


def test_point_cloud_heights_improve_the_tie_points_and_their_variance_component_finds_the_noise(triplet):
    from selfcal.geometry.cloud import CloudSurface
    sim, block = triplet
    cloud = CloudSurface(*_cloud_over(sim, 50_000, 2.0))     # 2 m per point: about 0.9 m for a plane of 8
    rms0, rms1, tested, rows, estimated, true_sigma = _heights_with_and_without(sim, block, cloud, 1.0)
    print(f"tie heights RMS {rms0:.3f} m without, {rms1:.3f} m with {len(rows)} cloud heights; sigma estimated "
          f"{estimated:.3f} m, true {true_sigma:.3f} m")
    assert tested.result.converged and len(rows) > 300
    assert rms1 < 0.6 * rms0
    assert abs(estimated / true_sigma - 1.0) < 0.2


def test_cli_adjust_with_a_point_cloud(block_folder, tmp_path, capsys):
    sim = simulate_prism(seed=3, n_points=100)
    lat, lon, h = _cloud_over(sim, 20_000, 0.3)
    cloud = tmp_path / "cloud.csv"
    cloud.write_text("lat_deg,lon_deg,h_m\n" + "".join(f"{a:.9f},{b:.9f},{c:.3f}\n" for a, b, c in zip(lat, lon, h)))
    out = tmp_path / "results"
    assert run_cli("adjust", str(block_folder / "triplet"), "--out", str(out), "--terrain-cloud", str(cloud),
                   "--terrain-sigma-m", "0.5", "--no-report", "--quiet") == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["terrain_observations"]["surface"] == "cloud" and summary["terrain_observations"]["n_used"] > 30
    assert (out / "terrain.csv").exists()
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y,z\n1,2,3\n")
    assert run_cli("adjust", str(block_folder / "triplet"), "--out", str(tmp_path / "b"), "--terrain-cloud",
                   str(bad), "--terrain-sigma-m", "0.5", "--quiet") == 2
    assert "bad.csv" in capsys.readouterr().err
    assert run_cli("adjust", str(block_folder / "triplet"), "--out", str(tmp_path / "c"), "--terrain-cloud",
                   str(cloud), "--terrain-observations", "--terrain-sigma-m", "0.5", "--quiet") == 2
    assert "one terrain at a time" in capsys.readouterr().err
