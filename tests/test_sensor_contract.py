"""The sensor contract (selfcal.sensors.base), for every sensor of the registry: the analytic Jacobians of
the prediction against central differences (image parameters, camera core parameters, object point), the
image -> object -> image round trip through the rays, and the declared parameters (unique names, known
units and groups). A sensor added to SENSORS without an example block here fails the first test."""
import os

import numpy as np
import pytest

from selfcal.adjust import AdjustOptions, APOptions, SensorOptions
from selfcal.adjust.initial import initial_state
from selfcal.adjust.residuals.image import contexts, predict
from selfcal.adjust.problem import build_problem
from selfcal.block import prune
from selfcal.sensors import SENSORS

from conftest import SHARED_DATA

UNITS = {"m", "rad", "rad/s", "mm", "ms", "px", ""}


def _frame():
    from selfcal.simulate import simulate_uav
    return prune(simulate_uav(seed=3, points_per_mm2=0.3).blocks["type3"]), AdjustOptions(ap=APOptions("none"))


def _frame_rolling():
    """A rolling shutter (33 ms at 8 m/s, serpentine) with the attitude turning during the readout too (its rate
    from the images' IMU attitudes): every term of the model's Jacobians."""
    from dataclasses import replace
    from selfcal.simulate import simulate_uav
    block = prune(simulate_uav(seed=3, points_per_mm2=0.3, flight="serpentine", rolling_shutter_ms=33.0)
                  .blocks["type2"])
    camera = block.cameras["ilce7m3"]
    return replace(block, cameras={"ilce7m3": replace(camera, readout_rotation=True)}), \
        AdjustOptions(ap=APOptions("none"))


def _bal():
    from selfcal.convert import block_from_bal
    from selfcal.io.bal import read_bal
    return block_from_bal(read_bal(os.path.join(SHARED_DATA, "bal", "dubrovnik-3-7-pre.txt"))), AdjustOptions()


def _opencv():
    """A chessboard calibration with OpenCV's rational model (selfcal.simulate.chessboard): 6 poses of 80 corners."""
    from selfcal.simulate.chessboard import simulate_chessboard
    return simulate_chessboard(seed=2, n_frames=6).block, AdjustOptions(ap=APOptions("none"))


def _pushbroom():
    from selfcal.simulate.prism import prism_block, simulate_prism
    return prism_block(simulate_prism(seed=1), seed=1), AdjustOptions(sensor=SensorOptions(model="M7"))


def _rpc():
    """One Pleiades RPC image and 12 ground points on it (ECEF)."""
    from selfcal.block import Block, Images, Observations, Points
    from selfcal.sensors.rpc import RpcCamera
    from selfcal.geometry.earth import ecef_from_geodetic
    from selfcal.io.rpc import read_rpc
    model = read_rpc(os.path.join(SHARED_DATA, "pushbroom", "pleiades", "rpc",
                                  "PHR1B_P_201709281038393_SEN_PRG_FC_178609-001.geom"))
    rng = np.random.default_rng(0)
    row = model.line_off + model.line_scale * rng.uniform(-0.8, 0.8, 12)
    col = model.samp_off + model.samp_scale * rng.uniform(-0.8, 0.8, 12)
    h = rng.uniform(100, 1000, 12)
    lon, lat = model.localize(row, col, h)
    xyz = ecef_from_geodetic(np.radians(lat), np.radians(lon), h)
    nan3 = np.full((1, 3), np.nan)
    block = Block("rpc", "EPSG:4978", {"c": RpcCamera("c", "affine")},
                  Images(np.array(["i"], object), np.array(["c"], object), np.array([""], object), np.array([np.nan]),
                         nan3, nan3, np.array([2])),
                  Points(np.array([f"p{k}" for k in range(12)], object), np.full(12, "gcp", object), xyz,
                         np.full((12, 3), 0.5), np.arange(12)),
                  Observations(np.zeros(12, np.int64), np.arange(12), np.column_stack([col, row]), np.full(12, 0.5),
                               np.arange(12)), 0.5, image_models={"i": model})
    return block, AdjustOptions()


def _usgscsm():
    """The Apollo 15 Metric network (frame ISDs) through selfcal import isis and the block folder."""
    import tempfile
    from selfcal.convert import block_from_isis
    from selfcal.io import read_block
    from selfcal.io.block_folder import write_block
    from selfcal.io.isis import read_control_network, read_image_folder
    folder = os.path.join(SHARED_DATA, "isis", "apollo15_metric")
    block, _ = block_from_isis(read_control_network(os.path.join(folder, "apolloNet.pvl")), read_image_folder(folder),
                               camera_settings={"sigma_position_m": 1000.0, "sigma_attitude_deg": 2.0})
    out = os.path.join(tempfile.mkdtemp(), "apollo")
    write_block(block, out)
    return read_block(out), AdjustOptions()


def _usgscsm_line():
    """The LRO NAC pair (line-scan ISDs) through selfcal import isis and the block folder, attitude of degree 3."""
    import tempfile
    from selfcal.convert import block_from_isis
    from selfcal.io import read_block
    from selfcal.io.block_folder import write_block
    from selfcal.io.isis import read_control_network, read_image_folder
    from selfcal.workflows.isis import hold_radii
    folder = os.path.join(SHARED_DATA, "isis", "lro_nac_pair")
    block, _ = block_from_isis(read_control_network(os.path.join(folder, "observationPair.net")),
                               read_image_folder(folder), 0.5,
                               camera_settings={"sigma_attitude_deg": 1.0, "attitude_degree": 3,
                                                "position_offsets": True, "sigma_position_m": 100.0})
    out = os.path.join(tempfile.mkdtemp(), "lro")
    write_block(block, out)
    return hold_radii(read_block(out), 1.0), AdjustOptions()


def _vendor(model, files):
    """Vendor line images (their metadata files as sensor_file) through a block folder, 15 ground points each."""
    import tempfile
    from selfcal.io import read_block
    from selfcal.sensors.pushbroom import ground_to_image, image_to_ground
    from selfcal.sensors.vendor import line_image_from_file
    folder = tempfile.mkdtemp()
    rng = np.random.default_rng(2)
    first = line_image_from_file(files[0], "a")
    ground = image_to_ground(first, rng.uniform(0.1, 0.9, 15) * first.rows,
                             rng.uniform(0.1, 0.9, 15) * first.camera.columns, rng.uniform(0, 300, 15))
    rows = []
    for k, path in enumerate(files):
        row, col = ground_to_image(line_image_from_file(path, f"i{k}"), ground)
        rows += [f"i{k},p{j},{col[j]:.3f},{row[j]:.3f}\n" for j in np.flatnonzero(np.isfinite(row))]
    with open(os.path.join(folder, "block.toml"), "w") as f:
        f.write(f'name = "v"\ncrs = "EPSG:4978"\n[cameras.c]\nmodel = "{model}"\n[observations]\nimage_sigma_px = 0.5\n')
    with open(os.path.join(folder, "images.csv"), "w") as f:
        f.write("image_id,camera_id,strip_id,time_s,X0,Y0,Z0,omega_deg,phi_deg,kappa_deg,sensor_file\n")
        f.writelines(f"i{k},c,,,,,,,,,{path}\n" for k, path in enumerate(files))
    with open(os.path.join(folder, "points.csv"), "w") as f:
        f.write("point_id,role,X,Y,Z,sigma_xy_m,sigma_z_m\n")
        f.writelines(f"p{j},gcp,{x:.3f},{y:.3f},{z:.3f},0.5,0.5\n" for j, (x, y, z) in enumerate(ground))
    with open(os.path.join(folder, "observations.csv"), "w") as f:
        f.write("image_id,point_id,col_px,row_px\n")
        f.writelines(rows)
    return read_block(folder), AdjustOptions(sensor=SensorOptions(model="M7"))


def _dimap():
    return _vendor("dimap", [os.path.join(SHARED_DATA, "pushbroom", "pleiades", "rpc",
                                          "PHRDIMAP_P1BP--2017030824934340CP.XML")])


def _dg():
    folder = os.path.join(SHARED_DATA, "pushbroom", "asp_dg_spot")
    return _vendor("dg", [os.path.join(folder, "dg_example1.xml"), os.path.join(folder, "dg_example2.xml")])


EXAMPLES = {"dimap": _dimap, "dg": _dg, "frame": _frame, "frame-rolling": _frame_rolling, "bal": _bal,
            "opencv": _opencv, "pushbroom": _pushbroom, "rpc": _rpc, "usgscsm": _usgscsm, "usgscsm-line": _usgscsm_line}


def test_every_registered_sensor_has_an_example():
    assert set(SENSORS) <= set(EXAMPLES), f"add an example block for {sorted(set(SENSORS) - set(EXAMPLES))}"


@pytest.fixture(scope="module", params=sorted(EXAMPLES))
def bound(request):
    block, options = EXAMPLES[request.param]()
    problem = build_problem(block, options)
    state, _ = initial_state(problem, block)
    # move every parameter off its start a little, so no derivative is taken at a special point
    rng = np.random.default_rng(1)
    state.image += rng.normal(0, 1e-4, state.image.shape) * np.where(np.abs(state.image) > 1, np.abs(state.image), 1)
    for slot in problem.sensors:
        slot.bound.refine_sigma(state, problem.obs_sigma)
    return request.param, problem, state


def test_parameters_are_declared_with_units_and_groups(bound):
    name, problem, _ = bound
    sensor = SENSORS[name]
    for block in (sensor.image_parameters, sensor.camera_parameters):
        names = [p.name for p in block]
        assert len(set(names)) == len(names)
        assert all(p.unit in UNITS for p in block) and all(p.group in ("EOP", "IOP") for p in block)
        assert len({p.file_key for p in block}) == len(block)
    assert problem.image_width == len(sensor.image_parameters)
    assert all(c.n_core == len(sensor.camera_parameters) for c in problem.cameras)


def _central(f, x, h):
    return (f(x + h) - f(x - h)) / (2 * h)


def _assert_derivative(analytic, f, h, scale, message):
    """``analytic`` against central differences of ``f`` at 0 with step h and 10 h, each element within 1e-5 relative
    (1e-9 of ``scale`` absolute) of either: the smaller step's rounding (a prediction with an iterative solution
    inside, usgscsm's line time, is reproducible to ~1e-13 of its value, which a step of 1e-6 turns into 1e-7 of a
    derivative) and the larger step's truncation do not both err where the analytic column is right."""
    small, large = _central(f, 0.0, h), _central(f, 0.0, 10.0 * h)
    ok = (np.abs(analytic - small) <= 1e-9 * scale + 1e-5 * np.abs(small)) | \
        (np.abs(analytic - large) <= 1e-9 * scale + 1e-5 * np.abs(large))
    bad = np.flatnonzero(~ok.ravel())
    assert not bad.size, (f"{message}: {bad.size} of {ok.size} elements, e.g. analytic {analytic.ravel()[bad[0]]!r}, "
                          f"steps h, 10 h: {small.ravel()[bad[0]]!r}, {large.ravel()[bad[0]]!r}")


def test_jacobians_match_central_differences(bound):
    """Every column of the image, core and point Jacobians within 1e-5 relative of central differences."""
    name, problem, state = bound
    o0, o1 = 0, min(problem.n_image_observations, 60)
    points = state.points[problem.obs_point[o0:o1]]
    f, j_e, j_p, j_c = predict(problem, contexts(problem, state), o0, o1, points, jacobians=True)
    img = problem.obs_image[o0:o1]
    cam = problem.image_camera[img]

    def evaluate(new_state, pts=points):
        return predict(problem, contexts(problem, new_state, jacobians=False), o0, o1, pts, jacobians=False)

    scale = np.abs(f).max() + 1.0
    units = [p.unit for p in SENSORS[name].image_parameters]
    for k in range(problem.image_width):
        step = 1e-6 * max(1.0, float(np.max(np.abs(state.image[:, k]))))
        if units[k] == "m":                 # a metre offset of a body-fixed point of 1.7e6 m: rounding below 1 mm
            step = max(step, min(1e-3, 1e-9 * float(np.max(np.abs(points)))))

        def moved(d, k=k):
            s = state.copy()
            s.image[:, k] += d
            return evaluate(s)
        _assert_derivative(j_e[:, :, k], moved, step, scale, f"{name}: image parameter {k}")
    n_core = problem.cameras[0].n_core
    for k in range(n_core):
        step = 1e-6 * max(1.0, float(np.max(np.abs([c[k] for c in state.cameras]))))

        def moved_core(d, k=k):
            s = state.copy()
            for values in s.cameras:
                values[k] += d
            return evaluate(s)
        _assert_derivative(j_c[:, :, k], moved_core, step, scale, f"{name}: core parameter {k}")
    # 1 mm, less for a close-range block (a chessboard 1 m away: 1 um)
    point_step = min(1e-3, 1e-6 * max(1.0, float(np.ptp(points, axis=0).max())))
    for a in range(3):
        e = np.zeros(3)
        e[a] = point_step
        numeric = (evaluate(state, points + e) - evaluate(state, points - e)) / (2 * point_step)
        np.testing.assert_allclose(j_p[:, :, a], numeric, rtol=1e-5, atol=1e-9 * scale,
                                   err_msg=f"{name}: point coordinate {a}")
    assert j_c.shape[2] >= n_core and np.all(cam >= 0)


def test_rays_and_pixels_round_trip(bound):
    """The point predicted for an observation lies on the ray of its predicted pixel (within 1 mm), and
    pixels() of the point returns that pixel (within 1e-6 px)."""
    name, problem, state = bound
    for slot in problem.sensors:
        o = slot.observations[:40]
        img = problem.obs_image[o]
        points = state.points[problem.obs_point[o]]
        context = slot.bound.context(state, False)
        pixel = slot.bound.pixels(context, img, points)
        again = slot.bound.pixels(context, img, points)
        assert np.all(np.isfinite(pixel)) and np.allclose(pixel, again)
        if name == "bal":
            continue                                # BAL's rays leave its radial distortion out (initial values)
        # the rays of the pixels predicted for the points pass through the points
        origin, direction = slot.bound.rays(context, img, pixel)
        d = points - origin
        miss = np.linalg.norm(d - np.einsum("ni,ni->n", d, direction)[:, None] * direction, axis=1)
        assert np.max(miss) < 1e-3, (name, np.max(miss))


@pytest.mark.parametrize("name", ["pushbroom", "usgscsm-line", "dimap", "dg"])
def test_working_rows_times_their_maps_are_the_rows(name):
    """Every line sensor with jitter (issue 42): its rows in working columns (its own columns and the raw scaling
    functions at each observation's line) times its image's map T are its rows in the image parameters, the powers
    the jitter's functions are orthogonal to carried by the sensor's polynomial columns (seed 001's d_1 (t - t_ref);
    usgscsm's s^k, the sign of the line period)."""
    from dataclasses import replace as _replace
    block, options = EXAMPLES[name]()
    options = _replace(options, sensor=_replace(options.sensor, jitter="wavelet1d:db4:5", jitter_sigma_rad=1e-5))
    problem = build_problem(block, options)
    state, _ = initial_state(problem, block)
    bound = problem.sensors[0].bound
    offset = bound.jitter_offset
    rng = np.random.default_rng(3)
    state.image[:, offset:] = rng.normal(0, 3e-6, state.image[:, offset:].shape)
    working = bound.working_columns()
    assert working is not None and working.slots < problem.image_width // 2
    o = problem.sensors[0].observations
    img = problem.obs_image[o]
    context = bound.context(state)
    points = state.points[problem.obs_point[o]]
    _, j_e, _, _ = bound.predict(context, o, img, problem.image_camera[img], points, True)
    _, j_w, columns, _, _ = bound.predict_working(context, o, img, problem.image_camera[img], points)
    rows = np.einsum("nks,nsw->nkw", j_w, working.to_parameters[img[:, None], columns])
    assert np.max(np.abs(rows - j_e)) < 1e-9 * np.max(np.abs(j_e))
    # and the jitter's columns themselves are not zero (the test sees them)
    assert np.max(np.abs(j_e[:, :, offset:])) > 1e-3 * np.max(np.abs(j_e[:, :, :offset]))


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_a_problem_is_freed_when_its_last_reference_goes(name):
    """No reference cycle through a bound sensor: a problem (with its observations, AP columns and linearisation
    arrays) goes with its last reference, not whenever the interpreter's cyclic collector next runs. The bound sensors
    held their problem strongly; the leave-one-out validation of a 200-image block then kept about 420 MB of finished
    re-adjustments alive at once (DESIGN-NOTES, "Plan before the run")."""
    import gc
    import weakref

    block, options = EXAMPLES[name]()
    gc.collect()
    gc.disable()
    try:
        problem = build_problem(block, options)
        initial_state(problem, block)
        bound = problem.sensors[0].bound
        assert bound.problem is problem
        alive = weakref.ref(problem)
        del problem
        assert alive() is None, f"{name}: the problem outlived its last reference (a reference cycle)"
        with pytest.raises(ReferenceError):
            bound.problem
    finally:
        gc.enable()
