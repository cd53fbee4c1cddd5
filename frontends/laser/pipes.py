"""Pipe detection: sequential cylinder RANSAC with normals, then duplicate merge (all in {S}, metres).

A hypothesis comes from a seed point's neighbourhood (a 5×5×5-voxel patch): the axis is the
direction its normals are orthogonal to, the radius the rate at which they turn across it
(``patch_hypotheses``; PCL's ``SACMODEL_CYLINDER`` draws two points with their normals instead,
``hypotheses``, of which only ~15 % give a usable radius on 1 cm voxels). Hypotheses are drawn
in a batch and scored together on a sample of the remaining points: a point is an inlier when its
distance to the axis is within ``distance_tolerance`` of the radius *and* its normal is within
``normal_tolerance_deg`` of radial (which is what keeps a pipe's cylinder off the flat faces of
objects). The best hypothesis is refined (axis from the inlier normals, circle fit across it; on
the points near its axis only), its inliers split into runs along the axis where they have gaps
or fittings, and every run at least ``min_detect_length`` long is a pipe segment whose endpoints
are its extreme projections on the axis (``reported`` when at least ``min_length`` long: shorter
ones only serve the object segmentation and connectivity).

A pipe is a solid: the sensor cannot see through it. A segment is kept only if the scan's rays
that cross its cylinder (well inside its silhouette) end on it, not behind it (``Rays``,
``max_see_through``): a flat strip about as wide as the pipe, such as a butterfly valve's lever
with its gear head, fits the cylinder's visible half as well as a pipe does (a 32 mm face lies
within the distance and normal tolerances of a 31.5 mm cylinder), but the rays through the rest of
that cylinder reach the valve body and the floor behind it.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from frontends.laser.config import PipeConfig
from frontends.laser.eigen import eigen3_parts
from frontends.laser.grid import median_of, row_dot, single_threaded_blas, split_sorted


@functools.lru_cache(maxsize=64)
def _cos_deg(deg: float) -> np.float64:
    """``np.cos(np.radians(deg))`` (the same value), once per angle: the tolerances' cosines are
    read in every inlier test, ~250 times a scan."""
    return np.cos(np.radians(deg))


_REFINE_REACH = 0.05  # m beyond a pipe's surface over which a refinement looks for its inliers
# A patch's normals must turn (mean sin² of their spread across the axis, a pipe of radius r over
# ±2 cm: ~0.1; a flat face: noise) about one axis (off-axis spread well below that).
_MIN_TURN = 0.02
_MAX_FITTING = 0.25  # m: a segment no longer than this may be a fitting found as a pipe (sockets, tee runs)
_MAX_OFF_AXIS = 0.5
# A pipe's bare end (split_at_fittings' open_beyond): the cylinder continued from 2 to 10 cm past its
# last inlier (past an end cap's rim) is seen through by at least half of at least 5 crossing rays.
_OPEN_FROM, _OPEN_TO, _MIN_OPEN_RAYS = 0.02, 0.10, 5
# A run's end stops at a fitting when flagged bins (split_at_fittings) begin within this many bins
# of its outermost inlier's (2 bins of 2 cm: the bin of a fitting's first points, and one more
# for a partly filled bin or a thin gap of missing returns at the joint).
_FITTED_END_BINS = 2
# A pipe seen over a narrow arc at stereo noise fits too large a radius, but not by more than this
# factor (pipeline seeds 4, 15, 16, true poses: 58-79 mm free on 55-57 mm lines; stop 38): a free
# radius more than twice a nominal one is something else (a 22 mm nominal radius held on seabed
# humps fitted at > 64 mm made false pipes on seed 9).
_MAX_ARC_BIAS = 2.0


@dataclass
class Pipe:
    """A detected pipe segment: axis endpoints ``p``, ``q`` (m, {S}), unit ``axis`` (p→q), radius,
    the indices of its inlier points, and the 6×6 covariance of [p; q]; ``between_fittings``: both
    its ends stop at a fitting (it was cut there from its cylinder fit's inliers on both sides);
    ``radius_held``: its radius is a nominal one (``nominal_radii``), held in the fit (a narrow arc)."""

    p: np.ndarray
    q: np.ndarray
    axis: np.ndarray
    radius: float
    inliers: np.ndarray
    covariance: np.ndarray
    between_fittings: bool = False
    radius_held: bool = False
    objects_only: bool = False  # a short held run given to the object stage only (``held_short_objects``)

    @property
    def length(self) -> float:
        # (np.linalg.norm's value, √(d·d), without its overhead: read ~200 times a scan)
        d = self.q - self.p
        return math.sqrt(d.dot(d))

    def reported(self, cfg: PipeConfig) -> bool:
        """Long enough to be an observation (shorter ones only serve segmentation and connectivity),
        or, with ``report_between_fittings``, a whole pipe between two fittings at least
        ``between_fittings_radii`` radii long: its extent is seen from end to end. Never one that only
        serves the objects (``objects_only``)."""
        if self.objects_only:
            return False
        if self.length >= cfg.min_partial_length:
            return True
        return (
            cfg.report_between_fittings
            and self.between_fittings
            and self.length >= cfg.between_fittings_radii * self.radius
        )


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


def patch_hypotheses(points, normals, grid, seeds, usable, cfg: PipeConfig):
    """Cylinders (axis point c, unit axis a, radius r) from the neighbourhoods of ``seeds``: the
    ``usable`` structure cells within two voxels (a 5×5×5 patch, ±2 cm). Returns c, a, r and the
    mask of valid hypotheses.

    A cylinder's normals all lie in the plane across its axis, so the axis is the direction the
    patch's normals are most orthogonal to (smallest eigenvector of Σ n nᵀ); the radius is the rate
    at which the normal turns across the axis (p = c + r·n ⇒ Δp⊥ = r·Δn⊥, least squares); the axis
    lies behind the seed at that radius. A patch fits some cylinder where its normals turn (a flat
    face's do not) about one axis (a ball's turn about all). One patch of ~15 normals gives a far
    steadier axis and radius than the two normals of PCL's point pairs (``hypotheses``), of which
    only ~15 % give a radius near the tank's at this resolution: fewer, better hypotheses.
    """
    nb = grid.neighbours(2, rows=seeds)
    # (seed, neighbour) pairs, by seed (−1 reads False), by flat positions: np.nonzero's order
    pair = np.flatnonzero(np.append(usable, False)[nb])
    s_of, j = pair // nb.shape[1], nb.take(pair)
    cnt = np.bincount(s_of, minlength=len(seeds))
    # (rows gathered by np.take: several times faster than fancy indexing on N×3 arrays)
    N = normals.take(j, axis=0)
    # (the six products n_i n_j as rows: the sums run along contiguous rows, and are the 6×S parts
    # eigen3_parts takes)
    M = _sums_by_seed(N.T.take([0, 0, 0, 1, 1, 2], axis=0) * N.T.take([0, 1, 2, 1, 2, 2], axis=0), cnt)
    lam0, lam1, _, a = eigen3_parts(M)
    # Offsets from the seed across the axis, of positions and of normals.
    aj = a.take(s_of, axis=0)
    ps, ns = points.take(seeds, axis=0), normals.take(seeds, axis=0)
    dp = points.take(j, axis=0) - ps.take(s_of, axis=0)
    dn = N - ns.take(s_of, axis=0)
    dp -= np.einsum("pj,pj->p", dp, aj)[:, None] * aj
    dn -= np.einsum("pj,pj->p", dn, aj)[:, None] * aj
    sums = _sums_by_seed(np.stack([np.einsum("pj,pj->p", dp, dn), np.einsum("pj,pj->p", dn, dn)]), cnt)
    r = sums[0] / np.maximum(sums[1], 1e-300)
    ok = (cnt >= 6) & (lam1 >= _MIN_TURN * cnt) & (lam0 <= _MAX_OFF_AXIS * lam1)
    nominal = _nominal_radii(cfg)
    if nominal:
        # A patch of a pipe seen over a narrow arc turns its normals too little for its radius: the
        # radius reads too large (up to _MAX_ARC_BIAS times), the axis stays right. Such a patch
        # proposes the largest nominal radius in range (its own radius is no guide there).
        largest = max(nominal)
        r = np.where(ok & (r > cfg.max_radius) & (r <= _MAX_ARC_BIAS * largest), largest, r)
    ok &= (r >= cfg.min_radius) & (r <= cfg.max_radius)
    if cfg.radius_prior is not None:
        r = np.full(len(seeds), cfg.radius_prior)
    ns = ns - np.einsum("sj,sj->s", ns, a)[:, None] * a
    ns /= np.maximum(np.linalg.norm(ns, axis=1), 1e-12)[:, None]
    c = ps - r[:, None] * ns
    return c, a, r, ok


def _nominal_radii(cfg: PipeConfig) -> list[float]:
    """The ``nominal_radii`` in the radius range (none when ``radius_prior`` holds every fit)."""
    if cfg.radius_prior is not None:
        return []
    return [float(r) for r in cfg.nominal_radii if cfg.min_radius <= r <= cfg.max_radius]


def _sums_by_seed(x: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Sums of consecutive column groups of ``x`` (k×P, grouped by seed, ``counts`` columns each; a
    group may be empty), by differences of a cumulative sum along the rows (k×S)."""
    c = np.zeros((x.shape[0], x.shape[1] + 1))
    np.cumsum(x, axis=1, out=c[:, 1:])
    end = np.cumsum(counts)
    return c[:, end] - c[:, end - counts]


def inlier_mask(points, normals, c, a, r, cfg: PipeConfig, sq=None, pn=None) -> np.ndarray:
    """Inliers of cylinders (c, a, r) given as H×3, H×3, H; points N×3 → H×N mask (H may be 1).

    Written with H×N matrix products only (no H×N×3 temporaries): with v = p − c,
    |v|² = |p|² − 2c·p + |c|², along = a·p − a·c, radial distance² = |v|² − along², and
    radial·n = p·n − c·n − along (a·n). ``sq`` = |p|² and ``pn`` = p·n per point may be passed
    when already known (they do not depend on the cylinder).
    """
    sq = row_dot(points, points) if sq is None else sq
    pn = row_dot(points, normals) if pn is None else pn
    # (the same operations in the same order as written out in the comments, into as few H×N
    # temporaries as possible: allocating them was a good part of the cost)
    along = a @ points.T  # along = a·p − a·c
    along -= np.einsum("hj,hj->h", a, c)[:, None]
    v2 = c @ points.T  # v2 = |p|² − 2 c·p + |c|²
    v2 *= 2.0
    np.subtract(sq[None, :], v2, out=v2)
    v2 += (c * c).sum(axis=1)[:, None]
    tmp = along * along  # dist = √max(v2 − along², 1e-18)
    np.subtract(v2, tmp, out=v2)
    dist = np.sqrt(np.maximum(v2, 1e-18, out=v2), out=v2)
    rn = c @ normals.T  # rn = p·n − c·n − along (a·n)
    np.subtract(pn[None, :], rn, out=rn)
    an = a @ normals.T
    np.multiply(along, an, out=an)
    rn -= an
    np.subtract(dist, r[:, None], out=tmp)  # |dist − r| within the tolerance
    close = np.abs(tmp, out=tmp) <= cfg.distance_tolerance
    np.multiply(_cos_deg(cfg.normal_tolerance_deg), dist, out=tmp)
    close &= rn >= tmp
    return close


class _Points:
    """Points with outward normals (a subset of the structure cloud, ``index`` into it), with the
    cylinder-independent products of the inlier test computed once."""

    def __init__(self, points, normals, index):
        self.index = index
        self.p = points.take(index, axis=0)  # (rows by np.take: several times faster than points[index])
        self.n = normals.take(index, axis=0)
        self.sq = row_dot(self.p, self.p)
        self.pn = row_dot(self.p, self.n)

    def subset(self, mask) -> _Points:
        """The points of a mask (or of sorted indices) of these."""
        sub = object.__new__(_Points)
        k = mask.nonzero()[0] if mask.dtype == bool else mask
        sub.index, sub.sq, sub.pn = self.index[k], self.sq[k], self.pn[k]
        sub.p, sub.n = self.p.take(k, axis=0), self.n.take(k, axis=0)
        return sub

    def test(self, c, a, r, cfg: PipeConfig):
        """Inlier mask of the cylinder (c, a, r)."""
        along, dist = self._along_dist(c, a)
        return self._inliers(c, a, r, cfg, along, dist)

    def test_near(self, c, a, r, cfg: PipeConfig, reach: float):
        """(indices of the points within ``r + reach`` of the axis, inlier mask of those points)
        for one cylinder: the inlier test runs on the points near the axis only (inliers are
        within ``r + distance_tolerance`` ≤ ``r + reach``)."""
        along = self.p @ a - a @ c
        d2 = self.sq - 2.0 * (self.p @ c) + c @ c - along * along
        # (the distances, √max(d², 1e-18) as in _along_dist, of the points whose d² is within a
        # bound a little above (r + reach)² only: no point whose rounded distance is within r + reach
        # lies beyond it, and elementwise results do not depend on the other elements)
        lim = r + reach
        maybe = (d2 <= lim * lim * (1.0 + 1e-9)).nonzero()[0]
        dist = np.sqrt(np.maximum(d2[maybe], 1e-18))
        within = dist <= lim
        near = maybe[within]
        return near, self._inliers(c, a, r, cfg, along[near], dist[within], near)

    def _along_dist(self, c, a):
        """Position along the axis and distance to it of every point."""
        along = self.p @ a - a @ c
        return along, np.sqrt(np.maximum(self.sq - 2.0 * (self.p @ c) + c @ c - along * along, 1e-18))

    def _inliers(self, c, a, r, cfg: PipeConfig, along, dist, rows=None):
        """Inlier mask (of the points ``rows``, all when None; ``along`` and ``dist`` those of the
        rows): within the distance tolerance of the surface, normal within the normal tolerance of
        radial. (The products with c and a are of the rows' normals only when they are at least
        two: a matrix-vector product gives every row the same value whichever other rows it
        holds, the one-row product does not.)"""
        pn = self.pn
        if rows is None:
            nc, na = self.n @ c, self.n @ a
        elif len(rows) >= 2:
            n = self.n.take(rows, axis=0)
            nc, na, pn = n @ c, n @ a, pn[rows]
        else:
            nc, na, pn = (self.n @ c)[rows], (self.n @ a)[rows], pn[rows]
        rn = pn - nc - along * na
        return (np.abs(dist - r) <= cfg.distance_tolerance) & (rn >= _cos_deg(cfg.normal_tolerance_deg) * dist)


class Rays:
    """The scan's rays from the sensor (at the origin of {S}): unit ``directions`` (N×3, float32)
    and the ``ranges`` (N,) at which they returned, for the see-through test of pipe segments."""

    def __init__(self, points: np.ndarray):
        pts = np.asarray(points, dtype=np.float64)
        ranges = np.sqrt(row_dot(pts, pts))
        keep = ranges > 0
        if not keep.all():  # (a copy of the scan only when some point is at the origin)
            pts, ranges = pts[keep], ranges[keep]
        self.ranges = ranges
        self.directions = (pts / ranges[:, None]).astype(np.float32)

    def _cones(self, centres: np.ndarray, halves: np.ndarray) -> list[np.ndarray]:
        """Indices of the rays inside the cone around each bounding sphere (centre, radius), all
        spheres in one matrix product (a sphere around the sensor gets no rays)."""
        C, lim, ok = self._cosines(centres, halves)
        return [(C[j] >= lim[j]).nonzero()[0] if ok[j] else np.zeros(0, np.int64) for j in range(len(centres))]

    def _cosines(self, centres: np.ndarray, halves: np.ndarray):
        """(the cosines of every ray to the direction of every sphere's centre (S×N, float32), the
        cones' least cosines (S, float32), whether each cone is defined) of :meth:`_cones`."""
        dist = np.sqrt((centres * centres).sum(axis=1))
        ok = dist > halves
        cos = np.sqrt(1.0 - np.minimum(halves / np.maximum(dist, 1e-12), 1.0) ** 2)
        unit = (centres / np.maximum(dist, 1e-12)[:, None]).astype(np.float32)
        C = unit @ self.directions.T
        # (the rays' float32 cosines against the least float32 not below each cone's cosine: the
        # same test as against the float64 cosine, without converting the N cosines to float64)
        return C, least_float32_not_below(cos), ok

    def _count(self, sel, c, a, r, t0, t1, cfg: PipeConfig, deep: float | None = None) -> tuple[int, int]:
        """(rays of ``sel`` returning behind the cylinder (c, a, r) between t0 and t1 along a — past
        its exit by ``see_through_margin``, or with ``deep`` past their entry by that much — rays
        crossing it) for :meth:`see_through` and :meth:`hollow`."""
        behind, crossing = self._counts([sel], [(c, a, r, t0, t1)], cfg, None if deep is None else [deep])
        return int(behind[0]), int(crossing[0])

    def _counts(self, sels: list, cylinders: list, cfg: PipeConfig, deep: list | None = None):
        """:meth:`_count` of several cylinders (c, a, r, t0, t1) and their rays ``sels`` at once:
        (behind, crossing) as arrays. The rays of all are taken together and every elementwise
        step runs once on all of them (each ray with its own cylinder's values); the two
        matrix-vector products run per cylinder, on its own rows (a contiguous block: a product
        gives a row the same value whichever other rows it holds), so every count is the one
        cylinder by cylinder."""
        n = len(sels)
        sizes = np.array([len(x) for x in sels], np.int64)
        bounds = [0, *np.cumsum(sizes).tolist()]
        sel = np.concatenate(sels) if n > 1 else np.asarray(sels[0], np.int64)
        cyl = np.repeat(np.arange(n), sizes)  # each ray's cylinder
        d = self.directions.take(sel, axis=0).astype(np.float64)
        da, wcp = np.empty(len(sel)), np.empty(len(sel))
        axes, ca, q, lo, hi = np.empty((n, 3)), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
        cps = []
        for k, (c, a, r, t0, t1) in enumerate(cylinders):
            da[bounds[k] : bounds[k + 1]] = d[bounds[k] : bounds[k + 1]] @ a
            cp = c - (c @ a) * a
            cps.append(cp)
            axes[k], ca[k], q[k], lo[k], hi[k] = a, c @ a, cp @ cp - r * r, t0 + 0.01, t1 - 0.01
        w = d - da[:, None] * axes.take(cyl, axis=0)
        for k, cp in enumerate(cps):
            wcp[bounds[k] : bounds[k + 1]] = w[bounds[k] : bounds[k + 1]] @ cp
        A = np.maximum(row_dot(w, w), 1e-12)
        B = -2.0 * wcp
        disc = B * B - 4.0 * A * q.take(cyl)
        hit = (disc > 0).nonzero()[0]  # (the rest miss their cylinder: the chords of these only)
        A, B, disc, da, cyl = A[hit], B[hit], disc[hit], da[hit], cyl[hit]
        root = np.sqrt(np.maximum(disc, 0.0))
        s1, s2 = (-B - root) / (2 * A), (-B + root) / (2 * A)
        t_mid = 0.5 * (s1 + s2) * da - ca.take(cyl)
        crossing = (s1 > 0) & (s2 - s1 >= cfg.see_through_chord) & (t_mid > lo.take(cyl)) & (t_mid < hi.take(cyl))
        rng = self.ranges[sel[hit]]
        if deep is None:
            behind = crossing & (rng > s2 + cfg.see_through_margin)
        else:
            behind = crossing & (rng > s1 + np.asarray(deep, float).take(cyl))
        return np.bincount(cyl[behind], minlength=n), np.bincount(cyl[crossing], minlength=n)

    def hollow(self, c, a, r, t0, t1, cfg: PipeConfig) -> tuple[int, int]:
        """(rays returning more than half the radius past their entry into the cylinder (c, a, r)
        between t0 and t1 along a, rays crossing it as in :meth:`see_through`): where a pipe is, the
        rays end on its surface; where it is absent, they end on the seabed inside its volume or
        beyond (a pipe lying on the ground has the ground under it, so few rays see through it)."""
        (sel,) = self._cones((c + a * 0.5 * (t0 + t1))[None], np.array([np.hypot(0.5 * (t1 - t0), r)]))
        return self._count(sel, c, a, r, t0, t1, cfg, deep=0.5 * r)

    def see_through(self, c, a, r, t0, t1, cfg: PipeConfig) -> tuple[int, int]:
        """(rays returning behind the cylinder (c, a, r) between t0 and t1 along a, rays crossing
        it): a ray crosses it when its chord through the cylinder is at least ``see_through_chord``
        (well inside the silhouette, where a slightly tilted fit cannot matter) within the segment
        (1 cm in from both ends); it returns behind when its range exceeds the exit by
        ``see_through_margin``."""
        (sel,) = self._cones((c + a * 0.5 * (t0 + t1))[None], np.array([np.hypot(0.5 * (t1 - t0), r)]))
        return self._count(sel, c, a, r, t0, t1, cfg)

    def seen_at(self, point: np.ndarray, radius: float, min_rays: int = 3) -> bool:
        """Whether at least ``min_rays`` of the scan's rays pass within ``radius`` of ``point``
        (seen there: outside the field of view, or in a hole of a stereo cloud, none do)."""
        C, lim, ok = self._cosines(np.asarray(point, float)[None], np.array([radius]))
        return (int(np.count_nonzero(C[0] >= lim[0])) if ok[0] else 0) >= min_rays

    def solid(self, pipes: list[Pipe], cfg: PipeConfig) -> np.ndarray:
        """Per pipe segment: whether the rays crossing its cylinder end on it (``see_through``)."""
        if not pipes:
            return np.zeros(0, bool)
        centres = np.array([0.5 * (p.p + p.q) for p in pipes])
        halves = np.array([np.hypot(0.5 * p.length, p.radius) for p in pipes])
        cylinders = [(p.p, p.axis, p.radius, 0.0, p.length) for p in pipes]
        behind, crossing = self._counts(self._cones(centres, halves), cylinders, cfg)
        return behind <= cfg.max_see_through * crossing


def least_float32_not_below(x: np.ndarray) -> np.ndarray:
    """Per float64 value x, the least float32 y ≥ x: for every float32 v, v ≥ x exactly when v ≥ y
    (a comparison of float32 values with float64 ones in float32, to the same result)."""
    y = x.astype(np.float32)
    return np.where(y.astype(np.float64) < x, np.nextafter(y, np.float32(np.inf)), y)


def fit_cylinder(points: np.ndarray, normals: np.ndarray, a0: np.ndarray, cfg: PipeConfig, radius=None):
    """Least-squares cylinder: axis, then a circle fit across the axis.

    The centre and radius are an algebraic circle fit refined by Gauss–Newton on
    the geometric distance, or the centre alone when the radius is known (``radius``, else
    ``radius_prior``).
    """
    # Axis: along a long segment the points' principal direction is the axis (the visible
    # half-shell is the same all along it) and it is far better conditioned than the normals; on a
    # short, stubby set the normals decide (all normals of a cylinder are orthogonal to its axis).
    # (3×3 scatter matrices by direct products: np.cov's overhead dominates on a few hundred points.)
    # (np.add.reduce(·, 0) / n is what ndarray.mean computes, without its Python overhead: this
    # runs ~100 times a scan on a few hundred points)
    n = len(points)
    o = np.add.reduce(points, 0) / n
    d = points - o
    pv, pvecs = _eigh(d.T @ d)
    _, pv1, pv2 = pv.tolist()  # (Python floats: the same comparison without numpy's scalar overhead)
    if pv2 > 9.0 * max(pv1, 1e-12 * n):
        a = pvecs[:, 2]
    else:
        _, vecs = _eigh(normals.T @ normals)
        a = vecs[:, 0]
    a = a if a @ a0 >= 0 else -a
    E = _across(a)
    x = d @ E
    held = cfg.radius_prior if radius is None else radius
    if held is not None:
        nx = normals @ E
        nx /= np.sqrt(nx[:, 0] * nx[:, 0] + nx[:, 1] * nx[:, 1])[:, None]  # (the row sum, without its per-row loop)
        r = held
        cx = np.add.reduce(x - (r - cfg.surface_offset) * nx, 0) / n
    else:
        cx, r = _circle_fit(x)
    c = o + E @ cx
    return c, a, float(r)


try:  # the LAPACK gufunc behind np.linalg.eigh, without its ~20 µs of checks per 3×3 call (same results)
    from numpy.linalg._umath_linalg import eigh_lo as _eigh_lo
except ImportError:  # pragma: no cover - a numpy that moved it
    _eigh_lo = None


def _eigh(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.linalg.eigh`` of one symmetric 3×3 float64 matrix (lower triangle used, as eigh does)."""
    return _eigh_lo(S, signature="d->dd") if _eigh_lo is not None else np.linalg.eigh(S)


def _across(a: np.ndarray) -> np.ndarray:
    """3×2 orthonormal basis of the plane orthogonal to the unit vector ``a`` (cross products
    written out: ``np.cross`` costs more than the rest of a small fit)."""
    ax, ay, az = a.tolist()
    if abs(ax) < 0.9:  # e1 = a × x̂
        e1 = np.array([0.0, az, -ay])
    else:  # e1 = a × ŷ
        e1 = np.array([-az, 0.0, ax])
    # (the norm by numpy's dot as before, so the basis is the same to the last bit; the rest in
    # Python floats, which round alike)
    e1x, e1y, e1z = (e1 / np.sqrt(e1 @ e1)).tolist()
    e2x, e2y, e2z = ay * e1z - az * e1y, az * e1x - ax * e1z, ax * e1y - ay * e1x
    return np.array([[e1x, e2x], [e1y, e2y], [e1z, e2z]])


def _circle_fit(x: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and radius of a circle through 2-D points: algebraic fit, then Gauss–Newton on the
    geometric distance with trimming (a visible arc of a few voxels is easily pulled by the
    handful of object points where the pipe enters an object)."""
    A = np.column_stack([2 * x, np.ones(len(x))])
    sol, *_ = np.linalg.lstsq(A, (x**2).sum(axis=1), rcond=None)
    cx = sol[:2]
    r = float(np.sqrt(max(sol[2] + cx @ cx, 1e-12)))
    use = None  # all points, until trimmed
    for it in range(6):
        dv = (x if use is None else x[use]) - cx
        dn = np.maximum(_norms2(dv), 1e-12)
        J = np.empty((len(dv), 3))
        J[:, :2] = -dv / dn[:, None]
        J[:, 2] = -1.0
        try:
            step = np.linalg.solve(J.T @ J, -(J.T @ (dn - r)))  # Gauss–Newton normal equations
        except np.linalg.LinAlgError:
            break
        cx, r = cx + step[:2], r + step[2]
        if it in (2, 4):
            res = _norms2(x - cx) - r
            sigma = 1.4826 * median_of(np.abs(res if use is None else res[use]))
            keep = np.abs(res) <= max(3.0 * sigma, 0.003)
            if keep.sum() >= 6:
                use = keep
    return cx, r


def _norms2(v: np.ndarray) -> np.ndarray:
    """Lengths of the rows of an N×2 array: ``np.linalg.norm(v, axis=1)`` and
    ``np.sqrt((v * v).sum(axis=1))`` to the last bit (a row sum of two is their one addition),
    without the per-row loop of a reduction along rows of 2."""
    v0, v1 = v[:, 0], v[:, 1]
    return np.sqrt(v0 * v0 + v1 * v1)


def free_radius(points: np.ndarray, c: np.ndarray, a: np.ndarray) -> tuple[float, float]:
    """(radius, its standard error) of the circle fitted to ``points`` across the axis (c, a), the
    axis direction held: the error from the Gauss-Newton normal matrix and the fit's own residual
    scatter (inf with fewer than 6 points or a singular fit). Over a narrow arc the radius is
    ill-conditioned and its error large."""
    if len(points) < 6:
        return float("nan"), float("inf")
    x = (points - c) @ _across(a)
    cx, r = _circle_fit(x)
    dv = x - cx
    dn = np.maximum(np.sqrt((dv * dv).sum(axis=1)), 1e-12)
    res = dn - r
    J = np.column_stack([-dv / dn[:, None], -np.ones(len(x))])
    try:
        cov = np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return float(r), float("inf")
    sigma2 = float(res @ res) / max(len(x) - 3, 1)
    return float(r), float(np.sqrt(max(cov[2, 2], 0.0) * sigma2))


def _runs(t: np.ndarray, max_gap: float) -> list[np.ndarray]:
    """Split positions along the axis into runs without gaps above ``max_gap`` (index arrays)."""
    order = np.argsort(t)
    cuts = (np.diff(t[order]) > max_gap).nonzero()[0] + 1
    return split_sorted(order, cuts)


def _nanmedian_rows(a: np.ndarray) -> np.ndarray:
    """``np.nanmedian(a, axis=1)`` (NaN for an all-NaN row) by one sort: NaNs sort last, so each
    row's median is the middle of its first ``count`` elements (np.nanmedian loops in Python
    over small arrays)."""
    s = np.sort(a, axis=1)
    n = (~np.isnan(a)).sum(axis=1)
    rows = np.arange(len(a))
    med = 0.5 * (s[rows, np.maximum((n - 1) // 2, 0)] + s[rows, np.maximum(n // 2, 0)])
    return np.where(n > 0, med, np.nan)


@dataclass
class BumpProfile:
    """A pipe's inliers in bins of ``bump_bin`` along its axis (bin 0 from ``t0``): each point's
    ``bin``; per bin its ``count``, ``median`` residual (NaN where empty), the pipe's own ``level``
    around it (the median of the bin medians over ±``bump_window``: a slightly tilted fit makes the
    level drift along the axis) and the ``smooth`` mean residual over it and its two neighbours
    (NaN where they hold fewer than 6 points); ``sigma`` the points' scatter about their bin's
    median (1.4826 × the median absolute deviation: a fitting's offset left out; NaN under 10
    points)."""

    t0: float
    bin: np.ndarray
    count: np.ndarray
    median: np.ndarray
    level: np.ndarray
    smooth: np.ndarray
    sigma: float

    def height(self, cfg: PipeConfig) -> np.ndarray | float:
        """How far a bin's median must stand above the level to show a fitting: ``bump_height``
        (``bump_height_known_radius`` with the radius known), and no less than ``bump_sigmas``
        (``bump_sigmas_known_radius``) × the noise of a bin's median, 1.2533 σ / √n for a median
        of n points: laser or stereo noise makes the profile of a sparse stretch bumpy by itself."""
        known = cfg.radius_prior is not None
        height = cfg.bump_height_known_radius if known else cfg.bump_height
        sigmas = cfg.bump_sigmas_known_radius if known else cfg.bump_sigmas
        if sigmas > 0 and np.isfinite(self.sigma):
            return np.maximum(height, sigmas * 1.2533 * self.sigma / np.sqrt(np.maximum(self.count, 1)))
        return height

    def bumps(self, cfg: PipeConfig) -> np.ndarray:
        """Bins standing out of the profile (a socket, a union: wider than the pipe): the median
        above the level by :meth:`height` (at least 3 points), or with ``bump_smooth`` the mean
        over the bin and its neighbours (a socket's profile is not flat — larger half, central
        stop, reduced half — and on a sparse view its bins alternate around the height)."""
        height = self.height(cfg)
        bad = (self.median - self.level > height) & (self.count >= 3)
        if cfg.bump_smooth:
            bad |= (self.smooth - self.level > height) & (self.count >= 2)
        return bad


def bump_profile(t: np.ndarray, residual: np.ndarray, cfg: PipeConfig) -> BumpProfile:
    """The :class:`BumpProfile` of inliers at ``t`` along the axis with ``residual`` (distance to
    the axis minus the radius; at least one point)."""
    t0 = t.min()
    b = np.floor((t - t0) / cfg.bump_bin).astype(np.int64)
    n_bins = int(b.max()) + 1
    cnt, med = _bin_medians(b, residual, n_bins)
    w = int(np.ceil(cfg.bump_window / cfg.bump_bin))
    padded = np.full(n_bins + 2 * w, np.nan)
    padded[w : w + n_bins] = med
    # (the windows gathered by index: as_strided's views cost more to set up than this copy)
    level = _nanmedian_rows(padded[np.arange(n_bins)[:, None] + np.arange(2 * w + 1)])
    sums = np.bincount(b, weights=residual, minlength=n_bins)
    s3 = np.convolve(sums, np.ones(3), "same")
    c3 = np.convolve(cnt, np.ones(3), "same")
    smooth = np.where(c3 >= 6, s3 / np.maximum(c3, 1), np.nan)
    sigma = 1.4826 * median_of(np.abs(residual - med[b])) if len(t) >= 10 else np.nan
    return BumpProfile(float(t0), b, cnt, med, level, smooth, sigma)


def split_at_fittings(
    t: np.ndarray,
    residual: np.ndarray,
    t_foreign: np.ndarray,
    cfg: PipeConfig,
    t_around: np.ndarray | None = None,
    open_beyond=None,
    ends: list | None = None,
    open_gap=None,
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
    faces are not cylinder inliers): fittings, not gaps, are what separate two pipes. With
    ``t_around``, a bump beyond the outermost segment must have some of them around it to cut the
    pipe (:func:`_bare_ends`; ``open_beyond(t0, t1)``, when given, must also tell that the sensor
    sees through the cylinder continued over [t0, t1]: the pipe ends there). ``ends``, when given, is
    filled with one (low, high) pair per run: whether that end of the run stops at a fitting
    (:func:`_fitted_ends`). ``open_gap(t0, t1)``, when given: whether the pipe is absent over
    [t0, t1] (the rays end inside its cylinder there, not on it); a gap where it is, is not
    bridged (a stone or a sand crest in line with a pipe's free end, past a stretch of bare seabed).
    """
    if len(t) == 0:
        return []
    prof = bump_profile(t, residual, cfg)
    t0, b, n_bins = prof.t0, prof.bin, len(prof.count)
    bad_bin = prof.bumps(cfg)
    # Bins flagged, over a range that also holds the foreign points' bins (which may lie beyond
    # the inliers): flag[k - first] is bin k's.
    first, flag = 0, bad_bin
    if len(t_foreign):
        fb = np.floor((t_foreign - t0) / cfg.bump_bin).astype(np.int64)
        fb_min = int(fb.min())
        crowded = np.bincount(fb - fb_min) >= cfg.fitting_points
        first = min(0, fb_min)
        flag = np.zeros(max(n_bins, fb_min + len(crowded)) - first, bool)
        flag[-first : n_bins - first] = bad_bin
        flag[fb_min - first : fb_min - first + len(crowded)] |= crowded
    # A fitting is at least min_fitting_length long (the shortest socket is 8.8 cm): a lone bin is
    # noise or a pipe passing close by, not a fitting.
    flag = _in_long_runs(flag, max(int(round(cfg.min_fitting_length / cfg.bump_bin)), 1))
    ta = None if t_around is None else np.sort(t_around)
    runs = _kept_runs(flag, first, b, t, t0, ta, cfg, open_gap)
    if ta is not None and cfg.end_fitting_points > 0:
        bare = _bare_ends(flag, first, t, t0, runs, ta, cfg, open_beyond)
        if bare is not None:
            flag = bare
            runs = _kept_runs(flag, first, b, t, t0, ta, cfg, open_gap)
    if ends is not None:
        bumped = np.zeros_like(flag)
        bumped[-first : n_bins - first] = bad_bin
        ends[:] = _fitted_ends(flag & bumped, first, b, runs)
    return runs


def _fitted_ends(flag, first: int, b, runs: list[np.ndarray]) -> list[tuple[bool, bool]]:
    """Per run (inliers in bins ``b``): whether its low and its high end stop at a fitting, a bin
    flagged for standing out of the pipe's profile (``flag[k - first]`` is bin k's: a bump left
    flagged by the cut) within ``_FITTED_END_BINS`` bins beyond its outermost inlier's bin. Such an
    end is where the pipe enters a coaxial part wider than itself (a socket, a valve's port), not the
    view's edge, an occlusion, or the side of a valve's body fitted as a pipe (beyond which the
    valve's other parts crowd without a coaxial shell)."""
    bad = set((flag.nonzero()[0] + first).tolist())
    out = []
    for run in runs:
        # (a run's inliers are sorted along the axis, so are their bins: its first and last hold
        # the lowest and the highest bin)
        lo, hi = int(b[run[0]]), int(b[run[-1]])
        below = any(k in bad for k in range(lo - _FITTED_END_BINS, lo))
        above = any(k in bad for k in range(hi + 1, hi + _FITTED_END_BINS + 1))
        out.append((below, above))
    return out


def _kept_runs(flag, first: int, b, t, t0: float, ta, cfg: PipeConfig, open_gap=None) -> list[np.ndarray]:
    """The runs of the inliers (bin ``b``, at ``t``) outside the flagged bins (``flag[k - first]``
    is bin k's), cut at flagged bins, at gaps longer than ``max_gap``, at gaps holding a body
    (``fitting_points`` of the sorted ``ta``, or None) and, with ``open_gap``, at gaps longer than
    ``min_open_gap`` over which the pipe is absent (``open_gap(t0, t1)``)."""
    bad_bins = flag.nonzero()[0] + first
    kept = (~flag[b - first]).nonzero()[0]
    if len(kept) == 0:
        return []
    kept = kept[np.argsort(t[kept])]
    tk = t[kept]
    # Cut between consecutive kept points with a fitting bin between them, or too far apart.
    fitting_before = np.searchsorted(t0 + bad_bins * cfg.bump_bin, tk)
    gap = tk[1:] - tk[:-1]
    cut = (fitting_before[1:] > fitting_before[:-1]) | (gap > cfg.max_gap)
    if ta is not None and len(ta):
        inside = np.searchsorted(ta, tk[1:]) - np.searchsorted(ta, tk[:-1], side="right")
        cut |= (gap > cfg.min_fitting_length) & (inside >= cfg.fitting_points)
    if open_gap is not None and cfg.min_open_gap > 0:
        for i in (~cut & (gap > cfg.min_open_gap)).nonzero()[0]:
            cut[i] = open_gap(float(tk[i]) + _OPEN_FROM, float(tk[i + 1]) - _OPEN_FROM)
    return split_sorted(kept, cut.nonzero()[0] + 1)


def _bare_ends(flag, first: int, t, t0: float, runs: list[np.ndarray], te, cfg: PipeConfig, open_beyond=None):
    """``flag`` with the flagged bins beyond the outermost segment (a run of at least ``min_points``
    over ``min_detect_length``) cleared, at either end, where fewer than ``end_fitting_points`` of
    ``te`` (sorted: ``t_around``, the points that may show a fitting) lie from that segment's end to
    ``end_fitting_reach`` beyond the outermost inlier: the pipe's own end, not a fitting. None when
    nothing is cleared.

    A bump alone cannot tell a fitting at the end of a pipe from the pipe's last centimetres: a sparse
    4 cm stretch under 5-10 mm of range noise stands 3-6 mm out of a slightly tilted fit as often as a
    socket's surface does (measured on the tank's free pipe ends), and cut there, the pipe stops short
    and its rest reads as an object. A fitting shows more: end faces, a body, a branch, a handle off the
    cylinder. (Flagged bins in between, or a short run beyond them, join the segment.)"""
    # (the runs' inliers are sorted along the axis: a run's first and last are its extremes)
    ends = [(float(t[r[0]]), float(t[r[-1]])) for r in runs if len(r) >= cfg.min_points]
    segments = [(a, b) for a, b in ends if b - a >= cfg.min_detect_length]
    if not segments:
        return None
    out = flag.copy()
    reach, bin_of = cfg.end_fitting_reach, lambda x: int(np.floor((x - t0) / cfg.bump_bin)) - first
    hi, lo = max(b for _, b in segments), min(a for a, _ in segments)
    t_max, t_min = t.max(), t.min()
    cleared = False
    if (
        t_max > hi
        and np.searchsorted(te, t_max + reach, "right") - np.searchsorted(te, hi) < cfg.end_fitting_points
        and (open_beyond is None or open_beyond(t_max + _OPEN_FROM, t_max + _OPEN_TO))
    ):
        out[bin_of(hi) + 1 :] = False
        cleared = True
    if (
        t_min < lo
        and np.searchsorted(te, lo, "right") - np.searchsorted(te, t_min - reach) < cfg.end_fitting_points
        and (open_beyond is None or open_beyond(t_min - _OPEN_TO, t_min - _OPEN_FROM))
    ):
        out[: max(bin_of(lo), 0)] = False
        cleared = True
    return out if cleared and not np.array_equal(out, flag) else None


def _bin_medians(b: np.ndarray, residual: np.ndarray, n_bins: int) -> tuple[np.ndarray, np.ndarray]:
    """Count and median residual of every bin ``b`` (NaN where empty), by one sort on (bin,
    residual): bin k's residuals are then rs[start[k] : start[k] + cnt[k]], in order. (Bin 0 and
    the last bin are never empty, so an empty bin's unused indices stay in range.)"""
    rs = residual[np.lexsort((residual, b))]
    cnt = np.bincount(b, minlength=n_bins)
    start = np.cumsum(cnt) - cnt
    med = 0.5 * (rs[start + (cnt - 1) // 2] + rs[start + cnt // 2])
    return cnt, np.where(cnt > 0, med, np.nan)


def _in_long_runs(flag: np.ndarray, need: int) -> np.ndarray:
    """The True entries of ``flag`` that belong to runs of at least ``need`` consecutive ones."""
    if need <= 1 or len(flag) < need:
        return flag if need <= 1 else np.zeros_like(flag)
    ones = np.ones(need, np.int64)
    full = np.convolve(flag, ones, "valid") == need  # windows of `need` flagged entries
    return np.convolve(full, ones, "full") > 0  # the entries of such windows


def endpoint_covariance(p, q, axis, n_points, mean_range, cfg: PipeConfig) -> np.ndarray:
    """6×6 covariance of [p; q].

    Across the axis, an endpoint's offset is a common shift of the axis plus, with opposite signs
    at the two ends, a tilt. For a line fitted to n points spread evenly along it, with point
    noise σ (growing with range), the shift has variance σ²/n and the tilt 3σ²/n at the ends
    (so each end 4σ²/n, correlation −1/2); the fit's systematic errors add ``axis_shift_sigma``²
    and ``axis_tilt_sigma``² (measured: they dominate σ²/n by far at these densities).
    Along the axis: the extreme projection is uncertain by ``endpoint_sigma`` (sampling) and σ.
    """
    sigma = cfg.range_sigma + cfg.range_sigma_per_m * mean_range
    lat = np.eye(3) - np.outer(axis, axis)
    s = sigma**2 / max(n_points, 1)
    shift = s + cfg.axis_shift_sigma**2
    tilt = 3 * s + cfg.axis_tilt_sigma**2
    along = (cfg.endpoint_sigma**2 + sigma**2) * np.outer(axis, axis)
    cov = np.zeros((6, 6))
    cov[:3, :3] = cov[3:, 3:] = (shift + tilt) * lat + along
    cov[:3, 3:] = cov[3:, :3] = (shift - tilt) * lat
    return cov


# The geometric refinement of a segment's axis: Gauss-Newton rounds, and how far it may turn the
# principal-direction axis (farther: the fit is not trusted, the first axis kept).
_GEOMETRIC_ROUNDS, _GEOMETRIC_MAX_TURN = 6, np.radians(5.0)


def refine_cylinder(points: np.ndarray, c: np.ndarray, a: np.ndarray, r: float, cfg: PipeConfig):
    """The cylinder (c, a, r) refitted to ``points`` by least squares on their distances to its
    surface (Gauss-Newton over the axis' two offsets and two tilts across it, and the radius).
    :func:`fit_cylinder`'s principal direction is the axis only where the visible part of the shell
    is the same all along it; a camera looking forward and down at a pipe on the seabed sees a
    different arc at its near and far ends, which turned the axis by 0.3-0.7° (pipeline scenario,
    seed 6), enough to make the map drift across a long pipeline. The radius is fitted too. Keeps the first fit when the refit turns
    the axis more than 5°, leaves the radius range or fits worse.

    Not with ``radius_prior`` (the tank): there it cut the mean axis error of the tank's segments
    (seeds 10 and 5: 1.59° → 1.13°, 0.62° → 0.27°) but, the radius being fitted too, a one-sided
    view at 9.7 mm range noise made most pipes 22-24 mm thin (prior 31.5) with their axes up to 18 mm
    towards the sensor, and noisy free pipe ends objects (tests/test_laser_lone_end.py; experiments/laser/README.md)."""
    if cfg.radius_prior is not None:
        return c, a, r
    c1, a1, rho = c, a, r

    def residuals(c_, a_, rho_):
        d = points - c_
        t = d @ a_
        x = d - np.outer(t, a_)
        dist = np.maximum(np.sqrt(row_dot(x, x)), 1e-12)
        return dist - rho_, t, x / dist[:, None]

    res, t, n = residuals(c1, a1, rho)
    cost0 = float(res @ res)
    for _ in range(_GEOMETRIC_ROUNDS):
        E = _across(a1)
        nE = n @ E
        J = np.concatenate([-nE, -t[:, None] * nE, -np.ones((len(points), 1))], axis=1)
        try:
            step = np.linalg.solve(J.T @ J, -(J.T @ res))
        except np.linalg.LinAlgError:
            return c, a, r
        c1 = c1 + E @ step[:2]
        a1 = a1 + E @ step[2:4]
        a1 = a1 / np.sqrt(a1 @ a1)
        rho = rho + step[4]
        res, t, n = residuals(c1, a1, rho)
        if np.abs(step).max() < 1e-6:
            break
    turned = np.arccos(min(1.0, abs(float(a1 @ a))))
    if turned > _GEOMETRIC_MAX_TURN or not (cfg.min_radius <= rho <= cfg.max_radius) or res @ res > cost0:
        return c, a, r
    a1 = a1 if a1 @ a >= 0 else -a1
    return c1, a1, float(rho)


def _make_pipe(points, normals, idx, a0, cfg: PipeConfig, radius: float | None = None) -> Pipe:
    """The pipe segment of the inliers ``idx`` (``radius``: a nominal radius held in the fit)."""
    pts = points.take(idx, axis=0)
    c, a, r = fit_cylinder(pts, normals.take(idx, axis=0), a0, cfg, radius)
    if radius is None:
        c, a, r = refine_cylinder(pts, c, a, r, cfg)
    t = (pts - c) @ a
    p, q = c + t.min() * a, c + t.max() * a
    rng = float(np.add.reduce(np.sqrt(np.add.reduce(pts * pts, 1))) / len(pts))  # mean range (np.linalg.norm(·).mean())
    return Pipe(p, q, a, r, idx, endpoint_covariance(p, q, a, len(idx), rng, cfg), radius_held=radius is not None)


def _refine(free: _Points, c, a, r, cfg: PipeConfig):
    """Refit a hypothesis to its inliers among the ``free`` points until they stop changing (at
    most ``refine_rounds``); None if the fit leaves the radius range. Returns (c, a, r, indices,
    held): ``held`` the nominal radius the fit holds, or None.

    With ``nominal_radii`` (and no ``radius_prior``), a free fit that reads a radius above the range
    is fitted again with each nominal radius held (the centre alone), and the one with the most
    inliers goes on, held from then on: a pipe seen over a narrow arc at stereo noise reads far too
    large a radius while its axis is right; whether it lies like a pipe is left to the seabed's tests.

    The rounds run on the points near the axis only (a pipe's inliers are within its radius plus
    the tolerance; ``_REFINE_REACH`` more allows the axis to move): a few hundred points instead of
    the whole structure. The final inliers are then tested on all free points, and if the axis
    moved far enough to gain more than two, the rounds go on from there.
    """
    reach = cfg.distance_tolerance + _REFINE_REACH
    near, inl = free.test_near(c, a, r, cfg, reach)
    rounds = 0
    held = None
    nominal = _nominal_radii(cfg)
    while True:
        local = free.subset(near)
        idx = inl.nonzero()[0]
        while rounds < cfg.refine_rounds:
            rounds += 1
            prev = len(idx)
            if len(idx) < cfg.min_points:
                return None
            P, N = local.p.take(idx, axis=0), local.n.take(idx, axis=0)
            c1, a1, r1 = fit_cylinder(P, N, a, cfg, held)
            if held is None and nominal and r1 > cfg.max_radius:
                fit = _hold_nominal(local, P, N, a, cfg, nominal, r1)
                if fit is None:
                    return None
                c1, a1, r1 = fit
                held = r1
            if not (cfg.min_radius <= r1 <= cfg.max_radius):
                return None
            c, a, r = c1, a1, r1
            idx = local.test(c, a, r, cfg).nonzero()[0]
            if abs(len(idx) - prev) <= 2:
                break
        near, inl = free.test_near(c, a, r, cfg, reach)
        if inl.sum() - len(idx) <= 2 or rounds >= cfg.refine_rounds:
            return c, a, r, free.index[near[inl]], held


def _hold_nominal(local: _Points, P, N, a0, cfg: PipeConfig, nominal: list[float], free: float):
    """The cylinder fitted to points P (normals N) with a radius of ``nominal`` held: of those at least
    ``1 / _MAX_ARC_BIAS`` of the ``free`` fit's radius, the one with the most inliers among ``local``.
    Returns (c, a, r), or None if no nominal radius is near enough."""
    best, most = None, -1
    for rn in nominal:
        if _MAX_ARC_BIAS * rn < free:
            continue
        c, a, r = fit_cylinder(P, N, a0, cfg, rn)
        k = int(local.test(c, a, r, cfg).sum())
        if k > most:
            best, most = (c, a, r), k
    return best


def _facing_sensor(P: np.ndarray, c: np.ndarray, a: np.ndarray, cfg: PipeConfig) -> np.ndarray:
    """Which points lie on the side of the axis (c, a) that faces the sensor (at the origin), within
    ``fitting_window_deg`` about the direction from the axis towards it: a fitting surrounds its pipe,
    so the sensor sees it over the pipe, where clutter beside the pipe (stones, the seabed, mixed
    pixels along its silhouette) does not lie."""
    toward = -(c - (c @ a) * a)  # from the axis towards the sensor, across it
    toward /= max(np.linalg.norm(toward), 1e-12)
    v = P - c
    v -= np.outer(v @ a, a)
    return v @ toward >= _cos_deg(cfg.fitting_window_deg) * np.sqrt(row_dot(v, v))


def _cut_into_segments(
    points,
    normals,
    sq,
    cb,
    ab,
    rb,
    idx,
    cfg: PipeConfig,
    foreign=None,
    seabed=None,
    rays: Rays | None = None,
    held: float | None = None,
) -> list[Pipe]:
    """The pipe segments of a refined cylinder's inliers ``idx``: cut at fittings (foreign points
    just outside its surface, wider sockets; only the points of the mask ``foreign`` count, all when
    None; along a pipe lying on the ``seabed``, only those over it, :func:`_facing_sensor`), keep
    the runs long enough (``held``: the nominal radius the cylinder was fitted with, held in the
    segments' fits)."""
    P = points.take(idx, axis=0)
    t = P @ ab
    if len(idx) < cfg.min_points or t.max() - t.min() < cfg.min_detect_length:
        return []  # no run of these inliers can be a segment
    t_all = points @ ab - ab @ cb
    t = t_all[idx]
    t_lo, t_hi = float(t.min()), float(t.max())
    # Distances to the surface of the inliers and of the points along their span only: a
    # matrix-vector product gives every row the same value whichever other rows it holds, when
    # it has at least two (the inliers are at least min_points ≥ 5 here).
    residual = np.sqrt(np.maximum(sq[idx] - 2.0 * (P @ cb) + cb @ cb - t * t, 0.0)) - rb
    span = ((t_all > t_lo - cfg.max_gap) & (t_all < t_hi + cfg.max_gap)).nonzero()[0]
    P_span, t_span = points.take(span, axis=0), t_all[span]
    pc = P_span @ cb if len(span) >= 2 else (points @ cb)[span]
    res_span = np.sqrt(np.maximum(sq[span] - 2.0 * pc + cb @ cb - t_span * t_span, 0.0)) - rb
    outside = res_span > cfg.distance_tolerance
    if foreign is not None:
        outside &= foreign[span]
    on_seabed = None  # whether the cylinder lies on the seabed (or over unknown ground): read once, when first needed

    def lies_on_seabed() -> bool:
        nonlocal on_seabed
        if on_seabed is None:
            on_seabed = seabed.on_or_unknown(cb, ab, rb, t_lo, t_hi)
        return on_seabed

    if (
        seabed is not None
        and cfg.fitting_window_deg < 180.0
        and outside.any()  # (nothing to narrow down otherwise: the ground's height is not read)
        and lies_on_seabed()
    ):
        outside[outside] = _facing_sensor(P_span.take(outside.nonzero()[0], axis=0), cb, ab, cfg)
    near = outside & (res_span < cfg.fitting_reach)
    around = outside & (res_span < cfg.gap_reach)
    out = []
    open_beyond = None
    if rays is not None and cfg.end_see_through:

        def open_beyond(t0: float, t1: float) -> bool:  # the sensor sees past the cylinder there
            behind, crossing = rays.see_through(cb, ab, rb, t0, t1, cfg)
            return crossing >= _MIN_OPEN_RAYS and behind >= 0.5 * crossing

    open_gap = None
    if rays is not None and seabed is not None and cfg.min_open_gap > 0 and lies_on_seabed():

        def open_gap(t0: float, t1: float) -> bool:  # the rays end inside the cylinder there: no pipe
            deep, crossing = rays.hollow(cb, ab, rb, t0, t1, cfg)
            return crossing >= _MIN_OPEN_RAYS and deep >= 0.5 * crossing

    ends: list[tuple[bool, bool]] = []
    runs = split_at_fittings(t, residual, t_span[near], cfg, t_span[around], open_beyond, ends, open_gap)
    for run, (lo, hi) in zip(runs, ends):
        seg = idx[run]
        if len(seg) < cfg.min_points:
            continue
        pipe = _make_pipe(points, normals, seg, ab, cfg, held)
        if held is not None and pipe.length < cfg.color_max_length:
            # the radius held is no evidence, and a short cylinder on the seabed may be a stone's top:
            # only a straight run long enough to be a pipe by its shape (Seabed) is one; with
            # held_short_objects it still serves the object stage (a fitting at its end)
            if not cfg.held_short_objects:
                continue
            pipe.objects_only = True
        pipe.between_fittings = lo and hi
        if pipe.length >= cfg.min_detect_length and cfg.min_radius <= pipe.radius <= cfg.max_radius:
            out.append(pipe)
    return out


def _apart(extra: list[Pipe], pipes: list[Pipe]) -> list[Pipe]:
    """The ``extra`` segments (object-stage only, in order) that share at most half of their inliers
    with the ``pipes`` and with the extra ones kept before them: taking no points from the search,
    a later cylinder may have fitted theirs again."""
    taken = np.concatenate([p.inliers for p in pipes]) if pipes else np.zeros(0, np.int64)
    out = []
    for p in extra:
        if 2 * int(np.isin(p.inliers, taken).sum()) <= len(p.inliers):
            out.append(p)
            taken = np.concatenate([taken, p.inliers])
    return out


def failure_budget(inlier_share: float, cfg: PipeConfig) -> int:
    """Rounds in a row without a pipe before the search ends, from the inlier ratio (adaptive
    RANSAC): enough for a pipe holding ``inlier_share`` of the seedable points (the smallest share
    of a pipe found so far) to have seeded one of a round's ``hypotheses`` with probability
    ``detection_confidence``; at least ``max_failures``, at most ``max_failures_cap``."""
    if inlier_share >= 1.0 or inlier_share <= 0.0 or cfg.detection_confidence <= 0:
        return cfg.max_failures
    rounds = np.log(1.0 - cfg.detection_confidence) / (cfg.hypotheses * np.log1p(-inlier_share))
    return int(np.clip(np.ceil(rounds), cfg.max_failures, max(cfg.max_failures_cap, cfg.max_failures)))


@single_threaded_blas
def detect_pipes(
    points: np.ndarray,
    normals: np.ndarray,
    grid,
    cfg: PipeConfig,
    rays: Rays | None = None,
    seedable: np.ndarray | None = None,
    foreign: np.ndarray | None = None,
    seabed=None,
) -> list[Pipe]:
    """Pipes among ``points`` (N×3, {S}) with outward ``normals``; ``grid`` the
    :class:`~frontends.laser.grid.VoxelGrid` whose cells they are, to draw point pairs; ``rays``
    the scan's rays for the see-through test (none when None). ``seedable`` (mask, all when None):
    the points that may seed hypotheses (not the ground); ``foreign`` (mask, all when None): the
    points that may tell a fitting next to a pipe (not the ground); ``seabed`` (a
    :class:`frontends.laser.pipe_shape.Seabed`, or None off a natural seabed): the tests a segment
    lying on the seabed must pass, and where fitting evidence is looked for along such a pipe.
    Returns merged pipe segments.

    Two masks: ``free`` points may still be inliers; ``seedable`` points may still seed hypotheses.
    A model that yields a pipe consumes its inliers; one that does not (an object's curved part, a
    bad fit) only stops seeding from them, so a pipe sharing points with it can still be found.
    """
    n = len(points)
    rng = np.random.default_rng(cfg.seed)
    free = np.ones(n, bool)
    seedable = np.ones(n, bool) if seedable is None else np.array(seedable, bool)
    max_failures = cfg.max_failures  # until a pipe tells how rare pipes are among the seeds
    sq = row_dot(points, points)
    pipes: list[Pipe] = []
    objects_only: list[Pipe] = []  # short held runs for the object stage (held_short_objects)
    failures = 0
    cand = None  # the free points, narrowed when a pipe takes some
    stale = False
    for _ in range(3 * cfg.max_pipes):
        if len(pipes) >= cfg.max_pipes or failures >= max_failures:
            break
        seeds = (seedable & free).nonzero()[0]
        if len(seeds) < cfg.min_points:
            break
        if cand is None:
            cand = _Points(points, normals, free.nonzero()[0])
        elif stale:  # free points only ever leave: keep the rest (and their products)
            cand, stale = cand.subset(free[cand.index]), False
        i = rng.choice(seeds, cfg.hypotheses)
        c, a, r, ok = patch_hypotheses(points, normals, grid, i, free, cfg)
        if not ok.any():
            seedable[i] = False  # these seeds give no cylinder at all (flat or ragged surface)
            failures += 1
            continue
        i, c, a, r = i[ok], c[ok], a[ok], r[ok]
        m = len(cand.index)
        pick = slice(None) if m <= cfg.score_sample else rng.choice(m, cfg.score_sample, replace=False)
        sample = cand.index[pick]
        if isinstance(pick, slice):
            in_sample = inlier_mask(cand.p, cand.n, c, a, r, cfg, cand.sq, cand.pn)
        else:
            in_sample = inlier_mask(
                cand.p.take(pick, axis=0), cand.n.take(pick, axis=0), c, a, r, cfg, cand.sq[pick], cand.pn[pick]
            )
        scores = in_sample.sum(axis=1)
        # A seed whose cylinder the data do not support (fewer than min_points inliers expected)
        # seeds no more: the pool shrinks to the points still worth trying, and the search ends
        # when it is empty rather than after max_failures wasted rounds.
        supported = scores * m / len(sample) >= cfg.min_points
        seedable[i[~supported]] = False
        # Refine the best hypothesis; if its fit leaves the radius range, the next best (up to 3).
        refined = None
        tried = np.argsort(scores)[::-1][:3]
        if supported[tried[0]]:
            for h in tried:
                refined = _refine(cand, c[h], a[h], r[h], cfg)
                if refined is not None:
                    break
        if refined is None:
            # No pipe here: stop seeding from these hypotheses' seeds and sampled inliers.
            seedable[i[tried]] = False
            seedable[sample[in_sample[tried].any(axis=0)]] = False
            failures += 1
            continue
        cb, ab, rb, idx, held = refined
        found = _cut_into_segments(points, normals, sq, cb, ab, rb, idx, cfg, foreign, seabed, rays, held)
        if any(pipe.objects_only for pipe in found):  # kept aside: the search goes on as without them
            short = [pipe for pipe in found if pipe.objects_only]
            found = [pipe for pipe in found if not pipe.objects_only]
            objects_only += short if seabed is None else [pipe for pipe in short if seabed.accept(pipe, colour=False)]
        if seabed is not None:
            found = seabed.accept_runs(found)
        for pipe in found:
            free[pipe.inliers] = False
            stale = True
        pipes += found
        seedable[idx] = False
        if found:
            share = min(len(pipe.inliers) for pipe in found) / max(int((seedable & free).sum()) + len(idx), 1)
            max_failures = max(max_failures, failure_budget(share, cfg))
        failures = 0 if found else failures + 1
    if rays is not None:  # no segment the sensor sees through (all tested at once)
        pipes = [p for p, ok in zip(pipes, rays.solid(pipes, cfg)) if ok]
        if objects_only:
            objects_only = [p for p, ok in zip(objects_only, rays.solid(objects_only, cfg)) if ok]
    pipes = merge_duplicates(pipes, points, normals, cfg)
    return pipes + _apart(objects_only, pipes)


def over_a_line(pipes: list[Pipe], lying: np.ndarray, up: np.ndarray, cfg: PipeConfig) -> np.ndarray:
    """Per segment: a fitting's part standing over a pipe line on the seabed, fitted as a short pipe
    across it (a valve's lever, handle or gear head): shorter than ``over_line_max_radii`` radii of
    a longer segment of the scan lying on the ground (``lying``; not one that only serves the
    objects), at least ``over_line_angle_deg`` across it, and the closest approach of its axis to
    that segment's axis line lies within its own extent, within that length of the longer one's
    ends, and above that line (along the unit ``up``) by more than the two radii: a pipe joining the
    line at a tee meets its axis there. (Only over a line lying on the ground: pipes on racks, as in
    the tank, cross over each other.)"""
    n = len(pipes)
    out = np.zeros(n, bool)
    if cfg.over_line_max_radii <= 0 or n < 2:
        return out
    cos_max = np.cos(np.radians(cfg.over_line_angle_deg))
    for i, s in enumerate(pipes):
        for line, lies in zip(pipes, lying):
            if line is s or not lies or line.objects_only or line.length <= s.length:
                continue
            reach = cfg.over_line_max_radii * line.radius
            b = float(s.axis @ line.axis)
            if s.length >= reach or abs(b) > cos_max:
                continue
            w = s.p - line.p
            d, e = float(s.axis @ w), float(line.axis @ w)
            ts, tl = (b * e - d) / (1.0 - b * b), (e - b * d) / (1.0 - b * b)
            if not (-line.radius <= ts <= s.length + line.radius and -reach <= tl <= line.length + reach):
                continue
            height = float((s.p + ts * s.axis - line.p - tl * line.axis) @ up)
            if height > s.radius + line.radius:
                out[i] = True
                break
    return out


def merge_duplicates(pipes: list[Pipe], points, normals, cfg: PipeConfig) -> list[Pipe]:
    """Merge segments of one pipe found twice: near-parallel, coaxial, overlapping or nearly touching.

    A fitting a little wider than its pipe (a socket, a tee's run) can be found as a short segment
    of its own, coaxial with the pipes it joins and touching them: merged, it would bridge the
    fitting. So the union is cut again at the fittings its own profile shows (the bumps of
    :func:`split_at_fittings`, now seen against the pipe on both sides) when one of the two is
    short enough to be a fitting: the runs replace the pair, the fitting's points are left to the
    objects.
    """
    pipes = list(pipes)
    for _ in range(4 * len(pipes) + 8):  # every step removes a segment or a fitting's points
        if len(pipes) < 2:
            break
        pair = _first_duplicate(pipes, cfg)
        if pair is None:
            break
        x, y = pair
        seg = np.union1d(pipes[x].inliers, pipes[y].inliers)
        merged = _make_pipe(points, normals, seg, pipes[x].axis, cfg)
        held = next((pp.radius for pp in (pipes[x], pipes[y]) if pp.radius_held), None)
        if held is not None and not (cfg.min_radius <= merged.radius <= cfg.max_radius):
            merged = _make_pipe(points, normals, seg, pipes[x].axis, cfg, held)  # still a narrow arc
        v = points.take(seg, axis=0) - merged.p
        t = v @ merged.axis
        residual = np.sqrt(np.maximum(row_dot(v, v) - t * t, 0.0)) - merged.radius
        runs = split_at_fittings(t, residual, np.zeros(0), cfg)
        dropped = np.ones(len(seg), bool)
        for run in runs:
            dropped[run] = False
        # Cut again only when one of the two may be a fitting (short): two long detections of one
        # pipe merge as they are.
        if not dropped.any() or min(pipes[x].length, pipes[y].length) > _MAX_FITTING:
            pipes[x] = merged
            del pipes[y]
            continue
        held = merged.radius if merged.radius_held else None
        pieces = [
            _make_pipe(points, normals, seg[run], merged.axis, cfg, held) for run in runs if len(run) >= cfg.min_points
        ]
        pieces = [pp for pp in pieces if pp.length >= cfg.min_detect_length]
        pipes = [pp for k, pp in enumerate(pipes) if k not in (x, y)] + pieces
    return pipes


def _first_duplicate(pipes: list[Pipe], cfg: PipeConfig) -> tuple[int, int] | None:
    """The first pair x < y (row-major) of duplicates, all pairs tested at once: B's axis within
    ``merge_angle_deg`` of A's, B's middle within ``merge_distance`` of A's axis, and B's interval
    on A's axis overlapping A's or less than ``merge_gap`` away."""
    A = np.array([p.axis for p in pipes])
    P = np.array([p.p for p in pipes])
    Q = np.array([p.q for p in pipes])
    L = np.array([p.length for p in pipes])
    parallel = np.abs(A @ A.T) >= np.cos(np.radians(cfg.merge_angle_deg))
    off = 0.5 * (P + Q)[None, :, :] - P[:, None, :]  # [x, y]: B's middle from A's start
    along = np.einsum("xyk,xk->xy", off, A)
    lateral = np.linalg.norm(off - along[:, :, None] * A[:, None, :], axis=2)
    tp = np.einsum("xyk,xk->xy", P[None, :, :] - P[:, None, :], A)
    tq = np.einsum("xyk,xk->xy", Q[None, :, :] - P[:, None, :], A)
    gap = np.maximum(np.maximum(np.minimum(tp, tq) - L[:, None], -np.maximum(tp, tq)), 0.0)
    dup = np.triu(parallel & (lateral <= cfg.merge_distance) & (gap <= cfg.merge_gap), 1)
    hits = np.argwhere(dup)
    return (int(hits[0, 0]), int(hits[0, 1])) if len(hits) else None
