"""Pipe detection: sequential cylinder RANSAC with normals, then duplicate merge (all in {S}, metres).

A hypothesis is drawn, as in PCL's ``SACMODEL_CYLINDER``, from two points with their normals: the
axis is n1 × n2, the axis point and radius come from where the two normal lines meet. Hypotheses are
drawn in a batch (pairs of neighbours, where both points are likely on one pipe) and scored together
on a sample of the remaining points: a point is an inlier when its distance to the axis is within
``distance_tolerance`` of the radius *and* its normal is within ``normal_tolerance_deg`` of radial
(which is what keeps a pipe's cylinder off the flat faces of objects). The best hypothesis is
refined (axis from the inlier normals, circle fit across it), its inliers split into runs along the
axis where they have gaps or fittings, and every run at least ``min_detect_length`` long is a pipe
segment whose endpoints are its extreme projections on the axis (``reported`` when at least
``min_length`` long: shorter ones only serve the object segmentation and connectivity).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from frontends.laser.config import PipeConfig


@dataclass
class Pipe:
    """A detected pipe segment: axis endpoints ``p``, ``q`` (m, {S}), unit ``axis`` (p→q), radius,
    the indices of its inlier points, and the 6×6 covariance of [p; q]."""

    p: np.ndarray
    q: np.ndarray
    axis: np.ndarray
    radius: float
    inliers: np.ndarray
    covariance: np.ndarray

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.q - self.p))

    def reported(self, cfg: PipeConfig) -> bool:
        """Long enough to be an observation (shorter ones only serve segmentation and connectivity)."""
        return self.length >= cfg.min_length


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def hypotheses(p1, n1, p2, n2, cfg: PipeConfig):
    """Cylinders (axis point c, unit axis a, radius r) through point pairs with normals (batched).

    Normals point out of the pipe (towards the sensor), so the axis lies behind both points along
    −n. Returns the arrays and the mask of valid hypotheses.
    """
    a = np.cross(n1, n2)
    s = np.linalg.norm(a, axis=1)
    ok = s > np.sin(np.radians(8.0))  # near-parallel normals do not define an axis
    a = a / np.maximum(s, 1e-12)[:, None]
    # Closest points of the normal lines p1 + t n1 and p2 + u n2.
    w = p1 - p2
    b = np.einsum("ij,ij->i", n1, n2)
    d = np.einsum("ij,ij->i", n1, w)
    e = np.einsum("ij,ij->i", n2, w)
    den = np.maximum(1.0 - b * b, 1e-12)
    t = (b * e - d) / den
    u = (e - b * d) / den
    c = 0.5 * (p1 + t[:, None] * n1 + p2 + u[:, None] * n2)
    r = -0.5 * (t + u)
    ok &= (t < 0) & (u < 0) & np.isfinite(r)
    ok &= (r >= cfg.min_radius) & (r <= cfg.max_radius)
    if cfg.radius_prior is not None:
        ok &= np.abs(r - cfg.radius_prior) <= cfg.radius_tolerance
    return c, a, r, ok


def inlier_mask(points, normals, c, a, r, cfg: PipeConfig) -> np.ndarray:
    """Inliers of cylinders (c, a, r) given as H×3, H×3, H; points N×3 → H×N mask (H may be 1).

    Written with H×N matrix products only (no H×N×3 temporaries): with v = p − c,
    |v|² = |p|² − 2c·p + |c|², along = a·p − a·c, radial distance² = |v|² − along², and
    radial·n = p·n − c·n − along (a·n).
    """
    along = a @ points.T - np.einsum("hj,hj->h", a, c)[:, None]
    v2 = (points * points).sum(axis=1)[None, :] - 2.0 * (c @ points.T) + (c * c).sum(axis=1)[:, None]
    dist = np.sqrt(np.maximum(v2 - along * along, 1e-18))
    rn = (points * normals).sum(axis=1)[None, :] - c @ normals.T - along * (a @ normals.T)
    close = np.abs(dist - r[:, None]) <= cfg.distance_tolerance
    return close & (rn >= np.cos(np.radians(cfg.normal_tolerance_deg)) * dist)


def fit_cylinder(points: np.ndarray, normals: np.ndarray, a0: np.ndarray, cfg: PipeConfig):
    """Least-squares cylinder: axis, then a circle fit across the axis.

    The centre and radius are an algebraic circle fit refined by Gauss–Newton on
    the geometric distance, or the centre alone when the radius is known.
    """
    # Axis: along a long segment the points' principal direction is the axis (the visible
    # half-shell is the same all along it) and it is far better conditioned than the normals; on a
    # short, stubby set the normals decide (all normals of a cylinder are orthogonal to its axis).
    pv, pvecs = np.linalg.eigh(np.cov(points.T))
    if pv[2] > 9.0 * max(pv[1], 1e-12):
        a = pvecs[:, 2]
    else:
        _, vecs = np.linalg.eigh(normals.T @ normals)
        a = vecs[:, 0]
    a = a if a @ a0 >= 0 else -a
    e1 = _unit(np.cross(a, [1.0, 0, 0]) if abs(a[0]) < 0.9 else np.cross(a, [0, 1.0, 0]))
    e2 = np.cross(a, e1)
    o = points.mean(axis=0)
    x = np.column_stack([(points - o) @ e1, (points - o) @ e2])
    if cfg.radius_prior is not None:
        nx = _unit(np.column_stack([normals @ e1, normals @ e2]))
        r = cfg.radius_prior
        cx = (x - r * nx).mean(axis=0)
    else:
        A = np.column_stack([2 * x, np.ones(len(x))])
        sol, *_ = np.linalg.lstsq(A, (x**2).sum(axis=1), rcond=None)
        cx = sol[:2]
        r = float(np.sqrt(max(sol[2] + cx @ cx, 1e-12)))
        # Geometric refinement (residual |x − c| − r) with trimming: a visible arc of a few voxels
        # is easily pulled by the handful of object points where the pipe enters an object.
        use = np.ones(len(x), bool)
        for it in range(6):
            dv = x[use] - cx
            dn = np.maximum(np.sqrt((dv * dv).sum(axis=1)), 1e-12)
            J = np.empty((len(dv), 3))
            J[:, :2] = -dv / dn[:, None]
            J[:, 2] = -1.0
            try:
                step = np.linalg.solve(J.T @ J, -(J.T @ (dn - r)))  # Gauss–Newton normal equations
            except np.linalg.LinAlgError:
                break
            cx, r = cx + step[:2], r + step[2]
            if it in (2, 4):
                res = np.linalg.norm(x - cx, axis=1) - r
                sigma = 1.4826 * np.median(np.abs(res[use]))
                keep = np.abs(res) <= max(3.0 * sigma, 0.003)
                if keep.sum() >= 6:
                    use = keep
    c = o + cx[0] * e1 + cx[1] * e2
    return c, a, float(r)


def _runs(t: np.ndarray, max_gap: float) -> list[np.ndarray]:
    """Split positions along the axis into runs without gaps above ``max_gap`` (index arrays)."""
    order = np.argsort(t)
    cuts = np.flatnonzero(np.diff(t[order]) > max_gap) + 1
    return np.split(order, cuts)


def split_at_fittings(
    t: np.ndarray, residual: np.ndarray, t_foreign: np.ndarray, cfg: PipeConfig, t_around: np.ndarray | None = None
) -> list[np.ndarray]:
    """Runs of a pipe's inliers, cut where a fitting sits on it (index arrays into ``t``).

    ``t`` are the inliers' positions along the axis, ``residual`` their distance to the axis minus
    the radius; ``t_foreign`` the positions of the other points just outside the pipe's surface
    (within ``fitting_reach`` of it). A fitting shows either way: sockets and unions are wider than
    the pipe they join (bins of ``bump_bin`` whose median residual stands ``bump_height`` above
    the pipe's), and bodies, branches and handles put many foreign points around the axis (at least
    ``fitting_points`` in a bin, over at least ``min_fitting_length``). Those bins' inliers leave
    the pipe (to the objects), the pipe is cut there. A gap in the inliers (a pipe in front hides
    part of this one) is bridged unless longer than ``max_gap`` or holding at least
    ``fitting_points`` of ``t_around`` (points within ``gap_reach`` of the surface: a body whose
    faces are not cylinder inliers): fittings, not gaps, are what separate two pipes.
    """
    if len(t) == 0:
        return []
    t0 = t.min()
    b = np.floor((t - t0) / cfg.bump_bin).astype(np.int64)
    n_bins = int(b.max()) + 1
    # Median residual per bin, vectorised: sort by (bin, residual), take each bin's middle element.
    order = np.lexsort((residual, b))
    bs, rs = b[order], residual[order]
    starts = np.flatnonzero(np.r_[True, bs[1:] != bs[:-1]])
    counts = np.diff(np.r_[starts, len(bs)])
    med = np.full(n_bins, np.nan)
    med[bs[starts]] = 0.5 * (rs[starts + (counts - 1) // 2] + rs[starts + counts // 2])
    cnt = np.zeros(n_bins, np.int64)
    cnt[bs[starts]] = counts
    # Against the pipe's own level nearby (a slightly tilted fit makes the level drift along the
    # axis): the median of the bin medians over ±bump_window, longer than any socket.
    w = int(np.ceil(cfg.bump_window / cfg.bump_bin))
    padded = np.pad(med, w, constant_values=np.nan)
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * w + 1)
    with warnings.catch_warnings():  # empty bins (occlusion) are NaN; an all-NaN window gives NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        level = np.nanmedian(windows, axis=1)
    height = cfg.bump_height if cfg.radius_prior is None else cfg.bump_height_known_radius
    bad = set(np.flatnonzero((med - level > height) & (cnt >= 3)).tolist())
    if len(t_foreign):
        fb = np.floor((t_foreign - t0) / cfg.bump_bin).astype(np.int64)
        u, c = np.unique(fb, return_counts=True)
        bad |= set(u[c >= cfg.fitting_points].tolist())
    bad_bins = np.sort(np.fromiter(bad, np.int64, len(bad)))
    # A fitting is at least min_fitting_length long (the shortest socket is 8.8 cm): a lone bin is
    # noise or a pipe passing close by, not a fitting.
    if len(bad_bins):
        run_start = np.r_[True, np.diff(bad_bins) > 1]
        run_id = np.cumsum(run_start) - 1
        run_len = np.bincount(run_id)
        need = max(int(round(cfg.min_fitting_length / cfg.bump_bin)), 1)
        bad_bins = bad_bins[run_len[run_id] >= need]
    kept = np.flatnonzero(~np.isin(b, bad_bins))
    if len(kept) == 0:
        return []
    kept = kept[np.argsort(t[kept])]
    tk = t[kept]
    # Cut between consecutive kept points with a fitting bin between them, or too far apart.
    lo = t0 + bad_bins * cfg.bump_bin
    fitting_between = np.searchsorted(lo, tk[1:]) > np.searchsorted(lo, tk[:-1])
    gap = np.diff(tk)
    cut = fitting_between | (gap > cfg.max_gap)
    if t_around is not None and len(t_around):
        ta = np.sort(t_around)
        inside = np.searchsorted(ta, tk[1:]) - np.searchsorted(ta, tk[:-1], side="right")
        cut |= (gap > cfg.min_fitting_length) & (inside >= cfg.fitting_points)
    return np.split(kept, np.flatnonzero(cut) + 1)


def endpoint_covariance(p, q, axis, n_points, mean_range, cfg: PipeConfig) -> np.ndarray:
    """6×6 covariance of [p; q].

    Across the axis: a line fitted to n points spread evenly along it has, at its ends, variance
    4σ²/n and correlation −1/2 between the two ends (σ the point noise, growing with range).
    Along the axis: the extreme projection is uncertain by ``endpoint_sigma`` (sampling) and σ.
    """
    sigma = cfg.range_sigma + cfg.range_sigma_per_m * mean_range
    lat = np.eye(3) - np.outer(axis, axis)
    s = sigma**2 / max(n_points, 1)
    along = (cfg.endpoint_sigma**2 + sigma**2) * np.outer(axis, axis)
    cov = np.zeros((6, 6))
    cov[:3, :3] = cov[3:, 3:] = 4 * s * lat + along
    cov[:3, 3:] = cov[3:, :3] = -2 * s * lat
    return cov


def _make_pipe(points, normals, idx, a0, cfg: PipeConfig) -> Pipe:
    c, a, r = fit_cylinder(points[idx], normals[idx], a0, cfg)
    t = (points[idx] - c) @ a
    p, q = c + t.min() * a, c + t.max() * a
    rng = float(np.linalg.norm(points[idx], axis=1).mean())
    return Pipe(p, q, a, r, idx, endpoint_covariance(p, q, a, len(idx), rng, cfg))


def _refine(points, normals, cand, c, a, r, cfg: PipeConfig):
    """Refit a hypothesis to its inliers among ``cand`` until they stop changing (at most
    ``refine_rounds``); None if the fit leaves the radius range."""
    idx = cand[inlier_mask(points[cand], normals[cand], c[None], a[None], np.array([r]), cfg)[0]]
    for _ in range(cfg.refine_rounds):
        prev = len(idx)
        if len(idx) < cfg.min_points:
            return None
        c, a, r = fit_cylinder(points[idx], normals[idx], a, cfg)
        if not (cfg.min_radius <= r <= cfg.max_radius):
            return None
        idx = cand[inlier_mask(points[cand], normals[cand], c[None], a[None], np.array([r]), cfg)[0]]
        if abs(len(idx) - prev) <= 2:
            break
    return c, a, r, idx


def detect_pipes(points: np.ndarray, normals: np.ndarray, neighbors: np.ndarray, cfg: PipeConfig) -> list[Pipe]:
    """Pipes among ``points`` (N×3, {S}) with outward ``normals``; ``neighbors`` (N×k) index lists
    used to draw point pairs (−1 = none). Returns merged pipe segments.

    Two masks: ``free`` points may still be inliers; ``seedable`` points may still seed hypotheses.
    A model that yields a pipe consumes its inliers; one that does not (an object's curved part, a
    bad fit) only stops seeding from them, so a pipe sharing points with it can still be found.
    """
    n = len(points)
    rng = np.random.default_rng(cfg.seed)
    free = np.ones(n, bool)
    seedable = np.ones(n, bool)
    pipes: list[Pipe] = []
    failures = 0
    for _ in range(3 * cfg.max_pipes):
        if len(pipes) >= cfg.max_pipes or failures >= cfg.max_failures:
            break
        seeds = np.flatnonzero(seedable & free)
        cand = np.flatnonzero(free)
        if len(seeds) < cfg.min_points:
            break
        i = rng.choice(seeds, cfg.hypotheses)
        j = neighbors[i, rng.integers(neighbors.shape[1] // 3, neighbors.shape[1], cfg.hypotheses)]
        good = j >= 0
        good[good] &= free[j[good]]
        i, j = i[good], j[good]
        c, a, r, ok = hypotheses(points[i], normals[i], points[j], normals[j], cfg)
        if not ok.any():
            seedable[i] = False  # these seeds give no cylinder at all (flat or ragged surface)
            failures += 1
            continue
        i, c, a, r = i[ok], c[ok], a[ok], r[ok]
        sample = cand if len(cand) <= cfg.score_sample else rng.choice(cand, cfg.score_sample, replace=False)
        in_sample = inlier_mask(points[sample], normals[sample], c, a, r, cfg)
        scores = in_sample.sum(axis=1)
        # Refine the best hypothesis; if its fit leaves the radius range, the next best (up to 3).
        refined = None
        tried = np.argsort(scores)[::-1][:3]
        if scores[tried[0]] * len(cand) / len(sample) >= cfg.min_points:
            for h in tried:
                refined = _refine(points, normals, cand, c[h], a[h], r[h], cfg)
                if refined is not None:
                    break
        if refined is None:
            # No pipe here: stop seeding from these hypotheses' seeds and sampled inliers.
            seedable[i[tried]] = False
            seedable[sample[in_sample[tried].any(axis=0)]] = False
            failures += 1
            continue
        cb, ab, rb, idx = refined
        found = False
        v = points - cb
        t_all = v @ ab
        res_all = np.linalg.norm(v - np.outer(t_all, ab), axis=1) - rb
        t, residual = t_all[idx], res_all[idx]
        span = (t_all > t.min() - cfg.max_gap) & (t_all < t.max() + cfg.max_gap)
        near = (res_all > cfg.distance_tolerance) & (res_all < cfg.fitting_reach) & span
        around = (res_all > cfg.distance_tolerance) & (res_all < cfg.gap_reach) & span
        for run in split_at_fittings(t, residual, t_all[near], cfg, t_all[around]):
            seg = idx[run]
            if len(seg) < cfg.min_points:
                continue
            pipe = _make_pipe(points, normals, seg, ab, cfg)
            if pipe.length >= cfg.min_detect_length and cfg.min_radius <= pipe.radius <= cfg.max_radius:
                pipes.append(pipe)
                free[seg] = False
                found = True
        seedable[idx] = False
        failures = 0 if found else failures + 1
    return merge_duplicates(pipes, points, normals, cfg)


def merge_duplicates(pipes: list[Pipe], points, normals, cfg: PipeConfig) -> list[Pipe]:
    """Merge segments of one pipe found twice: near-parallel, coaxial, overlapping or nearly touching."""
    pipes = list(pipes)
    cos_max = np.cos(np.radians(cfg.merge_angle_deg))
    merged = True
    while merged and len(pipes) > 1:
        merged = False
        for x in range(len(pipes)):
            for y in range(x + 1, len(pipes)):
                A, B = pipes[x], pipes[y]
                if abs(A.axis @ B.axis) < cos_max:
                    continue
                mid_b = 0.5 * (B.p + B.q)
                off = mid_b - A.p
                lateral = np.linalg.norm(off - (off @ A.axis) * A.axis)
                if lateral > cfg.merge_distance:
                    continue
                tb = sorted([(B.p - A.p) @ A.axis, (B.q - A.p) @ A.axis])
                gap = max(tb[0] - A.length, -tb[1], 0.0)
                if gap > cfg.merge_gap:
                    continue
                seg = np.union1d(A.inliers, B.inliers)
                pipes[x] = _make_pipe(points, normals, seg, A.axis, cfg)
                del pipes[y]
                merged = True
                break
            if merged:
                break
    return pipes
