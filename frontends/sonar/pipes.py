"""Pipelines on the elevation map, once the structures are removed.

Ridge cells rise ``min_height_m`` to ``max_height_m`` above the seabed level; cells inside a
recognised structure's footprint (grown by a margin) or near a taller cell (an unrecognised
structure) are not pipe, nor are the cells of a raised area wider than the widest pipe (where the
seabed level lags a slope). Straight pipes are extracted one at a time by RANSAC on the ridge cells
(all hypotheses scored together), refined by a principal axis fit of the inliers and cut into
runs at gaps longer than ``max_gap_m``; ``max_pipes`` counts the lines that gave a pipe (a line
that gave none takes its cells and is not counted, up to 4 × ``max_pipes`` lines). Each run's
cross-section (lateral offset u, height h of the cells near the axis) gives the radius and the
axis height: the upper arc of a circle, h = c + √(r² − (u − u₀)²), fitted by a search over r (the
arc's centre height c by the median, so a partly buried pipe, c < r, is handled). The axis is put at the pipe-centre depth.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from frontends.sonar.config import PipeDetectionConfig
from frontends.sonar.grid import ElevationMap


@dataclass
class PipeSegment:
    """A straight pipe segment in {W}: axis from ``p`` to ``q`` (north, east, depth of the axis)."""

    p: np.ndarray
    q: np.ndarray
    radius: float
    n_cells: int
    residual: float
    connected: tuple[str, ...] = field(default_factory=tuple)

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.q[:2] - self.p[:2]))


def _principal_axis(X: np.ndarray) -> np.ndarray:
    """Unit direction of largest spread of centred 2-D points."""
    w, V = np.linalg.eigh(X.T @ X)
    return V[:, -1]


def _fit_cross_section(u: np.ndarray, h: np.ndarray, cfg: PipeDetectionConfig) -> tuple[float, float, float, float]:
    """(radius, centre height c, lateral offset u0, residual) of the arc h = c + √(r² − (u−u0)²)."""
    top = h > cfg.min_height_m
    if top.sum() < 5:
        return np.nan, np.nan, 0.0, np.inf
    u0 = float(np.average(u[top], weights=np.maximum(h[top], 1e-3) ** 2))
    best = (np.nan, np.nan, u0, np.inf)
    for r in np.arange(cfg.min_radius_m, cfg.max_radius_m + 1e-9, 0.01):
        du = u - u0
        inside = np.abs(du) < r
        core = np.abs(du) < 0.8 * r
        if core.sum() < 5:
            continue
        arc = np.sqrt(np.maximum(r * r - du**2, 0.0))
        c = float(np.median(h[core] - arc[core]))
        res_in = np.abs(h[inside] - c - arc[inside])
        # outside the circle the cells must be at the seabed (no ridge wider than the pipe)
        res_out = np.maximum(h[~inside & (np.abs(du) < r + 0.15)], 0.0)
        cost = float(np.median(np.concatenate([res_in, res_out])))
        if cost < best[3]:
            best = (float(r), c, u0, float(cost))
    return best


def detect_pipes(
    em: ElevationMap,
    ground: np.ndarray,
    cfg: PipeDetectionConfig,
    excluded: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
) -> list[PipeSegment]:
    """Straight pipe segments on the elevation map ``em`` with seabed level ``ground`` (same grid);
    ``excluded`` marks cells that belong to recognised structures."""
    rng = rng or np.random.default_rng(cfg.seed)
    cell = em.spec.cell
    h = ground - em.depth
    bad = np.zeros(h.shape, bool) if excluded is None else excluded.copy()
    tall = (np.nan_to_num(h, nan=0.0) > cfg.max_height_m) & ~bad  # recognised structures are masked already
    if tall.any() and cfg.tall_exclusion_m > 0:
        dist = ndimage.distance_transform_edt(~tall) * cell
        bad |= dist <= cfg.tall_exclusion_m
    ridge = np.isfinite(h) & (h > cfg.min_height_m) & (h <= cfg.max_height_m) & ~bad
    # remove specks (a few noisy cells): a pipe is a connected band at least ~2 cells wide; first
    # close one-cell gaps (cells no return fell in: a pipe across the track, sampled every
    # speed / ping rate ≈ 5 cm across it, leaves empty 4 cm cells along it, and the opening broke
    # the band up)
    ridge = ndimage.binary_opening(ndimage.binary_closing(ridge, iterations=1) & ~bad, iterations=1)
    # ... and at most a pipe wide: what a disc wider than the widest pipe fits in (small holes of
    # noise closed) is a raised stretch of seabed where the seabed level lags a slope (at the edge
    # of the data, beside a structure's pad), not pipe: RANSAC's lines through it took the cells of
    # the pipes crossing it and used up the window's max_pipes
    kd = int(np.ceil((cfg.max_radius_m + 2 * cell) / cell))
    disc = np.hypot(*np.mgrid[-kd : kd + 1, -kd : kd + 1]) <= kd
    ridge &= ~ndimage.binary_opening(ndimage.binary_closing(ridge, iterations=2), structure=disc)
    N, E = em.spec.centres()
    ii, jj = np.nonzero(ridge)
    X = np.column_stack([N[ii], E[jj]])
    out: list[PipeSegment] = []
    alive = np.ones(len(X), bool)
    lines = tried = 0
    while lines < cfg.max_pipes and tried < 4 * cfg.max_pipes:  # the cap bounds a window's time
        tried += 1
        idx = np.flatnonzero(alive)
        if len(idx) < cfg.min_cells:
            break
        Y = X[idx]
        a = rng.integers(len(Y), size=cfg.ransac_iterations)
        b = rng.integers(len(Y), size=cfg.ransac_iterations)
        d = Y[b] - Y[a]
        L = np.linalg.norm(d, axis=1)
        good = L > cfg.min_length_m / 2
        if not good.any():
            break
        a, d, L = a[good], d[good], L[good]
        nrm = np.column_stack([-d[:, 1], d[:, 0]]) / L[:, None]
        # inliers of every hypothesis at once (hypotheses × cells)
        dist = np.abs(nrm @ Y.T - np.einsum("hk,hk->h", nrm, Y[a])[:, None])
        score = (dist < cfg.inlier_m).sum(1)
        k = int(np.argmax(score))
        inl = dist[k] < cfg.inlier_m
        if inl.sum() < cfg.min_cells:
            break
        P = Y[inl]
        c = P.mean(0)
        axis = _principal_axis(P - c)
        normal = np.array([-axis[1], axis[0]])
        lat_all = (Y - c) @ normal
        inl = np.abs(lat_all) < cfg.inlier_m
        s = (Y[inl] - c) @ axis
        order = np.sort(s)
        gaps = np.flatnonzero(np.diff(order) > cfg.max_gap_m)
        starts = np.concatenate([[0], gaps + 1])
        ends = np.concatenate([gaps, [len(order) - 1]])
        taken = False
        for s0, s1 in zip(order[starts], order[ends]):
            if s1 - s0 < cfg.min_length_m:
                continue
            seg = _segment(em, ground, h, c, axis, normal, s0, s1, cfg)
            if seg is not None:
                out.append(seg)
                taken = True
        # remove this line's cells (within the pipe's reach) whatever the outcome
        near = np.abs(lat_all) < max(cfg.inlier_m, cfg.max_radius_m)
        alive[idx[near]] = False
        lines += 1 if taken else 0
    return out


def _segment(em, ground, h, c, axis, normal, s0, s1, cfg) -> PipeSegment | None:
    """Fit the cross-section of the run [s0, s1] along the axis through ``c``; None if it is not a pipe."""
    cell = em.spec.cell
    N, E = em.spec.centres()
    reach = cfg.max_radius_m + 0.2
    lo = np.minimum(c + s0 * axis, c + s1 * axis) - reach
    hi = np.maximum(c + s0 * axis, c + s1 * axis) + reach
    i0, j0 = em.spec.index(lo[0], lo[1])
    i1, j1 = em.spec.index(hi[0], hi[1])
    i0, j0 = max(int(i0), 0), max(int(j0), 0)
    i1, j1 = min(int(i1) + 1, h.shape[0]), min(int(j1) + 1, h.shape[1])
    sub = h[i0:i1, j0:j1]
    n, e = np.meshgrid(N[i0:i1], E[j0:j1], indexing="ij")
    rel = np.stack([n - c[0], e - c[1]], -1)
    s = rel @ axis
    u = rel @ normal
    ok = np.isfinite(sub) & (s >= s0) & (s <= s1) & (np.abs(u) < reach)
    if ok.sum() < cfg.min_cells:
        return None
    # refine the axis on the crest (the cells above 60 % of the ridge's height lie along it)
    crest = ok & (sub > 0.6 * np.percentile(sub[ok], 95)) & (sub > cfg.min_height_m)
    if crest.sum() >= 10:
        X = np.column_stack([n[crest], e[crest]])
        c = X.mean(0)
        v = _principal_axis(X - c)
        axis = v if v @ axis >= 0 else -v
        normal = np.array([-axis[1], axis[0]])
        rel = np.stack([n - c[0], e - c[1]], -1)
        s = rel @ axis
        u = rel @ normal
        sx = (X - c) @ axis
        s0, s1 = max(s0, float(sx.min()) - 0.5), min(s1, float(sx.max()) + 0.5)
        s0, s1 = float(sx.min()), float(sx.max())
        ok = np.isfinite(sub) & (s >= s0) & (s <= s1) & (np.abs(u) < reach)
    r, cz, u0, res = _fit_cross_section(u[ok], sub[ok], cfg)
    if not np.isfinite(r) or res > cfg.max_fit_residual_m or (s1 - s0) < cfg.min_length_m:
        return None
    a2 = c + u0 * normal + s0 * axis
    b2 = c + u0 * normal + s1 * axis
    # axis depth: the crest's depth (measured directly, free of the seabed estimate) + r, as a
    # straight line along the run
    D = em.depth[i0:i1, j0:j1]
    top = ok & np.isfinite(D) & (np.abs(u - u0) < max(r / 3, 2 * cell))
    if top.sum() < 5:
        return None
    A = np.column_stack([np.ones(top.sum()), s[top]])
    coef, *_ = np.linalg.lstsq(A, D[top], rcond=None)
    p = np.array([a2[0], a2[1], coef[0] + coef[1] * s0 + r])
    q = np.array([b2[0], b2[1], coef[0] + coef[1] * s1 + r])
    return PipeSegment(p, q, float(r), int(ok.sum()), float(res))
