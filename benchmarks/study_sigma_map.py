"""Does the σ of the AP correction (distortion_sigma.csv) say how much the correction scatters? (issue 40 item 5)

Seed 000's 28-image block (Type 1 control, a Brown lens: ``--truth``), the same geometry over ``--seeds`` noise
seeds (:func:`selfcal.simulate.simulate_uav` ``noise_seed``: new image and survey noise, everything else kept);
each seed adjusted with every AP family (the basis built once, on the first seed, and kept, as a results folder's
model is). On the 61 x 41 grid of distortion_sigma.csv, at the nodes where observations lie:

* ``emp/pred``: sqrt of the empirical variance of Δ over the seeds (both axes, summed over the nodes) over the
  variance predicted by the covariance (the mean over seeds of σ̂0² Q, as the file gives it; ``a-priori``: of Q
  with the a-priori σ), with the 1-σ sampling error of that ratio: the summed empirical variance is a weighted sum
  of χ²(n - 1) variables whose weights are the eigenvalues of Σ^(1/2) G Σ^(1/2) (G the nodes' Gram matrix of the
  basis), so its relative standard deviation is sqrt(2 Σλ² / (n - 1)) / Σλ;
* ``node ratio``: sqrt(empirical / predicted variance) per node and axis: median, 5th and 95th percentile, and the
  share within 15 % (one node's variance from n seeds scatters by sqrt(2 / (n - 1)) itself: 20 % at 50 seeds);
* ``chi2/dof``: the coefficients' scatter against their covariance, Σ_s (a_s - ā)^T Σ^-1 (a_s - ā) over
  (n - 1) k (1 under a right covariance, its sampling error sqrt(2 / ((n - 1) k))).

``--screened`` adds each family with the AP set screening keeps on the first seed, held for every seed (the σ of a
screened set is conditional on the set).

``--half-block`` instead runs the half-block check (selfcal.workflows.half_block) on every seed, the model right (no
alarm should be raised but at its α = 0.001), and with the camera of strips S3, S4 changed by ``--change`` px of
radial distortion in the corners (found how often): the share flagged and the mean T / dof.

    python benchmarks/study_sigma_map.py [--seeds 50] [--families brown,wavelet:db4,...] [--density 3.5]
    python benchmarks/study_sigma_map.py --half-block [--seeds 30] [--change 4]
"""
from __future__ import annotations

import argparse
import gc
import time
from dataclasses import dataclass

import numpy as np

from selfcal.adjust import AdjustOptions, APOptions, adjust
from selfcal.simulate import simulate_uav
from selfcal.stats.field_sigma import ap_estimate, correction_sigma, grid_nodes
from selfcal.workflows.tested import prune_for

FAMILIES = ("brown", "ebner", "gruen", "legendre", "fourier", "wavelet:db4", "wavelet:sym4", "wavelet:meyer",
            "wavelet:bl4")


@dataclass
class MonteCarlo:
    """The corrections of one AP model over noise seeds, and the covariances the adjustments predicted."""

    model: str
    fields: np.ndarray          # (n_seeds, n_nodes, 2) Δ at the nodes, px, photo axes
    coefficients: np.ndarray    # (n_seeds, k)
    covariance: np.ndarray      # (n_seeds, k, k) σ̂0² Q of each seed
    variance_factor: np.ndarray
    bx: np.ndarray              # (n_nodes, k) the basis at the nodes
    by: np.ndarray
    observed: np.ndarray        # (n_nodes,) bool
    sigma0_px: np.ndarray
    seconds: float

    @property
    def n(self) -> int:
        return len(self.fields)

    def predicted(self, apriori: bool = False) -> np.ndarray:
        """The mean predicted covariance of the coefficients (a-posteriori, or a-priori: Q with unit variance
        factor)."""
        cov = self.covariance / self.variance_factor[:, None, None] if apriori else self.covariance
        return cov.mean(axis=0)

    def node_variances(self, apriori: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(empirical, predicted) variance (n_observed_nodes, 2) of Δ at the observed nodes."""
        emp = self.fields[:, self.observed].var(axis=0, ddof=1)
        C = self.predicted(apriori)
        bx, by = self.bx[self.observed], self.by[self.observed]
        pred = np.column_stack([np.einsum("ij,jk,ik->i", bx, C, bx), np.einsum("ij,jk,ik->i", by, C, by)])
        return emp, pred

    def node_ratios(self, apriori: bool = False) -> np.ndarray:
        """sqrt(empirical / predicted variance) per observed node and axis, where the basis is not zero (Brown's
        correction is zero at the frame's centre whatever its coefficients)."""
        emp, pred = self.node_variances(apriori)
        some = pred > 1e-12 * pred.max()
        return np.sqrt(emp[some] / pred[some])

    def aggregate(self, apriori: bool = False) -> tuple[float, float]:
        """sqrt(summed empirical / summed predicted variance) over the observed nodes, and its relative sampling
        standard deviation under a right covariance (module docstring)."""
        emp, pred = self.node_variances(apriori)
        C = self.predicted(apriori)
        bx, by = self.bx[self.observed], self.by[self.observed]
        G = bx.T @ bx + by.T @ by
        w, V = np.linalg.eigh(C)
        root = (V * np.sqrt(np.clip(w, 0, None))) @ V.T
        lam = np.linalg.eigvalsh(root @ G @ root)
        rel_var = np.sqrt(2.0 * np.sum(lam ** 2) / (self.n - 1)) / np.sum(lam)
        return float(np.sqrt(emp.sum() / pred.sum())), float(0.5 * rel_var)

    def chi2_per_dof(self, apriori: bool = False) -> tuple[float, int]:
        """Σ_s (a_s - ā)^T Σ^-1 (a_s - ā) / ((n - 1) k) and its degrees of freedom (n - 1) k."""
        C = self.predicted(apriori)
        d = self.coefficients - self.coefficients.mean(axis=0)
        scale = np.sqrt(np.diag(C))
        w, V = np.linalg.eigh(C / scale[:, None] / scale[None, :])
        keep = w > 1e-10 * w.max()
        z = (d / scale) @ V[:, keep]
        dof = (self.n - 1) * int(keep.sum())
        return float(np.sum(z * z / w[keep]) / dof), dof


def block_of(noise_seed: int, truth: str = "brown", points_per_mm2: float = 3.5, scenario: str = "type1",
             geometry_seed: int = 1, **simulate):
    """The block of one noise seed: the same geometry every time."""
    return prune_for(simulate_uav(seed=geometry_seed, distortion=truth, points_per_mm2=points_per_mm2,
                                  noise_seed=noise_seed, **simulate).blocks[scenario])


def monte_carlo(model: str, seeds, truth: str = "brown", points_per_mm2: float = 3.5, grid=(9, 6),
                screened: bool = False, scenario: str = "type1", **simulate) -> MonteCarlo:
    """Adjust the block of every noise seed with ``model`` (the basis, and with ``screened`` the AP set screening
    keeps, from the first seed) and collect Δ on the grid and the predicted covariances."""
    from selfcal.stats.screening import ScreeningOptions
    from selfcal.workflows.tested import adjust_with_tests
    t0 = time.perf_counter()
    options = AdjustOptions(ap=APOptions(model, grid=tuple(grid)))
    models = free = None
    fields, coefficients, covariances, factors, sigma0 = [], [], [], [], []
    bx = by = observed = None
    for s in seeds:
        block = block_of(s, truth, points_per_mm2, scenario, **simulate)
        if models is None and screened:
            first = adjust_with_tests(block, options, None, ScreeningOptions())
            models = {cam.camera_id: cam.ap for cam in first.result.problem.cameras}
            free = first.ap_free
        result = adjust(block, options, ap_models=models, free=free)
        if models is None:
            models = {cam.camera_id: cam.ap for cam in result.problem.cameras}
        estimated, a, C = ap_estimate(result, 0)
        if bx is None:
            x, y, _, _ = grid_nodes(result, 0)
            bx, by = result.problem.cameras[0].ap.basis(x, y)
            bx, by = bx[:, estimated], by[:, estimated]
            observed = correction_sigma(result, 0).observed
        fields.append(np.column_stack([bx @ a, by @ a]))
        coefficients.append(a)
        covariances.append(C)
        factors.append(result.variance_factor)
        sigma0.append(result.sigma0_px)
        del result
        gc.collect()            # (an adjustment's objects hold each other: collected now, not gigabytes later)
    return MonteCarlo(model + (" screened" if screened else ""), np.array(fields), np.array(coefficients),
                      np.array(covariances), np.array(factors), bx, by, observed, np.array(sigma0),
                      time.perf_counter() - t0)


def changed_camera(block, radial_px: float):
    """``block`` whose strips S3 and S4 were taken by a camera whose radial distortion grew by ``radial_px`` in the
    frame's corners (a k1 term of Brown's basis, 6000 x 4000 px): a camera that changed during the flight."""
    from dataclasses import replace
    ob = block.observations
    late = np.isin(np.asarray(block.images.strip_id)[ob.image_index], ["S3", "S4"])
    r0 = np.hypot(3000.0, 2000.0)
    u, v = (ob.pixel[:, 0] - 3000.0) / r0, (ob.pixel[:, 1] - 2000.0) / r0
    r2 = u * u + v * v
    pixel = ob.pixel.copy()
    pixel[late, 0] += radial_px * (u * r2)[late]
    pixel[late, 1] += radial_px * (v * r2)[late]
    return replace(block, observations=replace(ob, pixel=pixel))


def half_block_rates(model: str, seeds, change_px: float, truth: str = "brown", points_per_mm2: float = 3.5):
    """Over the noise seeds: (share flagged, mean T / dof) of the half-block check with the camera unchanged and
    with it changed by ``change_px``."""
    from selfcal.workflows.adjust import AdjustRequest, adjust_block
    out = []
    for change in (0.0, change_px):
        flags, ratios = [], []
        for s in seeds:
            block = changed_camera(block_of(s, truth, points_per_mm2), change)
            done = adjust_block(block, AdjustRequest(options=AdjustOptions(ap=APOptions(model)), snooping=None,
                                                     robust=None, control_loo=False))
            d = done.tested.half_block.cameras[0].difference
            flags.append(d.flag)
            ratios.append(d.statistic / d.dof)
            del done
            gc.collect()
        out.append((float(np.mean(flags)), float(np.mean(ratios))))
    return out


def row(mc: MonteCarlo) -> str:
    ratio, sd = mc.aggregate()
    ratio0, sd0 = mc.aggregate(apriori=True)
    nodes = mc.node_ratios()
    chi2, dof = mc.chi2_per_dof()
    within = float(np.mean(np.abs(nodes - 1.0) <= 0.15))
    return (f"| {mc.model} | {mc.coefficients.shape[1]} | {mc.sigma0_px.mean():.3f} | {ratio:.3f} ± {sd:.3f} | "
            f"{ratio0:.3f} ± {sd0:.3f} | {np.median(nodes):.3f} | {np.percentile(nodes, 5):.2f}-"
            f"{np.percentile(nodes, 95):.2f} | {within:.0%} | {chi2:.3f} ± {np.sqrt(2.0 / dof):.3f} | "
            f"{mc.seconds:.0f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=50)
    parser.add_argument("--families", default=",".join(FAMILIES))
    parser.add_argument("--truth", default="brown", help="the simulated lens (none, brown, local, local+brown)")
    parser.add_argument("--density", type=float, default=3.5, help="image points per mm^2")
    parser.add_argument("--screened", action="store_true", help="also each family's screened set")
    parser.add_argument("--half-block", action="store_true", help="the half-block check's alarms instead")
    parser.add_argument("--change", type=float, default=4.0, help="px of radial distortion the camera changes by")
    args = parser.parse_args()
    if args.half_block:
        print(f"{args.seeds} noise seeds, seed 000's block (Type 1), a '{args.truth}' lens, {args.density} "
              f"points/mm^2; strips S1, S2 | S3, S4\n")
        print(f"| model | flagged, right model | mean T/dof | flagged, camera changed by {args.change:g} px | "
              "mean T/dof |")
        print("|---|---|---|---|---|")
        for model in args.families.split(","):
            (f0, r0), (f1, r1) = half_block_rates(model, range(args.seeds), args.change, args.truth, args.density)
            print(f"| {model} | {f0:.0%} | {r0:.3f} | {f1:.0%} | {r1:.3f} |", flush=True)
        return
    print(f"{args.seeds} noise seeds, seed 000's block (Type 1), a '{args.truth}' lens, {args.density} points/mm^2\n")
    print("| model | k | mean σ̂0 [px] | emp/pred (a-posteriori) | emp/pred (a-priori) | node ratio median | "
          "P5-P95 | nodes within 15 % | chi2/dof | s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for model in args.families.split(","):
        for screened in (False, True) if args.screened else (False,):
            mc = monte_carlo(model, range(args.seeds), args.truth, args.density, screened=screened)
            print(row(mc), flush=True)


if __name__ == "__main__":
    main()
