"""The ground under a scan as a height field: what a natural seabed is, where flat planes are not.

Plane removal (``frontends.laser.planes``) takes out a tank's floor and walls; a natural seabed
(slopes, mounds, ripples, stones) has no large flat region and stays. This stage models the ground
as a surface over a grid of ``cell`` (m) across the up direction (from the AHRS), every cell with
its own tilted plane, so slopes are followed, and marks what lies within a few σ of that surface:

1. the low height of every cell: the height below which 10 % of its raw points lie (coarse voxels
   weighted by their points, so that lone returns below the surface do not count);
2. a morphological opening of those heights (min, then max, over a square of ``open_radius``): it
   removes whatever is narrower than the window (pipes, fittings, stones) and keeps the ground;
3. ground candidates: the voxels within ``band`` of the opened surface;
4. per cell, a plane fitted (least squares, no steeper than ``max_slope_deg``) to the candidates
   within ``fit_radius``, refitted twice on those within a few σ of the last fit: the local ground
   and its normal (what "up" is on a slope);
5. a point is ground when it lies less than ``height`` (or ``height_sigmas`` × the scan's noise σ
   or the ground's roughness about the planes, whichever is larger) above its cell's plane, or
   anywhere below it.

Everything is in the sensor frame {S}, metres. Cells without enough candidates around them have no
ground (nothing there is marked ground: walls, or a structure hiding the floor).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import maximum_filter, minimum_filter

from frontends.laser.config import GroundConfig
from frontends.laser.grid import stable_order_float

_MIN_FIT = 6  # fewest candidates for a cell's plane
_LOW_SHARE = 0.1  # a cell's low height: below it lie this share of its raw points
_MAX_CELLS = 2_000_000  # a grid larger than this (a cloud in the wrong units) gets no ground model
_REFITS = 2
_MIN_SPREAD = 0.2  # × fit_radius: the σ of a cell's candidates across their narrowest direction
_REFIT_SIGMAS = 3.0  # the refit keeps the candidates within this many σ (or ``height``) of the first fit


def _basis(up: np.ndarray) -> np.ndarray:
    """3×3 rows (e1, e2, up): an orthonormal frame whose third axis is ``up``."""
    u = up / np.linalg.norm(up)
    e1 = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return np.array([e1, np.cross(u, e1), u])


def _box_sum(x: np.ndarray, k: int) -> np.ndarray:
    """Sum over the (2k+1)² square around every cell of the 2-D arrays x[..., :, :] (zeros outside),
    by cumulative sums (several layers in one call: on a grid of ~100×100 cells the calls, not the
    arithmetic, are the cost)."""
    c = np.pad(x, ((0, 0),) * (x.ndim - 2) + ((k + 1, k), (k + 1, k))).cumsum(-2).cumsum(-1)
    n0, n1 = x.shape[-2:]
    w = 2 * k + 1
    return c[..., w : w + n0, w : w + n1] - c[..., :n0, w : w + n1] - c[..., w : w + n0, :n1] + c[..., :n0, :n1]


@dataclass
class GroundModel:
    """Per cell of the grid, the ground plane h = c0 + ca·a + cb·b in the frame ``basis`` (rows e1,
    e2, up; a, b, h the coordinates along them), NaN where there is no ground; ``threshold`` (m) the
    height below which a point is ground."""

    basis: np.ndarray
    cell: float
    origin: np.ndarray  # (a, b) of cell (0, 0)'s corner
    coef: np.ndarray  # n0 × n1 × 3: c0, ca, cb
    threshold: float

    def _cells(self, points: np.ndarray):
        x = np.asarray(points, float) @ self.basis.T
        ij = np.floor((x[:, :2] - self.origin) / self.cell).astype(np.int64)
        n0, n1 = self.coef.shape[:2]
        inside = (ij[:, 0] >= 0) & (ij[:, 0] < n0) & (ij[:, 1] >= 0) & (ij[:, 1] < n1)
        return x, ij, inside

    def height(self, points: np.ndarray) -> np.ndarray:
        """Height (m) of each point above the ground under it; NaN where there is no ground."""
        x, ij, inside = self._cells(points)
        # (every point's cell by one flat gather, cell 0 for those outside, which are then set to
        # NaN: the same products per point as boolean selections of the inside ones, ~3x faster)
        out = self._above_plane(x, np.where(inside, ij[:, 0] * self.coef.shape[1] + ij[:, 1], 0))
        out[~inside] = np.nan
        return out

    def _above_plane(self, x: np.ndarray, cell: np.ndarray) -> np.ndarray:
        """Height of points ``x`` (in the frame ``basis``) above the planes of their cells (flat
        indices into the grid)."""
        c = np.take(self.coef.reshape(-1, 3), cell, axis=0)
        return x[:, 2] - (c[:, 0] + c[:, 1] * x[:, 0] + c[:, 2] * x[:, 1])

    def is_ground(self, points: np.ndarray) -> np.ndarray:
        """Points less than ``threshold`` above the ground (or below it)."""
        h = self.height(points)
        return np.isfinite(h) & (h < self.threshold)

    def normal(self, point: np.ndarray) -> np.ndarray | None:
        """The ground's unit normal (upwards) under ``point``, None where there is no ground."""
        _, ij, inside = self._cells(np.asarray(point, float)[None])
        if not inside[0]:
            return None
        c = self.coef[ij[0, 0], ij[0, 1]]
        if not np.isfinite(c).all():
            return None
        n = self.basis[2] - c[1] * self.basis[0] - c[2] * self.basis[1]
        return n / np.linalg.norm(n)


def _fit_planes(a, b, h, w, ij, shape, k: int, ridge: float, max_slope: float, min_spread: float) -> np.ndarray:
    """Per cell, the least-squares plane h = c0 + ca·a + cb·b of the points (weights ``w``) in the
    (2k+1)² cells around it (n0 × n1 × 3; NaN where fewer than ``_MIN_FIT`` points). The slopes are shrunk by a ridge of
    ``ridge`` (m², added to the points' variance across): where they spread along one line only (a
    strip at the edge of the view) the slope across it stays near level rather than wild; a slope
    steeper than ``max_slope`` (tan of the angle) is brought back to it (a pipe's flank in the
    candidates tilts a plane, the ground is never that steep). Candidates that spread less than
    ``min_spread`` (m, σ) across their narrowest direction make no plane: a strip is a pipe's top
    seen where the floor is hidden, not ground."""
    flat = ij[:, 0] * shape[1] + ij[:, 1]
    n = shape[0] * shape[1]
    # The ten moments 1, w, w·a, w·b, w·h, w·a·a, w·a·b, w·b·b, w·a·h, w·b·h (products taken left to
    # right), written into one array: w·a·a is (w·a)·a, so it is row 2 times a.
    moments = np.empty((10, len(a)))
    moments[0], moments[1] = 1.0, w
    np.multiply(w, a, out=moments[2])
    np.multiply(w, b, out=moments[3])
    np.multiply(w, h, out=moments[4])
    np.multiply(moments[2], a, out=moments[5])
    np.multiply(moments[2], b, out=moments[6])
    np.multiply(moments[3], b, out=moments[7])
    np.multiply(moments[2], h, out=moments[8])
    np.multiply(moments[3], h, out=moments[9])
    # (all ten moments binned by one bincount, layer m of cell f at m·n + f, and box-summed at once:
    # each bin adds its points in the same order as a bincount per moment, so the same sums)
    layer = (np.arange(len(moments))[:, None] * n + flat[None, :]).ravel()
    binned = np.bincount(layer, moments.ravel(), len(moments) * n).reshape((len(moments),) + shape)
    num, cnt, sa, sb, sh, saa, sab, sbb, sah, sbh = _box_sum(binned, k)
    coef = np.full(shape + (3,), np.nan)
    ok = num >= _MIN_FIT
    if not ok.any():
        return coef
    c = cnt[ok]
    ma, mb, mh = sa[ok] / c, sb[ok] / c, sh[ok] / c
    vaa = saa[ok] / c - ma * ma + ridge
    vbb = sbb[ok] / c - mb * mb + ridge
    vab = sab[ok] / c - ma * mb
    vah = sah[ok] / c - ma * mh
    vbh = sbh[ok] / c - mb * mh
    # narrowest spread of the points (the smaller eigenvalue of their a-b covariance, without the ridge)
    half_trace = 0.5 * (vaa + vbb) - ridge
    narrow = half_trace - np.sqrt(np.maximum((0.5 * (vaa - vbb)) ** 2 + vab * vab, 0.0))
    det = vaa * vbb - vab * vab
    ca = (vbb * vah - vab * vbh) / det
    cb = (vaa * vbh - vab * vah) / det
    steep = np.hypot(ca, cb) / max_slope
    ca, cb = ca / np.maximum(steep, 1.0), cb / np.maximum(steep, 1.0)
    sol = np.column_stack([mh - ca * ma - cb * mb, ca, cb])
    sol[narrow < min_spread**2] = np.nan
    coef[ok] = sol
    return coef


def _low_heights(flat: np.ndarray, h: np.ndarray, w: np.ndarray, n_cells: int) -> np.ndarray:
    """Per cell, the height below which ``_LOW_SHARE`` of its raw points lie (the voxels weighted by
    their points: a voxel of a lone return a few cm behind a dense surface weighs nothing); +inf
    for an empty cell."""
    if n_cells <= 1 << 16:
        # np.lexsort((h, flat))'s order by two stable sorts, the second on 16-bit cells (a radix
        # sort, several times faster than the comparison sort lexsort runs on int64), the first
        # by the heights' digits (stable_order_float: np.argsort(h, kind="stable")'s order)
        by_h = stable_order_float(h)
        order = by_h[np.argsort(flat[by_h].astype(np.uint16), kind="stable")]
    else:
        order = np.lexsort((h, flat))
    f, hs, ws = flat[order], h[order], w[order]
    cum = np.cumsum(ws)
    start = np.flatnonzero(np.r_[True, f[1:] != f[:-1]])
    total = np.add.reduceat(ws, start)
    before = cum[start] - ws[start]
    # the first voxel of each cell whose cumulative weight reaches the share of the cell's
    target = np.repeat(before + _LOW_SHARE * total, np.diff(np.r_[start, len(f)]))
    reached = cum >= target
    first = np.flatnonzero(reached & np.r_[True, ~reached[:-1] | (f[1:] != f[:-1])])
    out = np.full(n_cells, np.inf)
    out[f[first]] = hs[first]
    return out


def fit_ground(
    points: np.ndarray, counts: np.ndarray, up: np.ndarray, cfg: GroundConfig, sigma: float
) -> GroundModel | None:
    """The ground model of a scan's coarse voxels ``points`` (M×3, {S}) holding ``counts`` raw
    points each; ``up`` the unit up direction in {S}, ``sigma`` the scan's noise (m). None when
    there are too few points."""
    if len(points) < _MIN_FIT:
        return None
    basis = _basis(up)
    x = np.asarray(points, float) @ basis.T
    lo = x[:, :2].min(axis=0)
    ij = np.floor((x[:, :2] - lo) / cfg.cell).astype(np.int64)
    shape = tuple(int(v) + 1 for v in ij.max(axis=0))
    if shape[0] * shape[1] > _MAX_CELLS:
        return None
    flat = ij[:, 0] * shape[1] + ij[:, 1]
    counts = np.asarray(counts, float)
    lowest = _low_heights(flat, x[:, 2], counts, shape[0] * shape[1]).reshape(shape)
    k_open = max(int(np.ceil(cfg.open_radius / cfg.cell)), 1)
    eroded = minimum_filter(lowest, size=2 * k_open + 1, mode="constant", cval=np.inf)
    opened = maximum_filter(np.where(np.isfinite(eroded), eroded, -np.inf), size=2 * k_open + 1, mode="nearest")
    above = x[:, 2] - opened.ravel()[flat]
    k_fit = max(int(np.ceil(cfg.fit_radius / cfg.cell)), 1)
    cand = np.isfinite(above) & (above <= cfg.band)
    # voxels weighted by their points, up to the typical voxel's (the nearest ground must not rule)
    w = np.minimum(counts, np.median(counts))
    fit = (shape, k_fit, 0.05 * cfg.cell**2, np.tan(np.radians(cfg.max_slope_deg)), _MIN_SPREAD * cfg.fit_radius)

    def planes(sel):
        return _fit_planes(x[sel, 0], x[sel, 1], x[sel, 2], w[sel], ij[sel], *fit)

    model = GroundModel(basis, cfg.cell, lo, planes(cand), max(cfg.height, cfg.height_sigmas * sigma))
    # (the points' heights above the planes from their frame coordinates and cells, known here: what
    # model.height(points) computes again, every point inside the grid)
    fitted = cand  # the points of the planes' last fit
    for _ in range(_REFITS):  # on the candidates near the last fit (a pipe or a stone's flank in the band pulls it)
        res = model._above_plane(x, flat)
        near = cand & np.isfinite(res) & (np.abs(res) <= max(_REFIT_SIGMAS * sigma, cfg.height))
        if np.array_equal(near, fitted):
            break  # the same points: the same planes again, and so every later refit (most tank scans)
        model.coef = planes(near)
        fitted = near
    # the ground's own roughness (ripples, gravel) about the planes counts as its noise
    res = model._above_plane(x, flat)
    near &= np.isfinite(res)
    if near.sum() >= _MIN_FIT:
        rough = 1.4826 * float(np.median(np.abs(res[near])))
        model.threshold = max(cfg.height, cfg.height_sigmas * max(sigma, rough))
    return model
