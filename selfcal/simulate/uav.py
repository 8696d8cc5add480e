"""The UAV block of seed 000, simulated with known truth.

28 vertical images in 4 east-west strips of 7 (75 % forward, 60 % side
overlap), a Sony ILCE-7M3 with a 21 mm lens (6000 x 4000 px, 5.9 um pixels)
215 m above the ground (GSD about 6.1 cm), rolling terrain, about 3.5 image
points per mm^2, and 39 ground marks split into the four control scenarios of
the paper:

=======  =============  ===========
type     GCP / CHK      trajectory
=======  =============  ===========
type1    15 / 24        none
type2    15 / 24        GNSS + IMU
type3    27 / 12        none
type4    27 / 12        GNSS + IMU
=======  =============  ===========

All four blocks share the same images and measurements, as in the paper; they
differ in which marks are control and whether the trajectory is observed.

The camera's true interior orientation differs from its nominal one, and the
image measurements carry a systematic distortion field (``none``, ``brown``,
``local``, ``local+brown``, ``ripple``, ``edge``), Gaussian noise and optionally blunders. The fields span three
spatial scales: Brown's over the whole frame, local bumps a few hundred pixels wide, and ripples of a higher
spatial frequency than seed 000's 9 x 6 grid (``ripple``) or confined to the frame's border (``edge``); none but
the first is represented exactly by an AP family. The
trajectory observations carry a per-strip shift and a linear drift (Eq. 12 of
seed 000) plus noise.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike

from ..block import Block, Dropped, FrameCamera, Images, Observations, Points, prune
from ..geometry.rotation import matrix_from_opk, opk_from_matrix
from ..sensors.frame import pixel_from_photo, project
from .names import DISTORTIONS, FLIGHTS, SCENARIOS
from .trajectory import TrajectoryErrors, TrajectoryTruth, draw_trajectory_errors

__all__ = ["TrueDistortion", "UAVTruth", "UAVSimulation", "simulate_uav", "truth_files", "SCENARIOS", "DISTORTIONS",
           "FLIGHTS"]

#: the a-priori readout a simulated rolling-shutter camera declares: the value of a camera nobody measured (ODM's
#: default guess, selfcal.convert.rolling) with a wide sigma
DECLARED_READOUT_MS, DECLARED_SIGMA_READOUT_MS = 30.0, 30.0

# Nangang calibration field mark accuracy (NLSC 2015, quoted in seed 000)
MARK_SIGMA_XY_M = 0.0167
MARK_SIGMA_Z_M = 0.0289


@dataclass(frozen=True)
class TrueDistortion:
    """A known distortion field Delta (pixels, photo axes), observed = ideal + Delta.

    ``brown`` holds k1, k2 (mm^-2, mm^-4), p1, p2 (mm^-1) about the principal
    point; ``bumps`` are Gaussian displacements (x_mm, y_mm, sigma_mm, dx_px, dy_px); ``waves`` plane waves
    (dx_px, dy_px, kx, ky per mm, phase): (dx, dy) sin(2 pi (kx x + ky y) + phase); ``edges`` ripples along the
    frame's border (amplitude_px, decay_mm, wavelength_mm): dx = a exp(-d / decay) sin(2 pi y / wavelength),
    dy = a exp(-d / decay) sin(2 pi x / wavelength), d the distance to the nearest edge of the frame of half size
    ``half_size_mm``.
    """

    pixel_size_mm: float
    principal_point_mm: tuple[float, float] = (0.0, 0.0)
    brown: dict | None = None
    bumps: tuple[tuple[float, float, float, float, float], ...] = ()
    waves: tuple[tuple[float, float, float, float, float], ...] = ()
    edges: tuple[tuple[float, float, float], ...] = ()
    half_size_mm: tuple[float, float] = (0.0, 0.0)

    def displacement_px(self, x_mm: ArrayLike, y_mm: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        x_mm, y_mm = np.asarray(x_mm, float), np.asarray(y_mm, float)
        dx = np.zeros_like(x_mm)
        dy = np.zeros_like(y_mm)
        if self.brown:
            b = self.brown
            xb, yb = x_mm - self.principal_point_mm[0], y_mm - self.principal_point_mm[1]
            r2 = xb * xb + yb * yb
            radial = b["k1"] * r2 + b["k2"] * r2 * r2
            dx += (xb * radial + b["p1"] * (r2 + 2 * xb * xb) + 2 * b["p2"] * xb * yb) / self.pixel_size_mm
            dy += (yb * radial + b["p2"] * (r2 + 2 * yb * yb) + 2 * b["p1"] * xb * yb) / self.pixel_size_mm
        for cx, cy, s, ax, ay in self.bumps:
            g = np.exp(-((x_mm - cx) ** 2 + (y_mm - cy) ** 2) / (2 * s * s))
            dx += ax * g
            dy += ay * g
        for ax, ay, kx, ky, phase in self.waves:
            wave = np.sin(2 * np.pi * (kx * x_mm + ky * y_mm) + phase)
            dx += ax * wave
            dy += ay * wave
        for amplitude, decay, wavelength in self.edges:
            d = np.minimum(self.half_size_mm[0] - np.abs(x_mm), self.half_size_mm[1] - np.abs(y_mm))
            g = amplitude * np.exp(-np.clip(d, 0.0, None) / decay)
            dx += g * np.sin(2 * np.pi * y_mm / wavelength)
            dy += g * np.sin(2 * np.pi * x_mm / wavelength)
        return dx, dy

    def as_dict(self) -> dict:
        return {"pixel_size_mm": self.pixel_size_mm, "principal_point_mm": list(self.principal_point_mm),
                "brown": self.brown, "bumps": [list(b) for b in self.bumps], "waves": [list(w) for w in self.waves],
                "edges": [list(e) for e in self.edges], "half_size_mm": list(self.half_size_mm)}


@dataclass
class UAVTruth:
    camera: FrameCamera                 # true interior orientation
    distortion: TrueDistortion
    image_id: np.ndarray
    eop: np.ndarray                     # (n_images, 6) true X0, Y0, Z0, omega, phi, kappa (rad)
    point_id: np.ndarray
    xyz: np.ndarray                     # (n_points, 3) true coordinates
    blunder_obs: np.ndarray             # observation rows carrying a blunder
    blunder_px: np.ndarray              # (n_blunders, 2) blunder vector (col, row) px
    strip_id: np.ndarray                # strips in order
    gnss_shift_m: np.ndarray            # (n_strips, 3) D0
    gnss_drift_m_s: np.ndarray          # (n_strips, 3) D1
    imu_shift_rad: np.ndarray           # (n_strips, 3)
    lever_arm_m: np.ndarray             # (3,) GNSS antenna in the camera frame
    boresight_rad: np.ndarray           # (3,) IMU boresight angles
    image_sigma_px: float
    gsd_m: float
    #: the trajectory errors as applied (per image without noise; drift origin; IMU drift)
    trajectory: TrajectoryTruth | None = None
    #: the flight ("seed000", "serpentine", "corridor"), the rolling shutter's readout (0: a global shutter) and
    #: each image's true velocity during its readout (m/s)
    flight: str = "seed000"
    readout_ms: float = 0.0
    velocity_m_s: np.ndarray | None = None


@dataclass
class UAVSimulation:
    blocks: dict[str, Block]
    truth: UAVTruth
    info: dict = field(default_factory=dict)


def _terrain(x, y):
    """Rolling terrain, about +-20 m of relief around 30 m."""
    return (30.0 + 12.0 * np.sin(2 * np.pi * x / 700.0) * np.cos(2 * np.pi * y / 520.0)
            + 6.0 * np.sin(2 * np.pi * (x + 0.6 * y) / 260.0))


def _distortion(name: str, pixel_size_mm: float, pp: tuple[float, float], scale: float = 1.0,
                half_size_mm: tuple[float, float] = (17.7, 11.8)) -> TrueDistortion:
    if name not in DISTORTIONS:
        raise ValueError(f"unknown distortion field '{name}' (known: {', '.join(DISTORTIONS)})")
    brown = None
    bumps: tuple = ()
    waves: tuple = ()
    edges: tuple = ()
    if "brown" in name:
        # about -11 px of radial distortion in the corners, 1 px decentering
        brown = {k: scale * v for k, v in {"k1": -9.1e-6, "k2": 5.0e-9, "p1": 4.0e-6, "p2": -3.0e-6}.items()}
    if "local" in name:
        # a non-stationary defect near the upper-right corner and a weaker one at the left edge
        bumps = tuple((x, y, s, scale * dx, scale * dy)
                      for x, y, s, dx, dy in ((12.5, 7.0, 3.5, 2.4, -1.6), (-14.0, -2.0, 2.5, -1.2, 0.9)))
    if name == "ripple":
        # two plane waves of 500 and 430 px wavelength (12 and 14 periods across the frame: finer than a 9 x 6
        # grid's cells of 667 px), 0.8 and 0.6 px
        waves = tuple((scale * ax, scale * ay, kx, ky, phase) for ax, ay, kx, ky, phase in
                      ((0.8, 0.3, 1 / 2.95, 0.08, 0.4), (-0.2, 0.6, 0.05, 1 / 2.54, 1.3)))
    if name == "edge":
        # a 2 px ripple of 600 px wavelength along the border, decaying inwards over 150 px
        edges = ((scale * 2.0, 150 * pixel_size_mm, 600 * pixel_size_mm),)
    return TrueDistortion(pixel_size_mm, pp, brown, bumps, waves, edges, half_size_mm)


def simulate_uav(seed: int = 0, distortion: str = "local+brown", image_sigma_px: float = 0.5,
                 blunder_rate: float = 0.0, points_per_mm2: float = 3.5,
                 gnss_sigma_m: tuple[float, float, float] = (0.05, 0.05, 0.10),
                 imu_sigma_deg: tuple[float, float, float] = (0.02, 0.02, 0.05),
                 gnss_shift_m: float = 0.2, gnss_drift_mm_s: float = 5.0, imu_shift_deg: float = 0.05,
                 distortion_scale: float = 1.0, lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 boresight_deg: tuple[float, float, float] = (0.0, 0.0, 0.0), n_strips: int = 4, images_per_strip: int = 7,
                 trajectory_errors: TrajectoryErrors | None = None, exposure_interval_s: float | None = None,
                 declare_mounting: bool = False, flight: str = "seed000", speed_mps: float = 8.0,
                 rolling_shutter_ms: float = 0.0, velocity_noise_mps: float = 0.1,
                 noise_seed: int | None = None, tilt_deg: float = 0.0) -> UAVSimulation:
    """Simulate the seed-000 block; returns the four scenario blocks and the truth.

    Parameters
    ----------
    seed : int
        Random seed: the same seed gives the same block.
    distortion : {"none", "brown", "local", "local+brown", "ripple", "edge"}
    distortion_scale : float
        Multiplies the whole field (1: about -11 px of radial distortion in the corners and local
        bumps of 2-3 px).
    image_sigma_px : float
        Standard deviation of the image measurement noise (and the blocks' a-priori sigma).
    blunder_rate : float
        Share of image observations given a blunder of 4-15 px in a random direction.
    points_per_mm2 : float
        Image point density.
    gnss_shift_m, gnss_drift_mm_s, imu_shift_deg : float
        Typical size of the per-strip trajectory errors of Eq. (12).
    n_strips, images_per_strip : int
        Block size (seed 000: 4 x 7 = 28 images). Larger blocks keep the overlaps and the point
        density; the 39 marks spread over the larger area (for performance studies).
    lever_arm_m, boresight_deg : 3 floats
        Mounting of the GNSS antenna (camera frame) and of the IMU: the GNSS observes
        X0 + M^T a, the IMU the angles of B(b)^T M (selfcal.adjust.residuals.trajectory.mounted_sensor).
        The blocks do not give them (block.toml has no lever_arm_m / boresight_deg) unless
        ``declare_mounting``.
    trajectory_errors : TrajectoryErrors, optional
        Draw the GNSS/IMU errors independently of the adjustment's shift/drift model
        (:mod:`selfcal.simulate.trajectory`: magnitude ranges, drift origin, rotation composition,
        strips without drift, true noise of their own); ``gnss_sigma_m`` and ``imu_sigma_deg`` are
        then only the sigmas the blocks declare. Default: Eq. (12) as the adjustment models it, with
        ``gnss_shift_m``, ``gnss_drift_mm_s``, ``imu_shift_deg`` and noise as declared. The images,
        points and measurements of a seed are the same either way (the trajectory is drawn last).
    exposure_interval_s : float, optional
        Time between exposures along a strip (default: the 75 % base at ``speed_mps``, 11.35 s at 8 m/s; 2 s gives
        strips of 12 s).
    flight : {"seed000", "serpentine", "corridor"}
        seed 000's strips with the camera turning at the strip ends; the same strips with a fixed heading; or a
        corridor: 2 strips of ``2 * images_per_strip`` images out and back with a fixed heading, its 39 marks on a
        13 x 3 grid along it (sparse control: every third column; dense: 27 of them).
    speed_mps : float
        Ground speed along the strips.
    rolling_shutter_ms : float
        Readout time of a rolling shutter (0: a global shutter). Each image's pose is that of its middle row at its
        time; the row of an image point is read (row - H/2)/H x readout later, while the camera moves with the
        image's velocity: the derivative of a cubic spline in time through its strip's true positions plus
        ``velocity_noise_mps`` of noise per axis (drawn from a stream of its own: a seed's images, points, noise
        and trajectory are those of the global shutter's). The blocks declare ``shutter = "rolling"`` with the readout a camera nobody measured gets
        (:data:`DECLARED_READOUT_MS` +- :data:`DECLARED_SIGMA_READOUT_MS`). Image points that the motion moves off the
        frame are left out (and the blocks pruned, :func:`selfcal.block.prune`, where that leaves a point with one ray).
    tilt_deg : float
        Convergent images: each image pitched forwards and backwards along its strip in turn by this angle (its phi
        +tilt, -tilt, ...; 0: seed 000's nadir block). The draws of a seed are the nadir block's.
    noise_seed : int, optional
        Draw the image measurement noise and the marks' survey noise from a generator of their own: every
        ``noise_seed`` gives the same block (images, points, which point is seen where, blunders,
        trajectory) with another noise (Monte-Carlo studies of precision). Default: from ``seed``'s
        generator, as before.
    """
    if flight not in FLIGHTS:
        raise ValueError(f"unknown flight '{flight}' (known: {', '.join(FLIGHTS)})")
    if not speed_mps > 0 or not rolling_shutter_ms >= 0:
        raise ValueError(f"speed_mps must be positive and rolling_shutter_ms not negative, found {speed_mps}, "
                         f"{rolling_shutter_ms}")
    rng = np.random.default_rng(seed)
    width_px, height_px, pixel = 6000, 4000, 0.0059
    nominal = FrameCamera("ilce7m3", width_px, height_px, pixel, focal_mm=21.0, x0_mm=0.0, y0_mm=0.0)
    if rolling_shutter_ms > 0:
        nominal = replace(nominal, shutter="rolling", readout_ms=DECLARED_READOUT_MS,
                          sigma_readout_ms=DECLARED_SIGMA_READOUT_MS)
    if flight == "corridor":
        n_strips, images_per_strip = 2, 2 * images_per_strip
    true_cam = FrameCamera("ilce7m3", width_px, height_px, pixel, focal_mm=20.962, x0_mm=0.034, y0_mm=-0.021)
    field_ = _distortion(distortion, pixel, (true_cam.x0_mm, true_cam.y0_mm), distortion_scale,
                         (0.5 * nominal.width_mm, 0.5 * nominal.height_mm))
    agl = 215.0
    scale = agl / true_cam.focal_mm                                     # m per mm
    foot_x, foot_y = nominal.width_mm * scale, nominal.height_mm * scale
    base, spacing = 0.25 * foot_x, 0.40 * foot_y
    per_strip = images_per_strip
    if n_strips < 2 or per_strip < 3:
        raise ValueError(f"a block needs at least 2 strips of 3 images, asked for {n_strips} x {per_strip}")
    speed = float(speed_mps)
    interval = base / speed if exposure_interval_s is None else float(exposure_interval_s)

    # --- exterior orientation (true)
    image_id: list[str] = []
    strip_rows: list[int] = []
    time_rows: list[float] = []
    eop_rows: list[list[float]] = []
    for s in range(n_strips):
        eastbound = s % 2 == 0
        for k in range(per_strip):
            j = k if eastbound else per_strip - 1 - k
            x = j * base + rng.normal(0, 1.5)
            y = s * spacing + rng.normal(0, 1.5)
            z = 30.0 + agl + rng.normal(0, 1.0)            # constant flying height
            kappa = (0.0 if eastbound or flight != "seed000" else np.pi) + np.radians(rng.normal(0, 1.5))
            eop_rows.append([x, y, z, np.radians(rng.normal(0, 1.2)), np.radians(rng.normal(0, 1.2)), kappa])
            image_id.append(f"S{s + 1}_{k + 1:02d}")
            strip_rows.append(s)
            time_rows.append(s * max(150.0, per_strip * interval + 60.0) + k * interval)
    eop = np.array(eop_rows)
    eop[:, 5] = (eop[:, 5] + np.pi) % (2 * np.pi) - np.pi
    times = np.array(time_rows)
    strip_of = np.array(strip_rows)
    n_img = len(image_id)
    if tilt_deg:
        if not 0.0 < tilt_deg <= 30.0:
            raise ValueError(f"tilt_deg must be in (0, 30], not {tilt_deg}")
        within = np.array([np.count_nonzero(strip_of[:i] == strip_of[i]) for i in range(n_img)])
        eop[:, 4] += np.radians(tilt_deg) * np.where(within % 2 == 0, 1.0, -1.0)

    # --- object points: tie points over the covered area, and 39 marks
    x_lo, x_hi = -foot_x / 2, (per_strip - 1) * base + foot_x / 2
    y_lo, y_hi = -foot_y / 2, (n_strips - 1) * spacing + foot_y / 2
    density = points_per_mm2 * nominal.width_mm * nominal.height_mm / (foot_x * foot_y)   # per m^2
    n_tie = int(density * (x_hi - x_lo) * (y_hi - y_lo))
    tx = rng.uniform(x_lo, x_hi, n_tie)
    ty = rng.uniform(y_lo, y_hi, n_tie)
    tz = _terrain(tx, ty) + rng.normal(0, 1.0, n_tie)
    tie = np.column_stack([tx, ty, tz])

    if flight == "corridor":
        gx = np.linspace(x_lo + 0.32 * foot_x, x_hi - 0.32 * foot_x, 13)
        gy = np.linspace(y_lo + 0.25 * foot_y, y_hi - 0.25 * foot_y, 3)
        grid = [(i, j) for j in range(3) for i in range(13)]                            # 39 marks
    else:
        gx = np.linspace(x_lo + 0.32 * foot_x, x_hi - 0.32 * foot_x, 8)
        gy = np.linspace(y_lo + 0.25 * foot_y, y_hi - 0.25 * foot_y, 5)
        grid = [(i, j) for j in range(5) for i in range(8) if (i, j) != (4, 2)]       # 39 marks
    mx = np.array([gx[i] for i, _ in grid]) + rng.normal(0, 8.0, 39)
    my = np.array([gy[j] for _, j in grid]) + rng.normal(0, 8.0, 39)
    marks = np.column_stack([mx, my, _terrain(mx, my)])
    if flight == "corridor":
        # sparse control: every third column of marks across the corridor; dense: 9 of the 13 columns
        sparse = [n for n, (i, _) in enumerate(grid) if i % 3 == 0]
        dense = [n for n, (i, _) in enumerate(grid) if i in (0, 1, 3, 5, 6, 7, 9, 11, 12)]
    else:
        periphery = [n for n, (i, j) in enumerate(grid) if i in (0, 7) or j in (0, 4)]     # 22 marks
        # sparse control: corners, four edge marks on the long sides, two on the short sides, five inner marks
        sparse = [n for n, (i, j) in enumerate(grid)
                  if (i in (0, 7) and j in (0, 2, 4)) or (j in (0, 4) and i in (2, 5))
                  or (i, j) in ((2, 2), (5, 2), (3, 1), (4, 3), (6, 3))]
        # dense control: the whole periphery plus the same inner marks
        dense = sorted(set(periphery) | set(sparse))
    assert len(sparse) == 15 and len(dense) == 27, (len(sparse), len(dense))

    xyz_true = np.vstack([marks, tie])
    point_id = np.array([f"M{k + 1:02d}" for k in range(39)] + [f"T{k + 1:06d}" for k in range(n_tie)], dtype=object)

    # --- the velocity of each image during its readout: the path through the images' positions (a cubic spline in
    # time along each strip: the positions wander by metres about the strip's line) and noise drawn from a stream of
    # its own (the rest of a seed stays the same)
    velocity = np.zeros((n_img, 3))
    if rolling_shutter_ms > 0:
        from scipy.interpolate import CubicSpline
        for s in range(n_strips):
            members = np.flatnonzero(strip_of == s)
            velocity[members] = CubicSpline(times[members], eop[members, :3]).derivative()(times[members])
        velocity += np.random.default_rng([seed, 41]).normal(0, velocity_noise_mps, (n_img, 3))

    # --- project every point into every image
    iop = np.array([true_cam.focal_mm, true_cam.x0_mm, true_cam.y0_mm])
    n_pts = len(xyz_true)
    img_parts: list[np.ndarray] = []
    pt_parts: list[np.ndarray] = []
    pix_parts: list[np.ndarray] = []
    off_parts: list[np.ndarray] = []
    # beyond any footprint (tilts of a few degrees, and the convergent images' along their strip)
    half = 0.75 * max(foot_x, foot_y) + agl * np.tan(np.radians(tilt_deg))
    order = np.argsort(xyz_true[:, 0], kind="stable")
    x_sorted = xyz_true[order, 0]
    for i in range(n_img):
        lo, hi = np.searchsorted(x_sorted, [eop[i, 0] - half, eop[i, 0] + half])
        near = np.sort(order[lo:hi])
        near = near[np.abs(xyz_true[near, 1] - eop[i, 1]) < half]
        xy = project(xyz_true[near], np.broadcast_to(eop[i], (near.size, 6)), iop)
        dx, dy = field_.displacement_px(xy[:, 0], xy[:, 1])
        xy_obs = xy + np.column_stack([dx, dy]) * pixel
        pix = pixel_from_photo(xy_obs, width_px, height_px, pixel)
        inside = ((pix[:, 0] > 1) & (pix[:, 0] < width_px - 1) & (pix[:, 1] > 1) & (pix[:, 1] < height_px - 1))
        idx = near[inside]
        pix = pix[inside]
        if rolling_shutter_ms > 0:       # the same points, seen on the lines the moving camera reads them on
            pix = _rolling_pixels(xyz_true[idx], eop[i], velocity[i], iop, field_, pix, rolling_shutter_ms,
                                  (width_px, height_px, pixel))
        img_parts.append(np.full(idx.size, i))
        pt_parts.append(idx)
        pix_parts.append(pix)
        off_parts.append((pix[:, 0] <= 0) | (pix[:, 0] >= width_px) | (pix[:, 1] <= 0) | (pix[:, 1] >= height_px))
    obs_img = np.concatenate(img_parts)
    obs_pt = np.concatenate(pt_parts)
    obs_pix = np.concatenate(pix_parts)
    obs_off = np.concatenate(off_parts)
    # keep tie points seen at least twice, marks seen at least twice
    rays = np.bincount(obs_pt, minlength=n_pts)
    keep_pt = rays >= 2
    new_index = np.cumsum(keep_pt) - 1
    keep_obs = keep_pt[obs_pt]
    obs_img, obs_pt, obs_pix = obs_img[keep_obs], new_index[obs_pt[keep_obs]], obs_pix[keep_obs]
    obs_off = obs_off[keep_obs]
    xyz_true, point_id = xyz_true[keep_pt], point_id[keep_pt]
    n_marks = int(keep_pt[:39].sum())
    mark_map = np.cumsum(keep_pt[:39]) - 1
    sparse = [int(mark_map[n]) for n in sparse if keep_pt[n]]
    dense = [int(mark_map[n]) for n in dense if keep_pt[n]]

    noise_rng = rng if noise_seed is None else np.random.default_rng([seed, noise_seed])
    noise = noise_rng.normal(0.0, image_sigma_px, obs_pix.shape)
    measured = obs_pix + noise
    n_obs = len(measured)
    n_blunder = int(round(blunder_rate * n_obs))
    blunder_obs = np.sort(rng.choice(n_obs, n_blunder, replace=False)) if n_blunder else np.zeros(0, np.int64)
    size = rng.uniform(4.0, 15.0, n_blunder)
    angle = rng.uniform(0, 2 * np.pi, n_blunder)
    blunder_px = np.column_stack([size * np.cos(angle), size * np.sin(angle)])
    measured[blunder_obs] += blunder_px
    measured[:, 0] = np.clip(measured[:, 0], 0.0, width_px)
    measured[:, 1] = np.clip(measured[:, 1], 0.0, height_px)
    if obs_off.any():                   # moved off the frame by the rolling shutter
        on = np.flatnonzero(~obs_off)
        renumber = np.full(n_obs, -1)
        renumber[on] = np.arange(on.size)
        keep_blunder = ~obs_off[blunder_obs]
        blunder_obs, blunder_px = renumber[blunder_obs[keep_blunder]], blunder_px[keep_blunder]
        obs_img, obs_pt, measured = obs_img[on], obs_pt[on], measured[on]
        n_obs = on.size

    # --- reference coordinates of the marks (with their survey noise)
    mark_noise = rng.normal(0, 1, (n_marks, 3))
    if noise_seed is not None:
        mark_noise = noise_rng.normal(0, 1, (n_marks, 3))
    ref = xyz_true[:n_marks] + mark_noise * [MARK_SIGMA_XY_M, MARK_SIGMA_XY_M, MARK_SIGMA_Z_M]

    # --- trajectory observations: per-strip shift + drift (Eq. 12) + noise
    gnss_sigma = np.array(gnss_sigma_m, float)
    imu_sigma = np.radians(np.array(imu_sigma_deg, float))
    lever_arm = np.array(lever_arm_m, float)
    boresight = np.radians(np.array(boresight_deg, float))
    M = matrix_from_opk(eop[:, 3:])
    antenna = eop[:, :3] + np.einsum("nji,j->ni", M, lever_arm)
    body = opk_from_matrix(np.einsum("ji,njk->nik", matrix_from_opk(boresight), M)) if boresight.any() else eop[:, 3:]
    if trajectory_errors is None:
        shift = rng.normal(0, gnss_shift_m, (n_strips, 3))
        drift = rng.normal(0, gnss_drift_mm_s / 1000.0, (n_strips, 3))
        imu_shift = np.radians(rng.normal(0, imu_shift_deg, (n_strips, 3)))
        t_strip0 = np.array([times[strip_of == s].min() for s in range(n_strips)])
        dt = times - t_strip0[strip_of]
        gnss_clean = antenna + shift[strip_of] + drift[strip_of] * dt[:, None]
        gnss = gnss_clean + rng.normal(0, 1, (n_img, 3)) * gnss_sigma
        imu_clean = body + imu_shift[strip_of]
        imu = imu_clean + rng.normal(0, 1, (n_img, 3)) * imu_sigma
        imu = (imu + np.pi) % (2 * np.pi) - np.pi
        trajectory = TrajectoryTruth(t_strip0, shift, drift, imu_shift, np.zeros((n_strips, 3)), "opk",
                                     gnss_clean, (imu_clean + np.pi) % (2 * np.pi) - np.pi)
    else:
        gnss, imu, trajectory = draw_trajectory_errors(trajectory_errors, rng, times, strip_of, antenna, body)
        shift, drift, imu_shift = trajectory.gnss_shift_m, trajectory.gnss_drift_m_s, trajectory.imu_shift_rad

    strip_names = np.array([f"S{s + 1}" for s in range(n_strips)], dtype=object)
    images = Images(
        image_id=np.array(image_id, dtype=object),
        camera_id=np.array(["ilce7m3"] * n_img, dtype=object),
        strip_id=strip_names[strip_of],
        time_s=times,
        position_m=gnss,
        attitude_rad=imu,
        line=np.arange(2, n_img + 2),
    )
    observations = Observations(
        image_index=obs_img, point_index=obs_pt, pixel=measured,
        sigma_px=np.full(n_obs, image_sigma_px), line=np.arange(2, n_obs + 2))

    blocks = {}
    for scenario in SCENARIOS:
        gcp = set(sparse if scenario in ("type1", "type2") else dense)
        role = np.array(["gcp" if k in gcp else "chk" for k in range(n_marks)] + ["tie"] * (len(xyz_true) - n_marks),
                        dtype=object)
        xyz = np.full_like(xyz_true, np.nan)
        xyz[:n_marks] = ref
        sigma = np.full_like(xyz_true, np.nan)
        sigma[:n_marks] = [MARK_SIGMA_XY_M, MARK_SIGMA_XY_M, MARK_SIGMA_Z_M]
        points = Points(point_id=point_id, role=role, xyz_m=xyz, sigma_m=sigma,
                        line=np.arange(2, len(xyz_true) + 2))
        with_traj = scenario in ("type2", "type4")
        blocks[scenario] = Block(
            name=f"seed000-uav-{scenario}",
            crs="local",
            cameras={"ilce7m3": nominal},
            images=images,
            points=points,
            observations=observations,
            image_sigma_px=image_sigma_px,
            gnss_sigma_m=tuple(gnss_sigma) if with_traj else None,
            imu_sigma_deg=tuple(np.degrees(imu_sigma)) if with_traj else None,
            gnss_lever_arm_m=tuple(lever_arm) if with_traj and declare_mounting else None,
            imu_boresight_deg=tuple(np.degrees(boresight)) if with_traj and declare_mounting else None,
            dropped=Dropped(),
        )
        if obs_off.any():       # points the motion left with one ray: out, as a block folder's reader does
            blocks[scenario] = prune(blocks[scenario])
    truth = UAVTruth(
        camera=true_cam, distortion=field_, image_id=images.image_id, eop=eop,
        point_id=point_id, xyz=xyz_true, blunder_obs=blunder_obs, blunder_px=blunder_px,
        strip_id=strip_names, gnss_shift_m=shift, gnss_drift_m_s=drift, imu_shift_rad=imu_shift,
        lever_arm_m=lever_arm, boresight_rad=boresight, image_sigma_px=image_sigma_px, gsd_m=pixel * agl / true_cam.focal_mm,
        trajectory=trajectory, flight=flight, readout_ms=float(rolling_shutter_ms), velocity_m_s=velocity,
    )
    info = {"n_images": n_img, "n_points": len(xyz_true), "n_observations": n_obs,
            "points_per_image": n_obs / n_img, "n_marks": n_marks, "seed": seed, "distortion": distortion,
            "flight": flight, "speed_mps": speed, "rolling_shutter_ms": float(rolling_shutter_ms)}
    return UAVSimulation(blocks, truth, info)


def _rolling_pixels(points: np.ndarray, eop: np.ndarray, velocity: np.ndarray, iop: np.ndarray,
                    field_: TrueDistortion, pixel: np.ndarray, readout_ms: float, frame: tuple,
                    iterations: int = 6) -> np.ndarray:
    """Pixels (col, row) of ``points`` in one image whose rows are read down during ``readout_ms``: the projection
    centre at the time of the row the point lands on, X0 + v (row - H/2)/H readout, found by iterating from the
    global shutter's ``pixel`` (each step shrinks the error by the image motion during the readout over the image
    height, ~1e-3)."""
    width_px, height_px, size = frame
    for _ in range(iterations):
        dt = (pixel[:, 1] - height_px / 2.0) / height_px * readout_ms / 1000.0
        moved = np.broadcast_to(eop, (len(points), 6)).copy()
        moved[:, :3] += velocity[None, :] * dt[:, None]
        xy = project(points, moved, iop)
        dx, dy = field_.displacement_px(xy[:, 0], xy[:, 1])
        pixel = pixel_from_photo(xy + np.column_stack([dx, dy]) * size, width_px, height_px, size)
    return pixel


def truth_files(truth: UAVTruth, nodes_x: int = 61) -> dict:
    """The truth of a simulation as data files (dicts become JSON, tuples CSV)."""
    cam = truth.camera
    nodes_y = int(round((nodes_x - 1) * cam.height_px / cam.width_px)) + 1
    col_grid, row_grid = np.meshgrid(np.linspace(0, cam.width_px, nodes_x), np.linspace(0, cam.height_px, nodes_y))
    col, row = col_grid.ravel(), row_grid.ravel()
    x = (col - cam.width_px / 2) * cam.pixel_size_mm
    y = (cam.height_px / 2 - row) * cam.pixel_size_mm
    dx, dy = truth.distortion.displacement_px(x, y)
    deg = np.degrees(truth.eop[:, 3:])
    camera = {
        "camera_id": cam.camera_id, "width_px": cam.width_px, "height_px": cam.height_px,
        "pixel_size_mm": cam.pixel_size_mm, "focal_mm": cam.focal_mm, "x0_mm": cam.x0_mm, "y0_mm": cam.y0_mm,
        "distortion": truth.distortion.as_dict(), "image_sigma_px": truth.image_sigma_px, "gsd_m": truth.gsd_m,
        "flight": truth.flight, "shutter": "rolling" if truth.readout_ms > 0 else "global",
        "readout_ms": truth.readout_ms,
    }
    # the velocities during the readout, where there is one (the poses are those of the middle rows)
    velocity: tuple[list, list, list] = ([], [], [])
    if truth.readout_ms > 0 and truth.velocity_m_s is not None:
        velocity = (["vx_m_s", "vy_m_s", "vz_m_s"], list(truth.velocity_m_s.T), [".5f"] * 3)
    trajectory = {
        "strip_id": list(truth.strip_id),
        "gnss_shift_m": truth.gnss_shift_m, "gnss_drift_m_s": truth.gnss_drift_m_s,
        "imu_shift_deg": np.degrees(truth.imu_shift_rad),
        "lever_arm_m": truth.lever_arm_m, "boresight_deg": np.degrees(truth.boresight_rad),
    }
    return {
        "camera.json": camera,
        "trajectory.json": trajectory,
        "images.csv": (["image_id", "X0", "Y0", "Z0", "omega_deg", "phi_deg", "kappa_deg"] + velocity[0],
                       [truth.image_id, *truth.eop[:, :3].T, *deg.T] + velocity[1],
                       ["", ".5f", ".5f", ".5f", ".8f", ".8f", ".8f"] + velocity[2]),
        "points.csv": (["point_id", "X", "Y", "Z"], [truth.point_id, *truth.xyz.T], ["", ".5f", ".5f", ".5f"]),
        "distortion_grid.csv": (["col", "row", "dcol", "drow"], [col, row, dx, -dy], [".2f", ".2f", ".5f", ".5f"]),
        "blunders.csv": (["observation_row", "dcol_px", "drow_px"],
                         [truth.blunder_obs, truth.blunder_px[:, 0], truth.blunder_px[:, 1]], ["d", ".3f", ".3f"]),
    }
