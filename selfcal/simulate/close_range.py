"""A convergent close-range block with known truth: a free network of a few images of a 3-D object.

Modelled on Strecha et al.'s (2008) *fountain-P11* (benchmarks/study_known_camera.py adjusts the real one): a wall
10 m wide and 6 m high with relief up to 1.5 m deep, photographed from an arc in front of it, every camera about
1.6 m above the ground (within a few centimetres), tilted up towards the middle of the wall and turned about it by
a few degrees. Strecha's camera by default: 3072 x 2048 px, fx 2759.48, fy 2764.16, cx 1520.69, cy 1006.81 px
(no distortion; fx != fy, an affinity of 0.17 %).

Conventions are selfcal's (DESIGN.md §2): photo coordinates in mm, y up; the camera looks along -z of its image
axes; M = R3(kappa) R2(phi) R1(omega). The true projection of object point X by an image (X0, M) is

    x = x0 + p fx u,   y = y0 + p fy v,   (u, v) = -(m1·d, m2·d) / (m3·d),   d = X - X0,

plus the lens's distortion where one is given (Brown's radial coefficients about the principal point, added at
the ideal position); pixels by :func:`selfcal.sensors.frame.pixel_from_photo`. In selfcal's model with one
principal distance the same camera is c = p fy and an affinity: Brown's b1 = (1 - fy / fx) r0 / p pixels at the
frame corner (:attr:`CloseRangeTruth.b1_px`; r0 the half-diagonal).

The block is what a matcher and an SfM reconstruction give: a free network (``datum = "free"``) of tie points only,
the images' orientation and the points' coordinates as start values (the truth plus a few centimetres and
tenths of a degree of error), the camera's nominal c and the frame centre as principal point.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..block import Block, Dropped, FrameCamera, Images, Observations, Points, prune
from ..geometry.rotation import looking_at, matrix_from_opk, opk_from_matrix
from ..sensors.frame import pixel_from_photo

__all__ = ["CloseRangeTruth", "CloseRangeSimulation", "simulate_close_range", "STRECHA_K"]

#: Strecha et al.'s camera of fountain-P11 and Herz-Jesus-P8 (K.txt): fx, fy, cx, cy in px (3072 x 2048)
STRECHA_K = (2759.48, 2764.16, 1520.69, 1006.81)


@dataclass(frozen=True)
class CloseRangeTruth:
    fx_px: float
    fy_px: float
    cx_px: float                        # principal point (col, row) in selfcal's pixel convention
    cy_px: float
    camera: FrameCamera                 # the same camera in selfcal's model: c = p fy (its affinity is b1_px)
    b1_px: float                        # Brown's b1 of selfcal's model that makes fx from c = p fy
    radial: tuple[float, ...]           # the lens's radial coefficients (k1, k2 on normalised coordinates)
    image_id: np.ndarray
    eop: np.ndarray                     # (n_images, 6) X0, Y0, Z0, omega, phi, kappa (rad)
    focal_scale: np.ndarray             # (n_images,) each image's principal distance over the camera's (1: same)
    point_id: np.ndarray
    xyz: np.ndarray                     # (n_points, 3)
    image_sigma_px: float

    def z_scores(self, values: np.ndarray, sigma: np.ndarray, names: list[str]) -> dict[str, float]:
        """(estimate - truth) / sigma of c (against p fy), x0, y0 and Brown's b1 where it is among ``names``, from
        a camera's parameter vector (c, x0, y0 in mm, then its AP coefficients in px) and its sigma."""
        cam = self.camera
        truth = {"c": cam.focal_mm, "x0": cam.x0_mm, "y0": cam.y0_mm, "b1": self.b1_px}
        return {name: float((values[k] - truth[name]) / sigma[k]) for k, name in enumerate(names) if name in truth}


@dataclass
class CloseRangeSimulation:
    block: Block
    truth: CloseRangeTruth
    info: dict = field(default_factory=dict)


def _relief(x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Depth (m, towards the cameras) of the wall's surface at (x, z): a basin, columns and niches."""
    basin = 1.5 * np.exp(-((x / 1.6) ** 2 + ((z - 1.0) / 1.2) ** 2))
    columns = 0.4 * (np.cos(2 * np.pi * x / 3.3) > 0.6)
    niche = -0.5 * np.exp(-(((x - 2.5) / 0.8) ** 2 + ((z - 4.0) / 0.9) ** 2))
    return basin + columns + niche + 0.1 * np.sin(1.7 * x) * np.cos(1.3 * z)


def simulate_close_range(seed: int = 0, n_images: int = 11, n_points: int = 3000, image_sigma_px: float = 0.5,
                         camera_px: tuple[float, float, float, float] = STRECHA_K,
                         size_px: tuple[int, int] = (3072, 2048), pixel_size_mm: float = 0.005,
                         radial: tuple[float, ...] = (), arc_deg: float = 70.0, distance_m: float = 9.0,
                         height_sd_m: float = 0.03, turn_sd_deg: float = 2.0,
                         focal_sd: float = 0.0) -> CloseRangeSimulation:
    """Simulate the block; the same seed gives the same block.

    Parameters
    ----------
    n_images, n_points : int
        Images on the arc (at least 3) and points on the wall (those seen in fewer than two images go).
    image_sigma_px : float
        Standard deviation of the measurement noise per coordinate (and the block's a-priori sigma).
    camera_px : fx, fy, cx, cy
        The true camera in pixels (cx, cy in selfcal's convention: (0, 0) the upper-left corner).
    radial : k1[, k2]
        Radial distortion of the lens on normalised coordinates about the principal point (OpenCV's k1, k2),
        added at the ideal position; empty: none.
    arc_deg, distance_m : float
        The cameras' arc about the wall's middle: its angle and radius.
    height_sd_m, turn_sd_deg : float
        Scatter of the cameras' heights about 1.6 m, and of their turns (pan, tilt, roll) off the wall's middle.
    focal_sd : float
        Relative scatter of each image's principal distance about the camera's (a focus that changed between
        images: a model error no AP family represents; 0: none).
    """
    if n_images < 3 or n_points < 10:
        raise ValueError(f"a close-range block needs at least 3 images and 10 points, asked for {n_images}, "
                         f"{n_points}")
    rng = np.random.default_rng(seed)
    width_px, height_px = size_px
    p = float(pixel_size_mm)
    fx, fy, cx, cy = (float(v) for v in camera_px)
    x0_mm, y0_mm = (cx - width_px / 2) * p, (height_px / 2 - cy) * p

    # --- object: points on the wall (y: depth towards the cameras, z: up)
    x = rng.uniform(-5.0, 5.0, n_points)
    z = rng.uniform(0.0, 6.0, n_points)
    xyz = np.column_stack([x, _relief(x, z), z])
    e = 1e-4                                                     # the surface's normal, for visibility
    normal = np.column_stack([-(_relief(x + e, z) - _relief(x - e, z)) / (2 * e), np.ones(n_points),
                              -(_relief(x, z + e) - _relief(x, z - e)) / (2 * e)])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)

    # --- images on the arc, looking at the wall's middle, turned a little
    target = np.array([0.0, 0.5, 3.0])
    azimuth = np.radians(np.linspace(-arc_deg / 2, arc_deg / 2, n_images))
    centres = np.column_stack([distance_m * np.sin(azimuth), distance_m * np.cos(azimuth),
                               1.6 + rng.normal(0.0, height_sd_m, n_images)])
    eop = np.zeros((n_images, 6))
    for k in range(n_images):
        turn = matrix_from_opk(np.radians(rng.normal(0.0, turn_sd_deg, 3))[None])[0]
        eop[k, :3] = centres[k]
        eop[k, 3:] = opk_from_matrix((turn @ looking_at(centres[k], target, (0.0, 0.0, 1.0)))[None])[0]
    M = matrix_from_opk(eop[:, 3:])
    focal_scale = 1.0 + rng.normal(0.0, focal_sd, n_images) if focal_sd > 0 else np.ones(n_images)

    # --- measurements: every point in front of a camera, inside the frame, seen at less than 70 degrees
    img_rows, pt_rows, pix_rows = [], [], []
    k_radial = np.zeros(2)
    k_radial[:len(radial)] = radial
    for k in range(n_images):
        d = xyz - centres[k]
        cam = d @ M[k].T
        front = cam[:, 2] < 0
        u, v = -cam[:, 0] / cam[:, 2], -cam[:, 1] / cam[:, 2]
        r2 = u * u + v * v
        radial_factor = 1.0 + k_radial[0] * r2 + k_radial[1] * r2 * r2
        xy = np.column_stack([x0_mm + p * fx * focal_scale[k] * u * radial_factor,
                              y0_mm + p * fy * focal_scale[k] * v * radial_factor])
        pixel = pixel_from_photo(xy, width_px, height_px, p)
        facing = np.einsum("ij,ij->i", -d / np.linalg.norm(d, axis=1, keepdims=True), normal) > np.cos(np.radians(70))
        inside = (pixel[:, 0] > 5) & (pixel[:, 0] < width_px - 5) & (pixel[:, 1] > 5) & (pixel[:, 1] < height_px - 5)
        seen = np.flatnonzero(front & facing & inside)
        img_rows.append(np.full(seen.size, k))
        pt_rows.append(seen)
        pix_rows.append(pixel[seen])
    obs_img, obs_pt = np.concatenate(img_rows), np.concatenate(pt_rows)
    measured = np.concatenate(pix_rows) + rng.normal(0.0, image_sigma_px, (len(obs_img), 2))

    # --- the block: a free network, start values as an SfM reconstruction gives them
    image_id = np.array([f"{k:04d}" for k in range(n_images)], dtype=object)
    point_id = np.array([f"p{k}" for k in range(n_points)], dtype=object)
    start_eop = eop + np.column_stack([rng.normal(0, 0.05, (n_images, 3)), np.radians(rng.normal(0, 0.3, (n_images, 3)))])
    start_xyz = xyz + rng.normal(0, 0.02, xyz.shape)
    nominal = FrameCamera("cam", width_px, height_px, p, focal_mm=p * round(0.5 * (fx + fy), -1))
    m = len(obs_img)
    block = Block(
        name=f"close-range-{seed}", crs="local", cameras={"cam": nominal},
        images=Images(image_id=image_id, camera_id=np.array(["cam"] * n_images, dtype=object),
                      strip_id=np.array([""] * n_images, dtype=object), time_s=np.full(n_images, np.nan),
                      position_m=start_eop[:, :3], attitude_rad=start_eop[:, 3:], line=np.arange(2, n_images + 2)),
        points=Points(point_id=point_id, role=np.array(["tie"] * n_points, dtype=object), xyz_m=start_xyz,
                      sigma_m=np.full((n_points, 3), np.nan), line=np.arange(2, n_points + 2)),
        observations=Observations(image_index=obs_img, point_index=obs_pt, pixel=measured,
                                  sigma_px=np.full(m, image_sigma_px), line=np.arange(2, m + 2)),
        image_sigma_px=image_sigma_px, dropped=Dropped(), datum="free")
    block = prune(block)
    r0_px = 0.5 * float(np.hypot(width_px, height_px))
    true_cam = FrameCamera("cam", width_px, height_px, p, focal_mm=p * fy, x0_mm=x0_mm, y0_mm=y0_mm)
    truth = CloseRangeTruth(fx, fy, cx, cy, true_cam, (1.0 - fy / fx) * r0_px, tuple(float(k) for k in radial),
                            image_id, eop, focal_scale, point_id, xyz, image_sigma_px)
    info = {"n_images": n_images, "n_points": len(block.points), "n_observations": len(block.observations),
            "seed": seed}
    return CloseRangeSimulation(block, truth, info)
