"""Elevation maps: points (north, east, depth) in {W} → a north/east grid of robust depths.

A cell's depth is the median of the depths that fall in it (robust to outliers: a few stray returns
cannot move it); cells without a return stay empty (NaN), never interpolated. Heights are taken
above a seabed level estimated from the map itself (:func:`estimate_ground`): structures and pipes
stand out as positive heights, the relief is removed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage


@dataclass(frozen=True)
class GridSpec:
    """A north/east grid: cell (i, j) covers north [n0 + i·cell, n0 + (i+1)·cell) and east likewise."""

    n0: float
    e0: float
    cell: float
    shape: tuple[int, int]

    @classmethod
    def around(cls, lo, hi, cell: float, pad: float = 0.0) -> GridSpec:
        """The grid aligned on multiples of ``cell`` covering the box [lo, hi] (north, east) grown by ``pad``."""
        lo = np.floor((np.asarray(lo, float) - pad) / cell) * cell
        hi = np.asarray(hi, float) + pad
        shape = np.maximum(np.ceil((hi - lo) / cell).astype(int) + 1, 1)
        return cls(float(lo[0]), float(lo[1]), float(cell), (int(shape[0]), int(shape[1])))

    def index(self, n, e) -> tuple[np.ndarray, np.ndarray]:
        return (
            np.floor((np.asarray(n) - self.n0) / self.cell).astype(np.int64),
            np.floor((np.asarray(e) - self.e0) / self.cell).astype(np.int64),
        )

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """North (rows) and east (columns) coordinates of the cell centres."""
        return (
            self.n0 + (np.arange(self.shape[0]) + 0.5) * self.cell,
            self.e0 + (np.arange(self.shape[1]) + 0.5) * self.cell,
        )

    def extent(self) -> tuple[float, float, float, float]:
        """(e_min, e_max, n_min, n_max) for matplotlib's imshow with origin='lower'."""
        return (self.e0, self.e0 + self.shape[1] * self.cell, self.n0, self.n0 + self.shape[0] * self.cell)


def cell_medians(keys: np.ndarray, values: np.ndarray, q: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``q`` quantile (default the median) of ``values`` per distinct key: (unique keys,
    quantiles, counts), interpolated linearly between order statistics (even counts: the median
    averages the two middle values)."""
    if len(keys) == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64)
    order = np.lexsort((values, keys))
    k, v = keys[order], values[order]
    uniq, start, counts = np.unique(k, return_index=True, return_counts=True)
    pos = q * (counts - 1)
    lo = np.floor(pos).astype(np.int64)
    f = pos - lo
    hi = np.minimum(lo + 1, counts - 1)
    return uniq, (1 - f) * v[start + lo] + f * v[start + hi], counts


class ElevationMap:
    """Median depth per north/east cell; NaN where no return fell. ``count`` is the returns per cell."""

    def __init__(self, spec: GridSpec, depth: np.ndarray, count: np.ndarray):
        self.spec = spec
        self.depth = depth
        self.count = count

    @classmethod
    def from_points(
        cls, points: np.ndarray, cell: float = 0.01, spec: GridSpec | None = None, quantile: float = 0.5
    ) -> ElevationMap:
        """Grid N×3 points (north, east, depth) at ``cell`` (or on ``spec``; points outside it are
        ignored). A cell holds the median depth of its points, or their ``quantile`` (0.1: the upper
        surface, as a top-down ray would see it, while an oblique beam also sees under overhangs)."""
        pts = np.asarray(points, float).reshape(-1, 3)
        if spec is None:
            if len(pts) == 0:
                spec = GridSpec(0.0, 0.0, cell, (1, 1))
            else:
                spec = GridSpec.around(pts[:, :2].min(0), pts[:, :2].max(0), cell)
        i, j = spec.index(pts[:, 0], pts[:, 1])
        ok = (i >= 0) & (i < spec.shape[0]) & (j >= 0) & (j < spec.shape[1]) & np.isfinite(pts[:, 2])
        keys = i[ok] * spec.shape[1] + j[ok]
        uniq, med, cnt = cell_medians(keys, pts[ok, 2], quantile)
        depth = np.full(spec.shape, np.nan)
        count = np.zeros(spec.shape, np.int32)
        depth.flat[uniq] = med
        count.flat[uniq] = cnt
        return cls(spec, depth, count)

    @property
    def filled(self) -> np.ndarray:
        return np.isfinite(self.depth)

    def sample(self, n, e) -> np.ndarray:
        """Bilinear interpolation of the depth at (n, e) between the four surrounding cell centres; NaN
        when one of them is empty or outside the grid (no extrapolation across holes)."""
        s = self.spec
        x = (np.asarray(n, float) - s.n0) / s.cell - 0.5
        y = (np.asarray(e, float) - s.e0) / s.cell - 0.5
        i0 = np.floor(x).astype(np.int64)
        j0 = np.floor(y).astype(np.int64)
        fx, fy = x - i0, y - j0
        ok = (i0 >= 0) & (i0 + 1 < s.shape[0]) & (j0 >= 0) & (j0 + 1 < s.shape[1])
        out = np.full(np.shape(x), np.nan)
        if not ok.any():
            return out
        i, j, fx, fy = i0[ok], j0[ok], fx[ok], fy[ok]
        D = self.depth
        out[ok] = (
            (1 - fx) * (1 - fy) * D[i, j]
            + fx * (1 - fy) * D[i + 1, j]
            + (1 - fx) * fy * D[i, j + 1]
            + fx * fy * D[i + 1, j + 1]
        )
        return out

    def fill_small_holes(self, min_neighbours: int = 3) -> ElevationMap:
        """A copy whose empty cells with at least ``min_neighbours`` filled cells among their eight
        neighbours take the mean of those: the gaps between sparse beams close (a bilinear sample
        needs its four surrounding cells), while real holes (shadows, unsurveyed areas) stay empty."""
        D = self.depth
        f = np.isfinite(D)
        v = np.where(f, D, 0.0)
        k = np.ones((3, 3))
        k[1, 1] = 0
        cnt = ndimage.convolve(f.astype(float), k, mode="constant")
        tot = ndimage.convolve(v, k, mode="constant")
        fill = ~f & (cnt >= min_neighbours)
        out = D.copy()
        out[fill] = tot[fill] / cnt[fill]
        return ElevationMap(self.spec, out, self.count)

    def gradient(self) -> tuple[np.ndarray, np.ndarray]:
        """∂depth/∂north and ∂depth/∂east by central differences (NaN next to holes)."""
        D = self.depth
        gn = np.full_like(D, np.nan)
        ge = np.full_like(D, np.nan)
        gn[1:-1] = (D[2:] - D[:-2]) / (2 * self.spec.cell)
        ge[:, 1:-1] = (D[:, 2:] - D[:, :-2]) / (2 * self.spec.cell)
        return gn, ge


def _normalised_smooth(values: np.ndarray, weight: np.ndarray, sigma_cells: float) -> np.ndarray:
    v = np.where(weight > 0, np.nan_to_num(values), 0.0)
    num = ndimage.gaussian_filter(v * weight, sigma_cells, mode="nearest")
    den = ndimage.gaussian_filter(weight.astype(float), sigma_cells, mode="nearest")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 1e-3, num / den, np.nan)


def estimate_ground(
    depth: np.ndarray,
    cell: float,
    block_m: float = 0.5,
    window_m: float = 9.0,
    smooth_m: float = 1.0,
    band_m: float = 0.10,
    iterations: int = 3,
) -> np.ndarray:
    """Seabed depth under every cell of an elevation map (NaN cells included).

    1. Blocks of ``block_m``: the 75 % depth quantile of their filled cells (the deeper side: the
       seabed under a structure's gaps, not its top). 2. A median over ``window_m`` of the blocks:
       a structure (or a pipe) fills less than half of any such window, so the median is seabed.
    3. Refinement: cells within ``band_m`` of that level (or deeper) are seabed; the level is
       re-interpolated from them by a normalised Gaussian convolution (σ ``smooth_m``), which also
       fills the seabed under structures from the seabed around and between their parts.
    """
    D = np.asarray(depth, float)
    H, W = D.shape
    b = max(int(round(block_m / cell)), 1)
    nb = (-(-H // b), -(-W // b))
    pad = np.full((nb[0] * b, nb[1] * b), np.nan)
    pad[:H, :W] = D
    blocks = pad.reshape(nb[0], b, nb[1], b).transpose(0, 2, 1, 3).reshape(nb[0], nb[1], b * b)
    filled = np.isfinite(blocks).sum(-1)
    # 75 % quantile of each block's filled cells: NaNs sort last, so index into the sorted rows
    srt = np.sort(blocks, axis=-1)
    pos = np.maximum(np.round(0.75 * (filled - 1)).astype(np.int64), 0)
    q = np.take_along_axis(srt, pos[..., None], axis=-1)[..., 0]
    q[filled < max(3, b * b // 20)] = np.nan
    if not np.isfinite(q).any():
        return np.full_like(D, np.nan)
    w = max(int(round(window_m / (b * cell))), 1) | 1
    # median over the window; empty blocks first take their nearest block's value
    holes = np.isnan(q)
    if holes.any():
        idx = ndimage.distance_transform_edt(holes, return_distances=False, return_indices=True)
        q = q[tuple(idx)]
    g_blocks = ndimage.median_filter(q, size=w, mode="nearest")
    g = np.repeat(np.repeat(g_blocks, b, 0), b, 1)[:H, :W]
    # smooth the blocky level before the refinement
    g = ndimage.uniform_filter(g, size=b, mode="nearest")
    sig = smooth_m / cell
    for it in range(iterations):
        # the band narrows once the level is smooth: the flanks of a pipe must not pull it up
        ground = np.isfinite(D) & (D >= g - (band_m if it == 0 else band_m / 2))
        if ground.sum() < 10:
            break
        # smoothing on a coarser grid is equivalent and much cheaper for a wide σ
        f = max(int(sig / 4), 1)
        if f > 1:
            Hc, Wc = -(-H // f), -(-W // f)
            vv = np.zeros((Hc * f, Wc * f))
            ww = np.zeros((Hc * f, Wc * f))
            vv[:H, :W] = np.where(ground, D, 0.0)
            ww[:H, :W] = ground
            vs = vv.reshape(Hc, f, Wc, f).sum((1, 3))
            ws = ww.reshape(Hc, f, Wc, f).sum((1, 3))
            with np.errstate(invalid="ignore", divide="ignore"):
                mean = np.where(ws > 0, vs / np.maximum(ws, 1), np.nan)
            gc = _normalised_smooth(mean, ws, sig / f)
            gi = ndimage.zoom(
                np.nan_to_num(gc, nan=np.nanmean(gc) if np.isfinite(gc).any() else 0.0),
                f,
                order=1,
                mode="nearest",
                grid_mode=True,
            )[:H, :W]
            g_new = gi
        else:
            g_new = _normalised_smooth(D, ground.astype(float), sig)
        g = np.where(np.isfinite(g_new), g_new, g)
    return g


def heights(em: ElevationMap, ground: np.ndarray) -> np.ndarray:
    """Height above the seabed (m, up positive) per cell; NaN where the map is empty."""
    return ground - em.depth
