"""A referee for the attitude jitter of line images (issue 42, item 4): the Ames Stereo Pipeline's ``jitter_solve``
approach, written from its documentation, on the same observations as selfcal's ``--jitter auto``.

    python benchmarks/referee_asp_jitter.py [--seeds 1] [--points 1500] [--lines-per-pose 250] [--weights 0,1,3]

What ASP documents (docs/tools/jitter_solve.rst of NeoGeographyToolkit/StereoPipeline, "jitter_solve": the sections
"Resampling the poses", "Camera constraints", "Smoothness constraint", the examples and "Command-line options";
docs/tools/bundle_adjust.rst for the cost function), and what this referee does with it:

* the orientations of a line camera are resampled to one sample per ``--num-lines-per-orientation`` lines and the
  solver moves every sample (the examples use 1000 lines for CTX, 500 for Pleiades, 400 for WorldView, 100 for ASTER;
  the rig section asks for less than half the jitter period). Here: a roll, pitch and yaw correction per node every
  N lines (``--lines-per-pose``, default 250: under half the 660-line period of the simulation's fastest jitter,
  4.1 Hz at 0.37 ms a line; the rule is ASP's, the number is chosen knowing the truth, to the referee's advantage),
  interpolated linearly between the nodes (ASP interpolates its CSM poses; the doc does not say how, a hat function
  per node is this referee's choice). Hats reproduce a linear function, so the nodes also move bias and drift.
* the solver starts from bundle-adjusted cameras (``--input-adjustments-prefix``): here seed 001's M5 (bias and
  drift of roll, pitch, yaw; the focal lengths given) on the same block, and its tie points; the node corrections
  start at zero.
* the cost of the reprojection errors is robust: ``--cost-function`` Cauchy (bundle_adjust's default) with
  ``--robust-threshold`` 0.5 px (the default): s^2 log(1 + (r / s)^2) with s = 0.5 px on every image residual
  (pixels, all observations of the block, outliers not removed beforehand). ASP minimises with Ceres; here
  Levenberg-Marquardt with the image residuals reweighted by the Cauchy rho' each iteration and a sparse direct solve
  (analytic Jacobian: the node hats times the engine's derivatives of a constant attitude increment, checked against
  finite differences). scipy's ``least_squares`` (trf, lsmr, the same loss as a callable, ``--scipy-nfev``) was
  tried first: on 150 points at 250 lines per pose it had not converged after 1500 evaluations (15 s; residual RMS
  0.49, 0.35, 0.22 px after 60, 300, 1500), where this solver stops in 20-70 evaluations.
* ``--smoothness-weight`` (default 0, "0.01 to 0.1 recommended", "internally adjusted based on the initial curvature
  of the sequence of orientations"): a penalty on the second differences of the sequence of orientations. The
  internal adjustment is not documented, so this referee puts the penalty in pixels, the unit of every ASP cost:
  w * (c[k-1] - 2 c[k] + c[k+1]) * f / pixel size per node, image and axis, not robust. Its weights are not ASP's
  numbers; three of them (``--weights``) span none (ASP's default) to strong.
* positions are held (ASP: "the camera positions are likely accurate", ``--camera-position-weight`` 1e+4 - 1e+6 to
  keep them); ``--rotation-weight`` 0 (its default; "suggested not to use"); no ``--tri-weight``, no DEM or anchor
  points: the five GCPs are observations of their points (quadratic, with their sigma), as in selfcal's block.
* ASP reports reprojection errors per camera and per point; it gives no a-posteriori sigma of the poses, and neither
  does this referee.

Printed per case: image residual RMS (px, both coordinates, every observation), the jitter error against the truth
(urad RMS, roll and pitch, in all and in what the tie points see: :meth:`PrismTruth.jitter_error_of`, the definition
of ``study_jitter.py``), check-point RMSE across / along / up (m: the adjusted tie points against their true
coordinates), the number of evaluations and the time; then selfcal's ``--jitter auto`` with the same numbers and the
sigma of its jitter terms.
"""
from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares
from scipy.sparse.linalg import spsolve

from selfcal.adjust import AdjustOptions, SensorOptions
from selfcal.sensors.pushbroom.model import LineImage, image_residuals, image_scales
from selfcal.sensors.pushbroom.sensor import jitter_table
from selfcal.simulate.prism import JITTER, prism_block, simulate_prism
from selfcal.stats.snooping import SnoopingOptions
from selfcal.workflows import seed001
from selfcal.workflows.jitter import choose_jitter

TRUE_FOCAL_MM = {"F": 1938.20, "N": 1937.45, "B": 1936.66}
#: jitter_solve / bundle_adjust ``--robust-threshold`` default (pixels), with the default Cauchy cost function
ASP_ROBUST_THRESHOLD_PX = 0.5
SAMPLES = 2001


@dataclass(frozen=True)
class Hats:
    """Piecewise-linear interpolation of poses every ``lines`` lines: hat functions of tau = row / rows."""

    rows: int
    lines: int

    @property
    def size(self) -> int:
        return int(np.ceil(self.rows / self.lines)) + 1

    def __call__(self, tau) -> np.ndarray:
        u = np.atleast_1d(np.asarray(tau, float)) * self.rows / self.lines
        return np.maximum(0.0, 1.0 - np.abs(u[:, None] - np.arange(self.size)[None, :]))

    def combine(self, tau, coefficients) -> np.ndarray:
        """The poses' corrections at tau, (n, k) for ``coefficients`` (k, size): what a line image asks of its
        jitter basis (:meth:`selfcal.sensors.pushbroom.jitter.TimeWaveletBasis.combine`)."""
        return self(tau) @ np.atleast_2d(np.asarray(coefficients, float)).T


def start_case(seed: int, n_points: int):
    """The simulated triplet with jitter, its block, GCPs and seed 001's M5 (bias and drift) on it."""
    sim = simulate_prism(seed=seed, n_points=n_points, jitter=JITTER)
    block = seed001.with_focal(prism_block(sim, seed=seed), TRUE_FOCAL_MM)
    gcps = seed001.choose_gcps(block, None)
    t = time.perf_counter()
    c = seed001.run_case(block, "M5", gcps, (0, 1, 2), None, "F+N+B", AdjustOptions(sensor=SensorOptions(model="M5")))
    return sim, block, gcps, c, time.perf_counter() - t


class Referee:
    """ASP's jitter_solve as this module's docstring describes it, on the observations of a selfcal result."""

    def __init__(self, result, track_axes, lines_per_pose: int):
        problem = result.problem
        slot = problem.sensors[0]
        bound = slot.bound
        context = bound.context(result.state)
        self.image_index = [int(i) for i in slot.images]
        self.images: list[LineImage] = [context[i] for i in self.image_index]
        o = np.asarray(slot.observations)
        position = {i: k for k, i in enumerate(self.image_index)}
        self.obs_image = np.array([position[int(i)] for i in problem.obs_image[o]])
        self.obs_point_block = problem.obs_point[o]
        self.row, self.col = bound.row[o], bound.col[o]
        self.point_ids = np.unique(self.obs_point_block)
        self.obs_point = np.searchsorted(self.point_ids, self.obs_point_block)
        self.points0 = result.state.points[self.point_ids].copy()
        role = problem.point_role[self.point_ids]
        self.check = np.flatnonzero(role == "chk")
        self.reference = result.block.points.xyz_m[self.point_ids]
        self.track_axes = track_axes
        control = problem.control
        self.gcp = np.searchsorted(self.point_ids, control.index)
        self.gcp_xyz = np.asarray(control.xyz, float)
        self.gcp_root = np.asarray(control.W, float)          # (n, 3, 3): W^T W the inverse covariance
        self.hats = [Hats(image.rows, lines_per_pose) for image in self.images]
        self.m = self.hats[0].size
        self.px_per_rad = np.array([image.parameters[6] / image.camera.pixel_size_mm for image in self.images])
        self.by_image = [np.flatnonzero(self.obs_image == k) for k in range(len(self.images))]
        self.tau_B = [h(self.row[o] / image.rows) for h, image, o in zip(self.hats, self.images, self.by_image)]
        self.scales = [image_scales(image, self.points0[self.obs_point[o]], self.row[o], self.col[o])
                       for image, o in zip(self.images, self.by_image)]
        self.n_pose = 3 * self.m * len(self.images)
        self.n_obs = len(self.row)

    # --- unknowns: node corrections (urad) per image, axis, node; then the points' shifts (m) ---
    def split(self, x):
        coeff = x[:self.n_pose].reshape(len(self.images), 3, self.m) * 1e-6
        return coeff, self.points0 + x[self.n_pose:].reshape(-1, 3)

    def corrected(self, coeff) -> list[LineImage]:
        return [image.with_parameters(image.parameters, jitter=(h, c))
                for image, h, c in zip(self.images, self.hats, coeff)]

    def image_residuals(self, images, points, jacobians=False):
        res = np.zeros((self.n_obs, 2))
        d_par = np.zeros((self.n_obs, 2, 10)) if jacobians else None
        d_pt = np.zeros((self.n_obs, 2, 3)) if jacobians else None
        for k, o in enumerate(self.by_image):
            out = image_residuals(images[k], points[self.obs_point[o]], self.row[o], self.col[o], jacobians,
                                  self.scales[k])
            if jacobians:
                res[o], d_par[o], d_pt[o] = out
            else:
                res[o] = out
        return (res, d_par, d_pt) if jacobians else res

    def residuals(self, x, weight):
        coeff, points = self.split(x)
        res = self.image_residuals(self.corrected(coeff), points)
        gcp = np.einsum("nij,nj->ni", self.gcp_root, points[self.gcp] - self.gcp_xyz)
        second = coeff[:, :, :-2] - 2 * coeff[:, :, 1:-1] + coeff[:, :, 2:]
        smooth = weight * second * self.px_per_rad[:, None, None]
        return np.concatenate([res.ravel(), gcp.ravel(), smooth.ravel()])

    def jacobian(self, x, weight):
        coeff, points = self.split(x)
        _, d_par, d_pt = self.image_residuals(self.corrected(coeff), points, True)
        rows, cols, vals = [], [], []
        n_pts = len(self.points0)
        for k, o in enumerate(self.by_image):
            B = self.tau_B[k]                                   # (n, m)
            for a in range(3):                                  # d res / d c = -(d computed / d constant of axis a) B
                d = -d_par[o][:, :, 2 * a]                      # (n, 2)
                nz_r, nz_k = np.nonzero(B)
                for c2 in range(2):
                    rows.append(2 * o[nz_r] + c2)
                    cols.append(k * 3 * self.m + a * self.m + nz_k)
                    vals.append(d[nz_r, c2] * B[nz_r, nz_k] * 1e-6)
        for c2 in range(2):
            for j in range(3):
                rows.append(2 * np.arange(self.n_obs) + c2)
                cols.append(self.n_pose + 3 * self.obs_point + j)
                vals.append(-d_pt[:, c2, j])
        base = 2 * self.n_obs
        for g, (p, R) in enumerate(zip(self.gcp, self.gcp_root)):
            for i in range(3):
                for j in range(3):
                    rows.append(np.array([base + 3 * g + i]))
                    cols.append(np.array([self.n_pose + 3 * p + j]))
                    vals.append(np.array([R[i, j]]))
        base += 3 * len(self.gcp)
        n_second = self.m - 2
        for k in range(len(self.images)):
            for a in range(3):
                for s in range(n_second):
                    r = base + (k * 3 + a) * n_second + s
                    for off, v in ((0, 1.0), (1, -2.0), (2, 1.0)):
                        rows.append(np.array([r]))
                        cols.append(np.array([k * 3 * self.m + a * self.m + s + off]))
                        vals.append(np.array([weight * v * self.px_per_rad[k] * 1e-6]))
        shape = (base + len(self.images) * 3 * n_second, self.n_pose + 3 * n_pts)
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=shape)

    def loss(self, z):
        """Cauchy on the image residuals (ASP's cost function), quadratic on the GCPs and the smoothness."""
        out = np.empty((3, len(z)))
        n = 2 * self.n_obs
        out[0, :n] = np.log1p(z[:n])
        out[1, :n] = 1.0 / (1.0 + z[:n])
        out[2, :n] = -1.0 / (1.0 + z[:n]) ** 2
        out[0, n:], out[1, n:], out[2, n:] = z[n:], 1.0, 0.0
        return out

    def cost(self, f) -> float:
        """ASP's cost: s^2 log(1 + (r / s)^2) per image residual (Cauchy, s the robust threshold), r^2 otherwise."""
        return float(self.loss((f / ASP_ROBUST_THRESHOLD_PX) ** 2)[0].sum() * ASP_ROBUST_THRESHOLD_PX ** 2)

    def solve(self, weight: float, iterations: int = 100, scipy_nfev: int = 0):
        """Minimise the cost: Levenberg-Marquardt on the Cauchy cost, the image residuals reweighted by rho'
        (iteratively reweighted least squares, as Ceres does for a robust loss), a sparse direct solve of the normal
        equations. ``scipy_nfev`` > 0: scipy's least_squares (trf, lsmr, the same loss) instead, at most that many
        evaluations (it converges slowly here: see the module docstring)."""
        x = np.zeros(self.n_pose + 3 * len(self.points0))
        t = time.perf_counter()
        if scipy_nfev:
            fit = least_squares(self.residuals, x, jac=self.jacobian, args=(weight,), method="trf", tr_solver="lsmr",
                                loss=self.loss, f_scale=ASP_ROBUST_THRESHOLD_PX, max_nfev=scipy_nfev)
            return RefereeFit(self, weight, fit.x, fit.nfev, time.perf_counter() - t, fit.status)
        f = self.residuals(x, weight)
        cost, lam, n_eval, status = self.cost(f), 1e-4, 1, 0
        n_img = 2 * self.n_obs
        for _ in range(iterations):
            J = self.jacobian(x, weight)
            w = np.ones(len(f))
            w[:n_img] = self.loss((f[:n_img] / ASP_ROBUST_THRESHOLD_PX) ** 2)[1]
            A = (J.T @ sp.diags(w) @ J).tocsc()
            g = J.T @ (w * f)
            d = A.diagonal()
            while True:
                dx = spsolve(A + sp.diags(lam * d + 1e-12 * d.max()), -g)
                f_new = self.residuals(x + dx, weight)
                n_eval += 1
                cost_new = self.cost(f_new)
                if cost_new < cost:
                    break
                lam *= 10.0
                if lam > 1e8:
                    break
            if cost_new >= cost:
                status = 2                       # no step lowers the cost: converged
                break
            x, f, gain, cost = x + dx, f_new, cost - cost_new, cost_new
            lam = max(lam / 10.0, 1e-8)
            if gain < 1e-10 * cost:
                status = 1
                break
        return RefereeFit(self, weight, x, n_eval, time.perf_counter() - t, status)

    # --- evaluation ---
    def residual_rms_px(self, images, points) -> float:
        return float(np.sqrt(np.mean(self.image_residuals(images, points) ** 2)))

    def check_rmse_m(self, points) -> np.ndarray:
        e = (points[self.check] - self.reference[self.check]) @ self.track_axes.T
        return np.sqrt(np.mean(e ** 2, axis=0))

    def curves(self, coeff) -> list[np.ndarray]:
        """Each image's estimated roll, pitch, yaw correction beyond its linear part (rad, (SAMPLES, 3))."""
        out = []
        for image, h, c in zip(self.images, self.hats, coeff):
            rows = np.linspace(0, image.rows, SAMPLES)
            curve = h(rows / image.rows) @ c.T
            V = np.stack([np.ones(SAMPLES), 2 * rows / image.rows - 1], -1)
            out.append(curve - V @ np.linalg.lstsq(V, curve, rcond=None)[0])
        return out


@dataclass
class RefereeFit:
    referee: Referee
    weight: float
    x: np.ndarray
    nfev: int
    seconds: float
    status: int

    @property
    def coeff(self):
        return self.referee.split(self.x)[0]

    @property
    def points(self):
        return self.referee.split(self.x)[1]

    def residual_rms_px(self) -> float:
        return self.referee.residual_rms_px(self.referee.corrected(self.coeff), self.points)

    def jitter_error_urad(self, truth):
        return truth.jitter_error_of(self.referee.images, self.referee.curves(self.coeff))


def ours(block, gcps):
    """selfcal's ``--jitter auto`` on the same block: the choice, then seed 001's case with it."""
    base = AdjustOptions(sensor=SensorOptions(model="M5"))
    t = time.perf_counter()
    choice = choose_jitter(seed001.case_block(block, (0, 1, 2), gcps),
                           AdjustOptions(sensor=SensorOptions(model="M5", jitter="auto")))
    chosen_s = time.perf_counter() - t
    t = time.perf_counter()
    c = seed001.run_case(block, "M5", gcps, (0, 1, 2), None, "F+N+B", choice.options(base), SnoopingOptions())
    return choice, c, chosen_s, time.perf_counter() - t


def evaluate_result(referee: Referee, result):
    """A selfcal result in the referee's numbers: residual RMS (px) over the same observations, check RMSE."""
    bound = result.problem.sensors[0].bound
    context = bound.context(result.state)
    images = [context[i] for i in referee.image_index]
    points = result.state.points[referee.point_ids]
    return referee.residual_rms_px(images, points), referee.check_rmse_m(points)


def row(name, rms, error, rmse, extra):
    return (f"{name:<26} {rms:7.3f}  {error[0][0]:6.2f} {error[0][1]:6.2f}  {error[1][0]:6.2f} {error[1][1]:6.2f}  "
            f"{rmse[0]:6.2f} {rmse[1]:6.2f} {rmse[2]:6.2f}  {extra}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="1")
    parser.add_argument("--points", type=int, default=1500)
    parser.add_argument("--lines-per-pose", type=int, default=250)
    parser.add_argument("--weights", default="0,1,3")
    parser.add_argument("--scipy-nfev", type=int, default=0, help="scipy's least_squares, at most this many "
                        "evaluations, instead of the Levenberg-Marquardt")
    args = parser.parse_args()
    weights = [float(w) for w in args.weights.split(",")]
    for seed in (int(s) for s in args.seeds.split(",")):
        sim, block, gcps, c, m5_s = start_case(seed, args.points)
        referee = Referee(c.result, c.track_axes, args.lines_per_pose)
        print(f"seed {seed}: {len(referee.points0)} points, {referee.n_obs} image observations, {len(referee.gcp)} GCP; "
              f"referee: {referee.m} nodes every {args.lines_per_pose} lines x 3 axes x 3 images, Cauchy "
              f"{ASP_ROBUST_THRESHOLD_PX} px")
        print(f"{'case':<26} {'res px':>7}  {'jitter err roll/pitch':>13}  {'seen roll/pitch':>13}  "
              f"{'across':>6} {'along':>6} {'up':>6}  time, sigma")
        zero = [np.zeros((SAMPLES, 3))] * len(referee.images)
        rms, rmse = evaluate_result(referee, c.result)
        print(row("bias+drift (M5, start)", rms, sim.truth.jitter_error_of(referee.images, zero), rmse,
                  f"{m5_s:.1f} s"), flush=True)
        for w in weights:
            fit = referee.solve(w, scipy_nfev=args.scipy_nfev)
            print(row(f"ASP referee w={w:g}", fit.residual_rms_px(), fit.jitter_error_urad(sim.truth),
                      referee.check_rmse_m(fit.points),
                      f"{fit.seconds:.1f} s ({fit.nfev} evaluations, status {fit.status}), no sigma"), flush=True)
        choice, ca, chosen_s, adjust_s = ours(block, gcps)
        r = ca.result
        rms, rmse = evaluate_result(referee, r)
        header, columns, _ = jitter_table(r, r.problem.sensors[0])
        sigma = columns[header.index("sigma_urad")]
        finite = np.isfinite(sigma)
        print(row(f"selfcal {choice.spec.replace('wavelet1d:', '')}", rms, sim.truth.jitter_error_urad(r), rmse,
                  f"{chosen_s + adjust_s:.1f} s (choice {chosen_s:.1f} + adjustment {adjust_s:.1f}); sigma for "
                  f"{finite.sum()}/{len(sigma)} terms, median {np.median(sigma[finite]):.2f} urad"), flush=True)


if __name__ == "__main__":
    main()
