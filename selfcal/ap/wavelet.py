"""``wavelet:NAME``: wavelet additional parameters (WAPs) of seed 000, Eqs. (6)-(11).

Photo coordinates are mapped to the wavelet domain by Eq. (10),

    x_w = x · Gx / W,   y_w = y · Gy / H,

with (x, y) centred on the image, so x_w lies in [-Gx/2, Gx/2] and one grid
cell is one unit (scale j = 0). The basis is the tensor product of scaling
functions of Eq. (6),

    Phi_{kx,ky}(x_w, y_w) = phi(x_w + kx) · phi(y_w + ky),

and Delta_x and Delta_y have coefficient sets of their own (Eq. 11), so the
initial number of WAPs is 2 · n_kx · n_ky. The translation sign (phi(t + k)
rather than phi(t - k)) is the labelling that reproduces the translation
ranges of Table 3 of seed 000 with a centred domain (e.g. ADB4: k_x from -4);
it does not change the space spanned.

The second formulation (``wavelet:NAME+details``) spans V_{j+1} with the
detail functions of Eqs. (7)-(9) at the same translations:
phi(x_w+kx) psi(y_w+ky) (h), psi(x_w+kx) phi(y_w+ky) (v) and psi psi (d).

Translations: k is a candidate when the effective support of phi(t + k)
(:data:`selfcal.wavelets.TRUNCATION`) meets the frame; it is kept when at
least ``MIN_OBSERVATIONS`` observations fall where |phi(t + k)| is above that
threshold (the "adaptive" ranges of Table 3). The ranges form a rectangle.
Coefficients are in pixels, the basis is dimensionless (selfcal.ap.base).

Interior orientation and attitude (ours; the paper does not say how it
separates them): the integer translates of a scaling function are a
partition of unity and reproduce polynomials (Strang-Fix; degree 3 for db4,
sym4 and bl4), so the raw WAP field contains the image-space effect of the
principal point (a constant shift), of the principal distance (the field
(x, y) · dc / c) and of a rotation of the camera that is the same in every
image: kappa turns the image, (y, -x), and omega and phi add the projective
fields (x y, y^2) and (x^2, x y) to a shift. Estimating c, x0, y0 together
with the raw basis is singular, and the exterior orientations of all images
together with it nearly so: with ground control only, a camera-fixed phi of
0.6 degrees traded against the WAPs at 7 sigma of the final estimate and
Gauss-Newton needed 30-50 iterations to follow that valley. Each basis
function (Bx_i, By_i) is therefore made orthogonal, in the L2 inner product
over the frame, to these six fields F:

    B'_i = B_i - F (F^T F)^-1 F^T B_i,

computed once from a dense sample of the frame (``ORTHO_SAMPLES``). When the
translations cover the frame, the raw span contains those fields (exactly or
to a fraction of a percent at the edges) and as many orthogonalised functions
become (near) combinations of the others; the last functions of a greedy
orthogonalisation of the sampled basis are left out (``n_dependent`` in
:meth:`WaveletAP.to_dict`, usually 6), the first listed of tied ones kept
(:func:`selfcal.ap.base.independent_functions`: the same choice on every
machine). The construction depends only on the frame, the wavelet, the grid
and the ranges, so it is recreated exactly when a model is reloaded. The
correction field keeps every local shape of the wavelets, c, x0, y0 stay
estimable and the attitudes are fixed by the block, not by the APs. What the
WAPs no longer carry is a field that a common tilt of the camera produces
(e.g. the projective part of decentring distortion): the attitudes take it,
which leaves the object points unchanged. The parameter correlations are
not small (max |rho| IOP-WAP up to 0.998 on the simulated Type 3 block,
driven by edge translations) and screening keeps many of them: significant
correlated WAPs are not dropped (see selfcal.stats.screening), so the small
values of Table 4 of seed 000 are not reproduced.
"""
from __future__ import annotations

import numpy as np

from ..wavelets import check_wavelet_name, get_wavelet
from .base import APModel, ImageFrame, SparseBasis, independent_functions

__all__ = ["WaveletAP", "MIN_OBSERVATIONS"]

#: a translation needs this many observations under its (effective) support,
#: or 0.2 % of the camera's observations if that is more
MIN_OBSERVATIONS = 20
#: sample points per grid cell and axis of the frame integral that removes the
#: interior-orientation and camera-rotation fields from the basis
ORTHO_SAMPLES = 16
#: a field of :func:`_camera_fields` that the raw basis reproduces to this relative
#: RMS over the frame makes one orthogonalised function (nearly) dependent
REPRODUCTION_TOLERANCE = 0.01


def _half_diagonal_mm(frame: ImageFrame) -> float:
    return 0.5 * float(np.hypot(frame.width_mm, frame.height_mm))


def _camera_fields(frame: ImageFrame, x_mm: np.ndarray, y_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The image-space fields (up to scale) of a change of x0, y0, c and of a camera-fixed rotation
    (kappa, phi, omega) at photo coordinates: (n, 6) each for x and y. Scaled by the half-diagonal r
    so that every field is of order one over the frame."""
    r = _half_diagonal_mm(frame)
    u, v = np.asarray(x_mm, float) / r, np.asarray(y_mm, float) / r
    one, zero = np.ones_like(u), np.zeros_like(u)
    Fx = np.column_stack([one, zero, u, v, u * u, u * v])
    Fy = np.column_stack([zero, one, v, -u, u * v, v * v])
    return Fx, Fy


def _camera_field_gradients(frame: ImageFrame, x_mm: np.ndarray, y_mm: np.ndarray):
    """d/dx and d/dy (per mm) of the fields of :func:`_camera_fields`: (dFx/dx, dFx/dy, dFy/dx, dFy/dy)."""
    r = _half_diagonal_mm(frame)
    u, v = np.asarray(x_mm, float) / r, np.asarray(y_mm, float) / r
    one, zero = np.ones_like(u), np.zeros_like(u)
    dFx_dx = np.column_stack([zero, zero, one, zero, 2 * u, v]) / r
    dFx_dy = np.column_stack([zero, zero, zero, one, zero, u]) / r
    dFy_dx = np.column_stack([zero, zero, zero, -one, v, zero]) / r
    dFy_dy = np.column_stack([zero, zero, one, zero, u, 2 * v]) / r
    return dFx_dx, dFx_dy, dFy_dx, dFy_dy


def _independent_details(w, half: float, k_phi: np.ndarray, samples: int = 4000, tol: float = 0.05) -> np.ndarray:
    """Translations k whose psi(t + k) adds to the span of the phi(t + k') over the frame.

    On a bounded frame, phi and psi translations that together span V_{j+1} are
    linearly dependent near the edges; the dependent psi are left out (greedy,
    in order of k) so that the details basis has full rank: a psi is kept when
    at least ``tol`` of its norm on the frame lies outside the span so far.
    """
    t = np.linspace(-half, half, samples)
    Q, _ = np.linalg.qr(w.phi(t[:, None] + k_phi[None, :]))
    kept = []
    for k in k_phi:
        col = w.psi(t + k)
        norm = np.linalg.norm(col)
        if norm == 0:
            continue
        resid = col - Q @ (Q.T @ col)
        if np.linalg.norm(resid) / norm > tol:
            kept.append(k)
            Q = np.column_stack([Q, resid / np.linalg.norm(resid)])
    return np.array(kept, dtype=np.int64)


def _translations(w, half: float, coords: np.ndarray | None, n_min: int) -> tuple[int, int]:
    a, b = w.support
    k_min = int(np.floor(a - half)) + 1
    k_max = int(np.ceil(b + half)) - 1
    if coords is None or coords.size == 0:
        return k_min, k_max
    peak = np.abs(w.phi_table).max()
    kept = [k for k in range(k_min, k_max + 1)
            if np.count_nonzero(np.abs(w.phi(coords + k)) >= w.threshold * peak) >= n_min]
    if not kept:
        return k_min, k_max
    return min(kept), max(kept)


class WaveletAP(APModel):
    family = "wavelet"
    settings = ("grid",)
    examples = ("wavelet:db4", "wavelet:sym4", "wavelet:meyer", "wavelet:bl4", "wavelet:sym4+details")

    def __init__(self, frame: ImageFrame, wavelet: str, grid: tuple[int, int], ranges: tuple[int, int, int, int],
                 formulation: str = "scaling", left_out: list[str] | None = None, span_only: bool = False):
        super().__init__(frame)
        if formulation not in ("scaling", "details"):
            raise ValueError(f"WAP formulation must be 'scaling' or 'details', found '{formulation}'")
        self.wavelet = get_wavelet(wavelet)
        self.grid = (int(grid[0]), int(grid[1]))
        self.ranges = tuple(int(v) for v in ranges)
        self.formulation = formulation
        kx0, kx1, ky0, ky1 = self.ranges
        self.kx = np.arange(kx0, kx1 + 1)
        self.ky = np.arange(ky0, ky1 + 1)
        parts = ["phi"] if formulation == "scaling" else ["phi", "h", "v", "d"]
        self._parts = parts
        if formulation == "details":
            self.kx_psi = _independent_details(self.wavelet, self.grid[0] / 2.0, self.kx)
            self.ky_psi = _independent_details(self.wavelet, self.grid[1] / 2.0, self.ky)
        else:
            self.kx_psi = self.ky_psi = np.zeros(0, np.int64)
        uses = {"phi": (self.kx, self.ky), "h": (self.kx, self.ky_psi), "v": (self.kx_psi, self.ky),
                "d": (self.kx_psi, self.ky_psi)}
        self._uses = uses
        names = []
        for axis in ("x", "y"):
            for part in parts:
                prefix = f"a{axis}" if part == "phi" else f"a{axis}{part}"
                kxs, kys = uses[part]
                names += [f"{prefix}[{kx:+d},{ky:+d}]" for ky in kys for kx in kxs]
        if span_only:               # the raw functions: their span with the camera fields (from_spec)
            self._kept, self._field_projection = np.ones(len(names), bool), np.zeros((6, len(names)))
        elif left_out is None:
            self._kept, self._field_projection = self._orthogonalise()
        else:
            # as written by to_dict: a file's coefficients are in the order of the functions it kept (and a file
            # from before the choice was made the same on every machine may have kept others)
            unknown = sorted(set(left_out) - set(names))
            if unknown:
                raise ValueError(f"{self.spec}: unknown function '{unknown[0]}' among those left out")
            self._kept, self._field_projection = self._orthogonalise(~np.isin(names, left_out))
        self._names = [n for n, k in zip(names, self._kept) if k]
        self._left_out = [n for n, k in zip(names, self._kept) if not k]

    def _orthogonalise(self, kept: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Which raw basis functions are kept (bool, n), and the coefficients M (6, n_kept) of the
        least-squares projection of each kept function on the camera fields over a
        dense midpoint sample of the frame. Functions are left out when the orthogonalised basis
        is (nearly) dependent with them, unless ``kept`` says which (a model read from a file)."""
        gx, gy = self.grid
        nx, ny = ORTHO_SAMPLES * gx, ORTHO_SAMPLES * gy
        x = (np.arange(nx) + 0.5) / nx * self.frame.width_mm - 0.5 * self.frame.width_mm
        y = (np.arange(ny) + 0.5) / ny * self.frame.height_mm - 0.5 * self.frame.height_mm
        xs, ys = (a.ravel() for a in np.meshgrid(x, y))
        # the raw basis is [B, 0] in the x rows and [0, B] in the y rows, with one scalar basis B
        scalar = self._blocks(*self._domain(xs, ys))
        Fx, Fy = _camera_fields(self.frame, xs, ys)
        fields_raw = np.hstack([Fx.T @ scalar, Fy.T @ scalar])                   # F^T [B_x; B_y], (6, n)
        M = np.linalg.solve(Fx.T @ Fx + Fy.T @ Fy, fields_raw)
        if kept is not None:
            return kept, M[:, kept]
        # each camera field the raw span reproduces costs one dimension. The fit separates into one for x and
        # one for y (8x fewer flops)
        fit = np.linalg.lstsq(scalar, np.hstack([Fx, Fy]), rcond=None)[0]
        n_fields = Fx.shape[1]
        misfit = np.hypot(np.linalg.norm(Fx - scalar @ fit[:, :n_fields], axis=0),
                          np.linalg.norm(Fy - scalar @ fit[:, n_fields:], axis=0)) / np.hypot(
                              np.linalg.norm(Fx, axis=0), np.linalg.norm(Fy, axis=0))
        n_dependent = int(np.sum(misfit < REPRODUCTION_TOLERANCE))
        kept = np.ones(2 * scalar.shape[1], bool)
        if n_dependent:
            # the Gram matrix of the raw functions less their projection on the fields, A = B - F M:
            # A^T A = B^T B - (F^T B)^T M, and B^T B is block diagonal with the scalar basis' Gram matrix twice
            n = scalar.shape[1]
            gram = -fields_raw.T @ M
            own = scalar.T @ scalar
            gram[:n, :n] += own
            gram[n:, n:] += own
            kept = independent_functions(gram, n_dependent)
        return kept, M[:, kept]

    @property
    def spec(self) -> str:
        return f"wavelet:{self.wavelet.name}" + ("+details" if self.formulation == "details" else "")

    @property
    def parameter_names(self) -> list[str]:
        return self._names

    def _domain(self, x_mm, y_mm):
        gx, gy = self.grid
        return (np.asarray(x_mm, float) * gx / self.frame.width_mm,
                np.asarray(y_mm, float) * gy / self.frame.height_mm)

    def _factors(self, t, k, function):
        return function(t[:, None] + k[None, :])

    def _blocks(self, xw, yw, dx=False, dy=False):
        """The 2-D functions of each part, (n, n_ky * n_kx), optionally differentiated in x_w or y_w."""
        w = self.wavelet
        fx = {"phi": w.dphi if dx else w.phi, "psi": w.dpsi if dx else w.psi}
        fy = {"phi": w.dphi if dy else w.phi, "psi": w.dpsi if dy else w.psi}
        pick = {"phi": ("phi", "phi"), "h": ("phi", "psi"), "v": ("psi", "phi"), "d": ("psi", "psi")}
        n = len(xw)
        out = []
        cache = {}
        for part in self._parts:
            sx, sy = pick[part]
            kxs, kys = self._uses[part]
            if ("x", sx) not in cache:
                cache[("x", sx)] = self._factors(xw, kxs, fx[sx])
            if ("y", sy) not in cache:
                cache[("y", sy)] = self._factors(yw, kys, fy[sy])
            out.append((cache[("y", sy)][:, :, None] * cache[("x", sx)][:, None, :]).reshape(n, -1))
        return np.concatenate(out, axis=1)

    def basis(self, x_mm, y_mm):
        x_mm, y_mm = np.asarray(x_mm, float), np.asarray(y_mm, float)
        B = self._blocks(*self._domain(x_mm, y_mm))
        n = B.shape[1]
        keep_x, keep_y = self._kept[:n], self._kept[n:]
        n_x = int(keep_x.sum())
        Fx, Fy = _camera_fields(self.frame, x_mm, y_mm)
        # [B_x, 0] - Fx M and [0, B_y] - Fy M, each written once (no zero-filled raw basis)
        Bx = Fx @ -self._field_projection
        By = Fy @ -self._field_projection
        Bx[:, :n_x] += B[:, keep_x]
        By[:, n_x:] += B[:, keep_y]
        return Bx, By

    def sparse_basis(self, x_mm, y_mm) -> SparseBasis | None:
        """The scaling-function basis as sparse rows: phi(t + k) vanishes outside phi's table, so at a
        point only a window of consecutive translations per axis is non-zero (7 of 13 for sym4), the
        same window for every point of one cell of the translation grid; the camera fields are six more
        raw columns, which ``to_params`` maps through -M (:meth:`basis`). None for the detail formulation."""
        if self.formulation != "scaling":
            return None
        x_mm, y_mm = np.asarray(x_mm, float), np.asarray(y_mm, float)
        xw, yw = self._domain(x_mm, y_mm)
        w = self.wavelet
        span = float(w.x[-1] - w.x[0])

        def window(t, k):
            """Each point's first translation of a window of consecutive ones that holds all its non-zero
            phi(t + k) (the open interval (x0 - t, x1 - t)), and phi there: (n,) positions into k, (n, K)."""
            size = min(len(k), int(np.ceil(span)))
            first = np.clip(np.floor(w.x[0] - t).astype(np.int64) + 1 - k[0], 0, len(k) - size)
            return first, size, w.phi(t[:, None] + k[first][:, None] + np.arange(size)[None, :])
        fx, kx, vx = window(xw, self.kx)
        fy, ky, vy = window(yw, self.ky)
        n_x, n = len(self.kx), len(xw)
        n_raw = n_x * len(self.ky)
        starts_x, starts_y = n_x - kx + 1, len(self.ky) - ky + 1
        # every window pair is a pattern, numbered alike wherever the basis is evaluated: (first ky) * starts_x +
        # (first kx); its raw columns (ky index) * n_kx + (kx index), then the fields, for the x and the y rows
        first_y, first_x = np.divmod(np.arange(starts_x * starts_y), starts_x)
        cells = ((first_y[:, None, None] + np.arange(ky)[None, :, None]) * n_x
                 + first_x[:, None, None] + np.arange(kx)[None, None, :]).reshape(len(first_x), ky * kx)
        fields = np.broadcast_to(2 * n_raw + np.arange(6), (len(first_x), 6))
        columns = np.stack([np.concatenate([cells, fields], axis=1), np.concatenate([n_raw + cells, fields], axis=1)],
                           axis=1)
        pattern = fy * starts_x + fx
        products = (vy[:, :, None] * vx[:, None, :]).reshape(n, ky * kx)
        Fx, Fy = _camera_fields(self.frame, x_mm, y_mm)
        values = np.stack([np.concatenate([products, Fx], axis=1), np.concatenate([products, Fy], axis=1)], axis=1)
        to_params = np.zeros((2 * n_raw + 6, int(self._kept.sum())))
        to_params[np.flatnonzero(self._kept), np.arange(to_params.shape[1])] = 1.0
        to_params[2 * n_raw:] = -self._field_projection
        return SparseBasis(pattern.reshape(-1), columns, values, to_params)

    def support_counts(self, x_mm, y_mm) -> np.ndarray:
        """How many of the points lie in each coefficient's effective support: where both factors of its tensor
        product (phi or psi) are at least the wavelet's truncation threshold times phi's peak (the support that
        qualifies a translation, :data:`MIN_OBSERVATIONS`)."""
        xw, yw = self._domain(np.asarray(x_mm, float), np.asarray(y_mm, float))
        w = self.wavelet
        level = w.threshold * np.abs(w.phi_table).max()
        within = {("x", f): (np.abs(fn(xw[:, None] + k[None, :])) >= level).astype(float)
                  for f, fn, k in (("phi", w.phi, self.kx), ("psi", w.psi, self.kx_psi))}
        within |= {("y", f): (np.abs(fn(yw[:, None] + k[None, :])) >= level).astype(float)
                   for f, fn, k in (("phi", w.phi, self.ky), ("psi", w.psi, self.ky_psi))}
        pick = {"phi": ("phi", "phi"), "h": ("phi", "psi"), "v": ("psi", "phi"), "d": ("psi", "psi")}
        counts = [(within[("y", pick[part][1])].T @ within[("x", pick[part][0])]).ravel() for part in self._parts]
        one_axis = np.concatenate(counts)
        return np.concatenate([one_axis, one_axis])[self._kept].astype(np.int64)

    def basis_derivatives(self, x_mm, y_mm):
        x_mm, y_mm = np.asarray(x_mm, float), np.asarray(y_mm, float)
        xw, yw = self._domain(x_mm, y_mm)
        sx = self.grid[0] / self.frame.width_mm
        sy = self.grid[1] / self.frame.height_mm
        Bdx = sx * self._blocks(xw, yw, dx=True)
        Bdy = sy * self._blocks(xw, yw, dy=True)
        zero = np.zeros_like(Bdx)
        kept, M = self._kept, self._field_projection
        gradients = _camera_field_gradients(self.frame, x_mm, y_mm)
        raw = (np.concatenate([Bdx, zero], axis=1), np.concatenate([Bdy, zero], axis=1),
               np.concatenate([zero, Bdx], axis=1), np.concatenate([zero, Bdy], axis=1))
        return tuple(part[:, kept] - grad @ M for part, grad in zip(raw, gradients))

    def active_ranges(self, active: np.ndarray) -> tuple[int, int, int, int] | None:
        """k ranges of the active coefficients (after screening); None if none is active."""
        full = np.zeros(len(self._kept), bool)
        full[self._kept] = np.asarray(active, bool)
        active = full
        n = len(self.kx) * len(self.ky)
        half = active[: len(active) // 2], active[len(active) // 2:]
        per_set = (half[0][:n] | half[1][:n]).reshape(len(self.ky), len(self.kx))
        if not per_set.any():
            return None
        ky_idx, kx_idx = np.nonzero(per_set)
        return (int(self.kx[kx_idx.min()]), int(self.kx[kx_idx.max()]),
                int(self.ky[ky_idx.min()]), int(self.ky[ky_idx.max()]))

    def to_dict(self) -> dict:
        return {"spec": self.spec, "wavelet": self.wavelet.name, "grid": list(self.grid),
                "ranges": list(self.ranges), "formulation": self.formulation,
                "truncation": self.wavelet.threshold, "n_dependent": int((~self._kept).sum()),
                "left_out": list(self._left_out)}

    @classmethod
    def from_dict(cls, data: dict, frame: ImageFrame) -> "WaveletAP":
        args = (frame, data["wavelet"], tuple(data["grid"]), tuple(data["ranges"]), data.get("formulation", "scaling"))
        left_out = data.get("left_out")
        written = [c.get("name") for c in data.get("coefficients", ())]
        if left_out is None and written and all(written):
            # a camera.json from before left_out was written: its coefficients name the functions it kept
            every = cls(*args, left_out=[]).parameter_names
            left_out = [name for name in every if name not in set(written)]
        return cls(*args, left_out=left_out)

    @classmethod
    def check_option(cls, option) -> None:
        if not option:
            raise ValueError("a wavelet AP model needs a wavelet: wavelet:db4, wavelet:sym4, wavelet:meyer, "
                             "wavelet:bl4 (any order of db, sym, bl)")
        name, _, form = option.partition("+")
        if form not in ("", "details"):
            raise ValueError(f"unknown WAP formulation '+{form}' (known: +details)")
        check_wavelet_name(name)

    @classmethod
    def from_spec(cls, option, frame: ImageFrame, observed_xy_mm=None, grid=(9, 6), span_only: bool = False,
                  **settings):
        """``span_only``: the raw tensor-product functions of the grid's translations, neither orthogonalised to the
        camera fields nor thinned (with those fields they span what the model spans, for fits that include them:
        cheap to build on large grids; not for an adjustment, where they are singular with the interior
        orientation)."""
        cls.check_option(option)
        name, _, form = option.partition("+")
        w = get_wavelet(name)
        gx, gy = int(grid[0]), int(grid[1])
        if gx < 1 or gy < 1:
            raise ValueError(f"the wavelet grid must be positive, found {gx}x{gy}")
        if observed_xy_mm is not None and len(observed_xy_mm):
            xy = np.asarray(observed_xy_mm, float)
            n_min = max(MIN_OBSERVATIONS, int(0.002 * len(xy)))
            xw = xy[:, 0] * gx / frame.width_mm
            yw = xy[:, 1] * gy / frame.height_mm
        else:
            n_min, xw, yw = MIN_OBSERVATIONS, None, None
        kx = _translations(w, gx / 2.0, xw, n_min)
        ky = _translations(w, gy / 2.0, yw, n_min)
        return cls(frame, name, (gx, gy), (*kx, *ky), "details" if form else "scaling", span_only=span_only)
