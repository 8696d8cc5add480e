"""The report's figures (matplotlib), each from plain arrays; nothing here reads files.

Every function returns a :class:`matplotlib.figure.Figure` built without pyplot
(no global state, no display needed, safe in worker processes). Image-space
figures draw the frame as it is seen: column to the right, row down, pixels as
unit; vectors along the pixel axes, with a scale arrow. Object-space figures
draw easting to the right and northing up, in metres.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:                     # matplotlib loads with the first figure, not with the report's import
    from matplotlib.figure import Figure


def _figure(**kwargs) -> Figure:
    """A matplotlib Figure without pyplot (matplotlib imported here, at the first figure: 0.4 s of a report)."""
    from matplotlib.figure import Figure
    return Figure(**kwargs)


__all__ = ["distortion_figure", "sigma_map_figure", "residual_grid_figure", "residual_histogram_figure",
           "control_error_figure", "correlation_figure", "precision_map_figure", "comparison_figure", "grid_mean_vectors",
           "robust_weight_figure", "rejection_map_figure", "camera_layout_figure", "OVERLAP_TOP",
           "nice_length", "length_unit"]

_WIDTH_IN = 7.5   # fits an A4 page with margins


def nice_length(value: float) -> float:
    """A round number (1, 2 or 5 times a power of ten) not larger than ``value``, for scale arrows."""
    if not value > 0 or not math.isfinite(value):
        return 1.0
    power = 10.0 ** math.floor(math.log10(value))
    for step in (5.0, 2.0, 1.0):
        if step * power <= value:
            return step * power
    return power


def length_unit(values_m: np.ndarray) -> tuple[str, float]:
    """('mm', 1000) for lengths below 0.1 m, ('cm', 100) below 2 m, else ('m', 1)."""
    finite = np.abs(values_m[np.isfinite(values_m)])
    largest = float(finite.max()) if finite.size else 0.0
    if largest < 0.1:
        return "mm", 1000.0
    if largest < 2.0:
        return "cm", 100.0
    return "m", 1.0


def _frame_axes(ax, width_px: float, height_px: float) -> None:
    ax.set_xlim(0, width_px)
    ax.set_ylim(height_px, 0)
    ax.set_aspect("equal")
    ax.set_xlabel("column [px]")
    ax.set_ylabel("row [px]")


def _vectors(ax, x, y, u, v, spacing: float, unit: str, color="C0", key_pos=(0.82, 1.04)):
    """Quiver with the largest vector about 1.2 ``spacing`` long and a round-numbered scale arrow.

    Vectors point from (x, y) to (x + u, y + v) in data coordinates, so on image
    axes (row down) ``v`` is along the row.
    """
    length = np.hypot(u, v)
    largest = float(np.nanmax(length)) if length.size and np.isfinite(length).any() else 0.0
    if largest <= 0:
        ax.plot(x, y, ".", color=color, ms=2)
        return
    scale = largest / (1.2 * spacing)           # data units of the vector per axis unit
    q = ax.quiver(x, y, u, v, angles="xy", scale_units="xy", scale=scale, color=color,
                  width=0.003, headwidth=4, headlength=5, zorder=3)
    key = nice_length(largest / 2)
    ax.quiverkey(q, *key_pos, key, f"{key:g} {unit}", labelpos="E", coordinates="axes")


def distortion_figure(col: np.ndarray, row: np.ndarray, dcol: np.ndarray, drow: np.ndarray, width_px: float, height_px: float, title: str,
                      step: int = 4) -> Figure:
    """Estimated distortion Δ on the regular grid of distortion_grid.csv (Fig. 6 of seed 000).

    The colour is |Δ| on every node; arrows are drawn on every ``step``-th node.
    """
    fig = _figure(figsize=(_WIDTH_IN, _WIDTH_IN * height_px / width_px * 0.85 + 0.6), layout="constrained")
    ax = fig.add_subplot()
    nx = int(np.unique(col).size)
    ny = col.size // max(nx, 1)
    magnitude = np.hypot(dcol, drow)
    gridded = nx * ny == col.size and nx > 1 and ny > 1
    if gridded:
        mesh = ax.pcolormesh(col.reshape(ny, nx), row.reshape(ny, nx), magnitude.reshape(ny, nx),
                             shading="gouraud", cmap="viridis", rasterized=True)
        fig.colorbar(mesh, ax=ax, label="|Δ| [px]", shrink=0.85)
        every = np.zeros((ny, nx), bool)
        every[::step, ::step] = True
        pick = every.ravel()
        spacing = step * width_px / (nx - 1)
    else:
        pick = np.ones(col.size, bool)
        spacing = width_px / 15
    _vectors(ax, col[pick], row[pick], dcol[pick], drow[pick], spacing, "px", color="white" if gridded else "C0")
    _frame_axes(ax, width_px, height_px)
    ax.set_title(f"{title}: max |Δ| {float(np.max(magnitude)) if magnitude.size else 0:.2f} px", loc="left",
                 fontsize=10)
    return fig


def _observed_outline(ax, col: np.ndarray, row: np.ndarray, observed: np.ndarray, nx: int, ny: int) -> None:
    """The observed area's outline (blue: it shows on both colour maps' ends) and the rest hatched."""
    mask = observed.reshape(ny, nx).astype(float)
    C, R = col.reshape(ny, nx), row.reshape(ny, nx)
    if 0.0 < mask.mean() < 1.0:
        ax.contourf(C, R, mask, levels=[-0.5, 0.5], colors="none", hatches=["////"], zorder=2)
        ax.contour(C, R, mask, levels=[0.5], colors="#1f77b4", linewidths=1.8, zorder=3)


def sigma_map_figure(col: np.ndarray, row: np.ndarray, sigma_px: np.ndarray, observed: np.ndarray, width_px: float,
                     height_px: float, title: str, difference: tuple | None = None, step: int = 4) -> Figure:
    """The σ of the correction Δ on the grid of distortion_sigma.csv (colour, its scale up to the observed area's
    95th percentile: beyond it the σ may be a hundred times larger), the observed area outlined and the rest hatched; with ``difference`` =
    (ddcol, ddrow, sigma_dcol, sigma_drow, label) a second panel: the half-block difference of the correction,
    |difference| / σ of the worse axis as colour and the vectors on every ``step``-th observed node."""
    nx = int(np.unique(col).size)
    ny = col.size // max(nx, 1)
    panels = 2 if difference is not None else 1
    fig = _figure(figsize=(_WIDTH_IN, panels * (_WIDTH_IN * height_px / width_px * 0.85) + 0.7), layout="constrained")
    axes = fig.subplots(panels, 1, squeeze=False)[:, 0]
    gridded = nx * ny == col.size and nx > 1 and ny > 1
    ax = axes[0]
    seen = observed.astype(bool)
    inside = float(np.max(sigma_px[seen])) if seen.any() else float("nan")
    # the colours span the observed area's σ up to its 95th percentile (at the edge of the observations, and beyond
    # them, it can be a hundred times larger)
    top = float(np.percentile(sigma_px[seen], 95)) if seen.any() else float(np.max(sigma_px))
    top = top if top > 0 else 1.0
    if gridded:
        mesh = ax.pcolormesh(col.reshape(ny, nx), row.reshape(ny, nx), sigma_px.reshape(ny, nx), shading="gouraud",
                             cmap="magma", rasterized=True, vmin=0.0, vmax=top)
        fig.colorbar(mesh, ax=ax, label="σ of Δ [px]", shrink=0.85,
                     extend="max" if float(np.max(sigma_px)) > top * (1 + 1e-9) else "neither")
        _observed_outline(ax, col, row, observed, nx, ny)
    _frame_axes(ax, width_px, height_px)
    ax.set_title(f"{title}: max σ {inside:.3f} px where observed (outlined), {float(np.max(sigma_px)):.3f} px on "
                 "the frame", loc="left", fontsize=9)
    if difference is not None:
        ddcol, ddrow, scol, srow, label = difference
        ax = axes[1]
        with np.errstate(invalid="ignore", divide="ignore"):
            # (a node where the correction has no variance, Brown's centre, has no difference either: 0 there)
            ratio = np.fmax(np.where(scol > 0, np.abs(ddcol) / scol, 0.0), np.where(srow > 0, np.abs(ddrow) / srow, 0.0))
        if gridded:
            shown = ratio[seen] if seen.any() else ratio
            top = max(4.0, float(np.nanmax(shown)) if np.isfinite(shown).any() else 4.0)
            mesh = ax.pcolormesh(col.reshape(ny, nx), row.reshape(ny, nx), ratio.reshape(ny, nx), shading="gouraud",
                                 cmap="RdYlGn_r", rasterized=True, vmin=0.0, vmax=top)
            fig.colorbar(mesh, ax=ax, label="|ΔΔ| / σ (worse axis)", shrink=0.85)
            _observed_outline(ax, col, row, observed, nx, ny)
            every = np.zeros((ny, nx), bool)
            every[::step, ::step] = True
            pick = every.ravel() & np.isfinite(ddcol) & (seen if seen.any() else True)
            _vectors(ax, col[pick], row[pick], ddcol[pick], ddrow[pick], step * width_px / (nx - 1), "px",
                     color="k")
        _frame_axes(ax, width_px, height_px)
        ax.set_title(label, loc="left", fontsize=9)
    return fig


def grid_mean_vectors(col: np.ndarray, row: np.ndarray, vcol: np.ndarray, vrow: np.ndarray, width_px: float,
                      height_px: float, grid: tuple[int, int]
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mean residual vector and count in each cell of a ``grid`` = (Gx, Gy) partition of the frame.

    Returns cell-centre columns and rows, mean vectors and counts, each (Gy, Gx).
    """
    gx, gy = grid
    ix = np.clip((col / width_px * gx).astype(int), 0, gx - 1)
    iy = np.clip((row / height_px * gy).astype(int), 0, gy - 1)
    cell = iy * gx + ix
    count = np.bincount(cell, minlength=gx * gy).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_c = np.bincount(cell, weights=vcol, minlength=gx * gy) / count
        mean_r = np.bincount(cell, weights=vrow, minlength=gx * gy) / count
    cx, cy = np.meshgrid((np.arange(gx) + 0.5) * width_px / gx, (np.arange(gy) + 0.5) * height_px / gy)
    shape = (gy, gx)
    return cx, cy, mean_c.reshape(shape), mean_r.reshape(shape), count.reshape(shape)


def residual_grid_figure(col: np.ndarray, row: np.ndarray, vcol: np.ndarray, vrow: np.ndarray, width_px: float, height_px: float, grid: tuple[int, int],
                         title: str) -> Figure:
    """Image residuals averaged in the cells of a Gx x Gy grid (Fig. 7 of seed 000): what the model left."""
    cx, cy, mc, mr, count = grid_mean_vectors(col, row, vcol, vrow, width_px, height_px, grid)
    fig = _figure(figsize=(_WIDTH_IN, _WIDTH_IN * height_px / width_px * 0.85 + 0.6), layout="constrained")
    ax = fig.add_subplot()
    gx, gy = grid
    for k in range(1, gx):
        ax.axvline(k * width_px / gx, color="0.85", lw=0.6, zorder=1)
    for k in range(1, gy):
        ax.axhline(k * height_px / gy, color="0.85", lw=0.6, zorder=1)
    ok = count > 0
    _vectors(ax, cx[ok], cy[ok], mc[ok], mr[ok], min(width_px / gx, height_px / gy), "px", color="C3")
    _frame_axes(ax, width_px, height_px)
    rms = float(np.sqrt(np.mean(mc[ok] ** 2 + mr[ok] ** 2))) if ok.any() else float("nan")
    ax.set_title(f"{title}: {gx}×{gy} cells, RMS of the cell means {rms:.3f} px", loc="left", fontsize=10)
    return fig


def residual_histogram_figure(vx: np.ndarray, vy: np.ndarray, sigma0_px: float, mean_redundancy: float, title: str,
                              half_width: float = 5.0) -> Figure:
    """Histograms of v_x and v_y with bins of width σ̂0 (Fig. 8 of seed 000).

    A residual of redundancy number r has the standard deviation σ̂0·√r, so the
    curve is the normal density with σ_v = σ̂0·√r̄ and the expected share within
    ±σ̂0 is that of this density. Values beyond ±``half_width``·σ̂0 are counted in
    the outermost bins (said in the legend).
    """
    fig = _figure(figsize=(_WIDTH_IN, 3.0), layout="constrained")
    axes = fig.subplots(1, 2, sharey=True)
    s = sigma0_px if sigma0_px and sigma0_px > 0 else float(np.std(np.concatenate([vx, vy])) or 1.0)
    edges = np.arange(-half_width, half_width + 1e-9, 1.0) * s
    grid = np.linspace(edges[0], edges[-1], 200)
    sv = s * math.sqrt(min(max(mean_redundancy, 1e-6), 1.0))
    expected = math.erf(s / (sv * math.sqrt(2))) * 100
    for ax, v, name in zip(axes, (vx, vy), ("v_x", "v_y")):
        v = v[np.isfinite(v)]
        clipped = np.clip(v, edges[0] + 1e-9 * s, edges[-1] - 1e-9 * s)
        ax.hist(clipped, bins=edges, color="C0", alpha=0.8, edgecolor="white")
        ax.plot(grid, v.size * s * np.exp(-0.5 * (grid / sv) ** 2) / (sv * math.sqrt(2 * math.pi)), color="C1",
                lw=1.2, label="N(0, σ̂0²·r̄)")
        within = float(np.mean(np.abs(v) <= s)) * 100 if v.size else float("nan")
        outside = int(np.sum(np.abs(v) > edges[-1]))
        ax.set_xlabel(f"${name}$ [px] (bins of σ̂0 = {s:.3f} px)")
        ax.set_title(f"{within:.1f} % within ±σ̂0 (normal: {expected:.1f} %)", fontsize=9)
        ax.legend(fontsize=7, title=f"{outside} beyond ±{half_width:g}σ̂0" if outside else None,
                  title_fontsize=7)
    axes[0].set_ylabel("observations")
    fig.suptitle(title, x=0.01, ha="left", fontsize=10)
    return fig


def control_error_figure(xy_m: np.ndarray, d_m: np.ndarray, role: np.ndarray, names: Sequence[str],
                         title: str) -> Figure:
    """Errors at control (triangles) and check points (circles): plan vectors and height arrows.

    ``d_m`` = adjusted - reference (n, 3); ``role`` "gcp" or "chk".
    """
    fig = _figure(figsize=(_WIDTH_IN, 3.8), layout="constrained")
    axes = fig.subplots(1, 2, sharex=True, sharey=True)
    unit, factor = length_unit(d_m)
    span = float(np.ptp(xy_m[:, 0]) + np.ptp(xy_m[:, 1])) / 2 if len(xy_m) > 1 else 1.0
    spacing = span / max(3.0, math.sqrt(len(xy_m)))
    origin = xy_m.mean(axis=0) if len(xy_m) else np.zeros(2)
    e, n = (xy_m - origin).T
    for ax, (u, v), what in ((axes[0], (d_m[:, 0], d_m[:, 1]), "plan (dX, dY)"),
                             (axes[1], (np.zeros(len(d_m)), d_m[:, 2]), "height (dZ, up = too high)")):
        for r, marker, label in (("gcp", "^", "control"), ("chk", "o", "check")):
            pick = role == r
            if pick.any():
                ax.plot(e[pick], n[pick], marker, color="0.3", ms=5, ls="none", label=label, zorder=2)
        _vectors(ax, e, n, u * factor, v * factor, spacing, unit, color="C3", key_pos=(0.75, 1.03))
        if len(names) <= 30:
            for x, y, t in zip(e, n, names):
                ax.annotate(str(t), (x, y), xytext=(3, -9), textcoords="offset points", fontsize=6, color="0.3")
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel("easting − mean [m]")
        ax.set_title(what, fontsize=9, loc="left")
    axes[0].set_ylabel("northing − mean [m]")
    axes[0].legend(fontsize=7, loc="lower left")
    fig.suptitle(title, x=0.01, ha="left", fontsize=10)
    return fig


def correlation_figure(names: list[str], rho: np.ndarray, title: str,
                       groups: Sequence[tuple[int, str]] = ()) -> Figure:
    """Correlation matrix as a heat map (−1 blue … +1 red); ``groups`` = (first index, label) separators."""
    n = len(names)
    fig = _figure(figsize=(_WIDTH_IN, _WIDTH_IN * 0.82), layout="constrained")
    ax = fig.add_subplot()
    image = ax.imshow(rho, cmap="RdBu_r", vmin=-1, vmax=1, interpolation="nearest")
    fig.colorbar(image, ax=ax, label="correlation ρ", shrink=0.85)
    if n <= 40:
        ax.set_xticks(range(n), names, rotation=90, fontsize=6)
        ax.set_yticks(range(n), names, fontsize=6)
    else:
        ax.set_xlabel("parameter index")
        ax.set_ylabel("parameter index")
    for start, label in groups:
        if 0 < start < n:
            ax.axhline(start - 0.5, color="k", lw=0.6)
            ax.axvline(start - 0.5, color="k", lw=0.6)
    off = rho - np.diag(np.diag(rho)) if n else rho
    largest = float(np.nanmax(np.abs(off))) if n > 1 else 0.0
    ax.set_title(f"{title}: {n} parameters, max |ρ| off the diagonal {largest:.2f}", loc="left", fontsize=10)
    return fig


def precision_map_figure(xy_m: np.ndarray, sigma_m: np.ndarray, title: str) -> Figure:
    """A-posteriori σ_XY = sqrt(σX² + σY²) and σ_Z of the tie points, in plan."""
    fig = _figure(figsize=(_WIDTH_IN, 3.6), layout="constrained")
    axes = fig.subplots(1, 2, sharex=True, sharey=True)
    sxy = np.hypot(sigma_m[:, 0], sigma_m[:, 1])
    origin = xy_m.mean(axis=0) if len(xy_m) else np.zeros(2)
    e, n = (xy_m - origin).T
    for ax, values, name in ((axes[0], sxy, "σ_XY"), (axes[1], sigma_m[:, 2], "σ_Z")):
        unit, factor = length_unit(values)
        ok = np.isfinite(values)
        dots = ax.scatter(e[ok], n[ok], c=values[ok] * factor, s=3, cmap="magma_r", rasterized=True,
                          linewidths=0)
        fig.colorbar(dots, ax=ax, label=f"{name} [{unit}]", shrink=0.85)
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel("easting − mean [m]")
        ax.set_title(f"{name}: median {np.nanmedian(values) * factor:.2f} {unit}" if ok.any() else name,
                     fontsize=9, loc="left")
    axes[0].set_ylabel("northing − mean [m]")
    fig.suptitle(title, x=0.01, ha="left", fontsize=10)
    return fig


def comparison_figure(scenarios: list[str], models: list[str], values: dict[str, np.ndarray], ylabel: str,
                      title: str) -> Figure:
    """Grouped bars, one group per scenario and one bar per model (Figs. 3-5 of seed 000).

    ``values`` maps a panel label to a (n_scenarios, n_models) array (NaN: no value).
    A panel whose values span more than a factor 20 gets a logarithmic axis, so that
    the small values stay readable next to those of ``none``.
    """
    panels = list(values)
    fig = _figure(figsize=(_WIDTH_IN, 2.8 * len(panels) + 0.4), layout="constrained")
    axes = np.atleast_1d(fig.subplots(len(panels), 1, sharex=True))
    width = 0.8 / max(len(models), 1)
    x = np.arange(len(scenarios))
    for ax, panel in zip(axes, panels):
        table = values[panel]
        for j, model in enumerate(models):
            ax.bar(x - 0.4 + (j + 0.5) * width, np.nan_to_num(table[:, j], nan=0.0), width, label=model,
                   color=f"C{j % 10}")
        positive = table[np.isfinite(table) & (table > 0)]
        if positive.size and positive.max() > 20 * positive.min():
            ax.set_yscale("log")
        ax.set_ylabel(f"{panel} {ylabel}")
        ax.grid(axis="y", color="0.9", which="both")
        ax.set_axisbelow(True)
    axes[-1].set_xticks(x, scenarios)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, ncols=min(len(models), 6), loc="outside lower center")
    fig.suptitle(title, x=0.01, ha="left", fontsize=10)
    return fig


def attitude_correction_figure(series: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]], axes: list[str],
                               title: str) -> Figure:
    """The attitude corrections along the images: one panel per axis, one curve per image (``series``: image id,
    lines, values (n, axes) and sigmas (n, axes) in urad) with its +/- sigma band."""
    fig = _figure(figsize=(_WIDTH_IN, 1.9 * len(axes) + 0.5), layout="constrained")
    panels = fig.subplots(len(axes), 1, sharex=True, squeeze=False)[:, 0]
    for a, (ax, name) in enumerate(zip(panels, axes)):
        for k, (image_id, lines, values, sigmas) in enumerate(series):
            ax.plot(lines, values[:, a], color=f"C{k % 10}", lw=1.2, label=image_id)
            ax.fill_between(lines, values[:, a] - sigmas[:, a], values[:, a] + sigmas[:, a], color=f"C{k % 10}",
                            alpha=0.2, lw=0)
        ax.set_ylabel(f"{name} [µrad]")
        ax.axhline(0.0, color="0.6", lw=0.6)
    panels[-1].set_xlabel("line")
    panels[0].legend(fontsize=8, loc="best")
    panels[0].set_title(title, loc="left", fontsize=10)
    return fig



def robust_weight_figure(weight: np.ndarray, u: np.ndarray, reject: float, title: str) -> Figure:
    """The robust cleaning's weights (left: how many observations ended with which weight, logarithmic counts) and
    the residual sizes u in robust sigmas (right), with the rejection threshold."""
    fig = _figure(figsize=(_WIDTH_IN, 2.8), layout="constrained")
    left, right = fig.subplots(1, 2)
    w = weight[np.isfinite(weight)]
    left.hist(np.clip(w, 0.0, 1.0), bins=np.linspace(0.0, 1.0, 21), color="C0", edgecolor="white")
    left.set_yscale("log")
    left.set_xlabel("weight at the end of the robust adjustment")
    left.set_ylabel("observations")
    left.set_title(f"{np.mean(w >= 0.999) * 100:.1f} % at full weight", fontsize=9)
    size = u[np.isfinite(u)]
    top = max(2.0 * reject, 1.0)
    right.hist(np.clip(size, 0.0, top), bins=np.linspace(0.0, top, 41), color="C0", edgecolor="white")
    right.axvline(reject, color="C3", lw=1.2, label=f"rejected beyond {reject:g}")
    right.set_yscale("log")
    right.set_xlabel(f"u = |v| / robust σ (beyond {top:g} counted in the last bin)")
    right.legend(fontsize=7)
    right.set_title(f"{int(np.sum(size > reject))} beyond the threshold", fontsize=9)
    fig.suptitle(title, x=0.01, ha="left", fontsize=10)
    return fig


def rejection_map_figure(images: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]], width_px: float,
                         height_px: float, title: str) -> Figure:
    """Where the rejected observations lie in the images with the most of them: each panel an image frame,
    ``images`` (name, kept (col, row), robust rejections (col, row), snooping rejections (col, row)); a patch of
    consistently wrong matches shows as a patch."""
    n = max(len(images), 1)
    columns = min(n, 3)
    rows = -(-n // columns)
    fig = _figure(figsize=(_WIDTH_IN, 1.9 * rows + 0.6), layout="constrained")
    axes = np.atleast_1d(fig.subplots(rows, columns)).ravel()
    for ax, (name, kept, robust, snooped) in zip(axes, images):
        ax.scatter(kept[:, 0], kept[:, 1], s=0.3, color="0.75", rasterized=True)
        ax.scatter(robust[:, 0], robust[:, 1], s=3, color="C3", label="robust cleaning")
        ax.scatter(snooped[:, 0], snooped[:, 1], s=3, color="C0", marker="x", label="data snooping")
        ax.set_xlim(0, width_px)
        ax.set_ylim(height_px, 0)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"{name}: {len(robust) + len(snooped)} of {len(kept) + len(robust) + len(snooped)}", fontsize=8)
    for ax in axes[len(images):]:
        ax.set_axis_off()
    if images:
        axes[0].legend(fontsize=6, loc="lower left", markerscale=2)
    fig.suptitle(title, x=0.01, ha="left", fontsize=10)
    return fig


#: the camera-layout figure's colour scale of images per point ends here (more images share its last colour)
OVERLAP_TOP = 9


def camera_layout_figure(points_xy_m: np.ndarray, images_per_point: np.ndarray, role: np.ndarray,
                         centres_xy_m: np.ndarray | None, strip: Sequence[str], names: Sequence[str],
                         title: str) -> Figure:
    """The camera layout over the object points (plan view, easting right, northing up, from the points' mean).

    Each point is coloured by the number of images that observe it (``images_per_point``, one discrete colour
    per count from 1 to :data:`OVERLAP_TOP` and more, red for few, green for many; 0 grey); control points
    (``role`` gcp) are drawn as triangles, check points (chk) as circles; the projection centres
    (``centres_xy_m``, None: not drawn) as black crosses joined along each strip, named when few.
    """
    from matplotlib import colormaps
    from matplotlib.colors import BoundaryNorm
    fig = _figure(figsize=(_WIDTH_IN, _WIDTH_IN * 0.72), layout="constrained")
    ax = fig.add_subplot()
    origin = points_xy_m.mean(axis=0) if len(points_xy_m) else np.zeros(2)
    e, n = (points_xy_m - origin).T
    counts = np.asarray(images_per_point, dtype=int)
    top = int(min(max(int(counts.max()) if counts.size else 2, 2), OVERLAP_TOP))
    cmap = colormaps["RdYlGn"].resampled(top)
    norm = BoundaryNorm(np.arange(0.5, top + 1.5), top)
    seen = counts > 0
    tie = ~np.isin(role, ("gcp", "chk"))
    ax.scatter(e[~seen], n[~seen], s=2, color="0.6", linewidths=0, rasterized=True)
    dots = ax.scatter(e[seen & tie], n[seen & tie], c=np.minimum(counts[seen & tie], top), s=5, cmap=cmap,
                      norm=norm, linewidths=0, rasterized=True)
    for r, marker, label in (("gcp", "^", "control"), ("chk", "o", "check")):
        pick = role == r
        if pick.any():
            ax.scatter(e[pick], n[pick], c=np.minimum(np.maximum(counts[pick], 1), top), cmap=cmap, norm=norm,
                       marker=marker, s=36, edgecolors="k", linewidths=0.6, label=label, zorder=3)
    bar = fig.colorbar(dots, ax=ax, label="images per point", shrink=0.85, ticks=range(1, top + 1))
    if counts.size and counts.max() > top:
        bar.ax.set_yticklabels([str(k) for k in range(1, top)] + [f"{top}+"])
    if centres_xy_m is not None and len(centres_xy_m):
        ce, cn = (centres_xy_m - origin).T
        strips = np.asarray(strip, dtype=object)
        for s in dict.fromkeys(strips):
            mine = strips == s
            ax.plot(ce[mine], cn[mine], "-", color="0.35", lw=0.7, zorder=4)
        ax.plot(ce, cn, "+", color="k", ms=7, mew=1.2, label="projection centres", zorder=5)
        if len(names) <= 40:
            for x, y, t in zip(ce, cn, names):
                ax.annotate(str(t), (x, y), xytext=(3, 3), textcoords="offset points", fontsize=5, color="0.2")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("easting − mean of the points [m]")
    ax.set_ylabel("northing − mean of the points [m]")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, loc="lower left", framealpha=0.8)
    median = float(np.median(counts[seen])) if seen.any() else float("nan")
    ax.set_title(f"{title}: {len(counts)} points, median {median:g} images per point", loc="left", fontsize=10)
    return fig
