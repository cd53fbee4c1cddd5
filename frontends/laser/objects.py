"""Object segmentation at pipe extremities, with connectivity (Vallicrosa et al. 2021, §3.3).

Objects (valves, elbows, tees...) sit where pipes end. Pipe ends that face each other on one line
(an in-line part between them) or whose axes cross just beyond them (a junction) meet at one
object, and the directions the pipes leave it in give its connectivity: 1 = one pipe, 2 = two
collinear pipes, 3 = two orthogonal pipes, 4 = three or more (a fitting's body fitted as a short
pipe between collinear pipes adds ends, not directions). A lone pipe end is an object only if
something is there, other than the pipe running on; on the seabed, a lying pipe's lone end against
another lying pipe's flank is a junction (a tee's branch against its run). The object is cropped from the structure points
(pipe inliers excluded) with an oriented box in a frame (pipe direction, across, up): the
"mushroom" (body box plus a handle box above it) when the object has one connection or two
collinear ones — a valve's handle stands above its body — and the body box alone otherwise. The
largest Euclidean cluster of the crop is the object's cloud (at a lone end: the largest touching the
end, around its axis, with the largest reaching back to it along the pipe, a handle); objects sharing half of their clouds
are one (the one on the most and longest pipes). Where pipes cross but their fits took in the
fitting's surface (an elbow continues its pipes' cylinders), the crop keeps the pipe points; two
lone ends whose crops overlap and whose axes meet a little farther away than ``max_port_distance``
are one object.

Its position is taken from the pipe geometry, which is more accurate than the centroid of a
one-sided view of the surface: the intersection of the pipe axes (two orthogonal or three pipes),
the middle of the gap between two collinear pipes, or for one pipe the point on its axis midway
along the object's extent. Its covariance follows from which of these it is (a crossing of axes is
good to a few mm, the middle of a gap or of an extent along the pipe to 2-3 cm), as measured on the
simulated tank (``ObjectConfig``). Everything is in the sensor frame {S}, metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from frontends.laser.config import ObjectConfig
from frontends.laser.grid import VoxelGrid, adjacency_of, row_dot, single_threaded_blas
from frontends.laser.pipes import Pipe


@dataclass
class SegmentedObject:
    """An object segment: ``position`` (m, {S}), 3×3 ``covariance``, ``indices`` of its points in the
    structure cloud, ``directions`` unit pipe axes leaving it, ``configuration`` 1–4, ``pipes``
    indices of the attached pipes in the pipe list."""

    position: np.ndarray
    covariance: np.ndarray
    indices: np.ndarray
    directions: np.ndarray
    configuration: int
    pipes: tuple[int, ...]


def configuration_of(directions: np.ndarray, collinear_angle_deg: float) -> int:
    """The paper's connectivity configuration from the pipe directions leaving an object."""
    n = len(directions)
    if n <= 1:
        return 1
    if n >= 3:
        return 4
    return 2 if directions[0] @ directions[1] <= -np.cos(np.radians(collinear_angle_deg)) else 3


def box_frame(direction: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Columns (along the pipe, across, up), with up made orthogonal to the pipe."""
    x = direction / np.linalg.norm(direction)
    z = up - (up @ x) * x
    if np.linalg.norm(z) < 1e-6:  # vertical pipe: any horizontal "up" will do
        z = np.cross(x, [1.0, 0, 0]) if abs(x[0]) < 0.9 else np.cross(x, [0, 1.0, 0])
    z = z / np.linalg.norm(z)
    # y = z × x written out in Python floats (the same products as np.cross, which costs ~10x more)
    (x0, x1, x2), (z0, z1, z2) = x.tolist(), z.tolist()
    y0, y1, y2 = z1 * x2 - z2 * x1, z2 * x0 - z0 * x2, z0 * x1 - z1 * x0
    return np.array([[x0, y0, z0], [x1, y1, z1], [x2, y2, z2]])


def in_box(points: np.ndarray, center: np.ndarray, R: np.ndarray, size) -> np.ndarray:
    inside = np.abs((points - center) @ R) <= np.asarray(size) / 2.0
    return inside[:, 0] & inside[:, 1] & inside[:, 2]  # (np.all(axis=1) loops per row of 3)


def _line_intersection(points: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Least-squares point nearest to the lines (points[k], dirs[k])."""
    P = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]
    return np.linalg.solve(P.sum(axis=0), np.einsum("kij,kj->i", P, points))


def _largest_cluster(points: np.ndarray, radius: float, anchored: np.ndarray | None = None) -> np.ndarray:
    """Indices of the largest cluster of points linked through neighbouring cells of a grid of
    ``radius``/2 (points in 26-adjacent cells are linked: they are 0–3.5 radius/2 apart, gaps up to
    ~radius are bridged), a hashed grid rather than a k-d tree's pair search. With ``anchored``
    (a mask of the points), the largest of the clusters holding one of those points (none: empty)."""
    return _largest_clusters([points], radius, [anchored])[0]


def _largest_clusters(clouds: list[np.ndarray], radius: float, anchored: list[np.ndarray | None]) -> list[np.ndarray]:
    """:func:`_largest_cluster` of every cloud (with its ``anchored`` mask or None), all in one grid.

    Each cloud's cells are laid out as in a grid of its own (integer cells from its own minimum),
    shifted along x by whole 8-cell blocks with a gap of two cells between clouds, so the grid's
    cells, hence the connected components' labels, come cloud after cloud in the order each
    would have alone, and the largest cluster (the first of equal ones) is the same. On a scan's
    ~16 objects this is one grid and one connected-components pass instead of one per object.
    """
    out: list[np.ndarray | None] = [None] * len(clouds)
    todo = []
    for k, (P, anc) in enumerate(zip(clouds, anchored)):
        if len(P) < 2 and anc is None:
            out[k] = np.arange(len(P))
        elif len(P) == 0:
            out[k] = np.arange(0)
        else:
            todo.append(k)
    if not todo:
        return out
    size, keys, x0 = radius / 2, [], 0
    for k in todo:
        key = np.floor(np.asarray(clouds[k], dtype=np.float64) / size).astype(np.int64)
        key -= np.array([key[:, j].min() for j in range(3)])  # (as VoxelGrid: column by column)
        key[:, 0] += x0
        x0 = -(-(int(key[:, 0].max()) + 3) // 8) * 8  # next block at least two empty cells away
        keys.append(key)
    grid = VoxelGrid(np.concatenate([clouds[k] for k in todo]), size, keys=np.concatenate(keys))
    _, lab = connected_components(adjacency_of(grid.neighbours(1)), directed=False)
    weight = np.bincount(lab, weights=grid.counts)
    start = 0
    for k in todo:
        n = len(clouds[k])
        labs = lab[grid.inverse[start : start + n]]  # a cloud's labels are consecutive: lo..hi
        start += n
        lo = int(labs.min())
        sizes = weight[lo : int(labs.max()) + 1]
        if anchored[k] is not None:
            allowed = np.zeros(len(sizes), bool)
            allowed[labs[anchored[k]] - lo] = True
            if not allowed.any():
                out[k] = np.arange(0)
                continue
            sizes = np.where(allowed, sizes, -1.0)
        out[k] = np.flatnonzero(labs == sizes.argmax() + lo)
    return out


def along_and_off_axis(points: np.ndarray, origin: np.ndarray, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position along the unit ``axis`` from ``origin`` and distance from that axis of every point."""
    x = points - origin
    t = x @ axis
    return t, np.sqrt(np.maximum(row_dot(x, x) - t * t, 0.0))


def stands_over(
    points: np.ndarray, end: np.ndarray, out: np.ndarray, up: np.ndarray, radius: float, reach: float, cfg: ObjectConfig
) -> int:
    """How many of an object's ``points`` stand over the pipe ending at ``end`` (outward unit
    ``out``, ``up`` the unit up across it): above its top (by ``own_margin``), over its axis (within
    its radius plus ``own_margin`` across) and from ``own_beyond`` before the end to ``reach``
    beyond it. A fitting on a pipe lying on the seabed rises over it, where the pipe enters it (a
    valve's body, stem and handle); the seabed's clutter around a pipe's end (sand, stones) lies
    beside it, or farther on."""
    x = points - end
    t, h = x @ out, x @ up
    across = np.sqrt(np.maximum(row_dot(x, x) - t * t - h * h, 0.0))
    over = (h > radius + cfg.own_margin) & (across <= radius + cfg.own_margin)
    return int((over & (t >= -cfg.own_beyond) & (t <= reach)).sum())


def sleeve_over(
    points: np.ndarray,
    end: np.ndarray,
    out: np.ndarray,
    up: np.ndarray,
    pipe: Pipe,
    all_points: np.ndarray,
    reach: float,
    cfg: ObjectConfig,
) -> bool:
    """Whether an object's ``points`` hold, over the pipe ending at ``end`` (outward unit ``out``,
    ``up`` the unit up across it), a sleeve on its line a little wider than the pipe: of the points
    above its axis and over it (within its radius plus ``own_margin`` across), from ``own_beyond`` to
    ``reach`` beyond the end, a 4 cm stretch (two 2 cm bins, at least ``min_own_points`` points)
    whose median distance from the axis stands above the pipe's own radial level (as
    :func:`wider_stretch`: by ``tail_tolerance`` and ``tail_sigmas`` × the noise of that median) but
    by no more than ``own_margin`` (higher is :func:`stands_over`'s), the distances' scatter about it
    within ``tail_tolerance`` or ``own_sigmas`` × the pipe's own (a surface coaxial with the pipe),
    its points on both sides of the axis, at least the pipe's radius apart across (over its top).
    A socket or a tee's run on a pipe lying on the seabed is such a sleeve, a few millimetres proud
    of the pipe: it does not rise over it by ``own_margin``; the seabed's clutter at a pipe's end
    lies beside it, and sand over a buried pipe's end stands at no constant distance from its axis,
    nor over the pipe's top."""
    if len(pipe.inliers) == 0:
        return False
    x = points - end
    t, h = x @ out, x @ up
    side = x @ np.cross(out, up)  # across, signed (up is square to the pipe: box_frame's)
    rad = np.sqrt(np.maximum(row_dot(x, x) - t * t, 0.0))
    over = (h > 0) & (np.abs(side) <= pipe.radius + cfg.own_margin) & (t > cfg.own_beyond) & (t <= reach)
    if not over.any():
        return False
    level, sigma = surface_level(pipe, all_points)
    t, offset, side = t[over] - cfg.own_beyond, rad[over] - level, side[over]
    scatter = max(cfg.tail_tolerance, cfg.own_sigmas * sigma)
    stretch = (t / _TAIL_BIN).astype(np.int64)
    for s in range(int(stretch.max()) + 1):
        w = (stretch == s) | (stretch == s + 1)
        n = int(w.sum())
        if n < max(_TAIL_BIN_POINTS, cfg.min_own_points):
            continue
        med = float(np.median(offset[w]))
        need = max(cfg.tail_tolerance, cfg.tail_sigmas * 1.2533 * sigma / np.sqrt(n))
        across = side[w]
        if (
            need < med <= cfg.own_margin
            and 1.4826 * float(np.median(np.abs(offset[w] - med))) <= scatter
            and across.min() < 0.0 < across.max()
            and float(np.ptp(across)) >= pipe.radius
        ):
            return True
    return False


def own_points(points: np.ndarray, end: np.ndarray, out: np.ndarray, radius: float, cfg: ObjectConfig) -> int:
    """How many of an object's ``points`` are its own rather than the pipe's that ends at ``end``
    (outward unit ``out``, pipe ``radius``): off the pipe's cylinder by more than ``own_margin``
    (a body, a branch or a handle wider than the pipe) or beyond its end by more than
    ``own_beyond`` (a socket, a part in line). A pipe's end cap, or a pipe leaving the view,
    has none."""
    t, rad = along_and_off_axis(points, end, out)
    return int(((rad > radius + cfg.own_margin) | (t > cfg.own_beyond)).sum())


_MIN_CENTRE_POINTS = 5  # fewest points off the cylinder that place a lone end's object (else all its points do)


def lone_end_depth(points: np.ndarray, end: np.ndarray, out: np.ndarray, radius: float, cfg: ObjectConfig) -> float:
    """How far beyond a lone pipe ``end`` (outward unit ``out``, pipe ``radius``) the centre of the
    object made of ``points`` lies: the middle (2nd-98th percentile) of the extent along the pipe of
    its points standing more than ``centre_margin`` outside the pipe's cylinder (from ``own_beyond``
    before the end on), or, when fewer than 5 do (a socket only a little wider than its pipe), of all
    its points beyond the end. What stands off the pipe (a valve's body and handle, an elbow's or a
    tee's other port) is centred on the fitting whatever its class; the whole extent is not for a
    fitting that turns: its centre, where its ports' axes cross, lies one port radius before its far
    wall, not midway from the pipe's end to it."""
    t, rad = along_and_off_axis(points, end, out)
    off = t[(rad > radius + cfg.centre_margin) & (t > -cfg.own_beyond)]
    if len(off) >= _MIN_CENTRE_POINTS:
        lo, hi = np.percentile(off, [2, 98])
        return float(0.5 * (lo + hi))
    lo, hi = np.percentile(t, [2, 98])
    return float(0.5 * (max(lo, 0.0) + hi))


_TAIL_BIN = 0.02  # m along the axis: the profile beyond a lone end is judged per stretch of this length
_TAIL_BIN_POINTS = 5  # ... with at least this many points (fewer everywhere: all of them as one)


def radial_level(pipe: Pipe, points: np.ndarray) -> float:
    """The median distance of ``pipe``'s inliers (rows of ``points``) from its axis: its surface as
    the scan sees it (the fitted radius is the prior's where one is set)."""
    return surface_level(pipe, points)[0]


def surface_level(pipe: Pipe, points: np.ndarray) -> tuple[float, float]:
    """(:func:`radial_level`, the scatter of the inliers' distances about it: 1.4826 × their median
    absolute deviation, the scan's noise on that pipe)."""
    rad = along_and_off_axis(points.take(pipe.inliers, axis=0), pipe.p, pipe.axis)[1]
    level = float(np.median(rad))
    return level, 1.4826 * float(np.median(np.abs(rad - level)))


def pipe_continues(
    points: np.ndarray, end: np.ndarray, out: np.ndarray, pipe: Pipe, all_points: np.ndarray, cfg: ObjectConfig
) -> bool:
    """Whether an object's ``points`` at a lone end of ``pipe`` (outward unit ``out``) are that pipe
    running on past its fitted ``end`` (its sparse far part not taken as inliers), or its own end
    (an end cap, an open bore, the last centimetres cut off by noise), rather than a fitting: fewer
    than ``min_own_points`` off its cylinder (by ``own_margin``, or ``own_sigmas`` × the scatter of
    the pipe's inliers where that is more: at 1 cm of range noise, 7 % of a bare pipe's points lie
    1.5 cm off it, so a 10 cm tail of a free end showed a "body"), and nowhere beyond the end wider than the pipe: no
    4 cm stretch (two of 2 cm, at least 5 points) whose median distance from the axis stands above
    the pipe's own radial level (the median distance of its inliers, in ``all_points``) by more than
    ``tail_tolerance`` and ``tail_sigmas`` × the noise of that median (1.2533 σ / √n, σ the scatter
    of the pipe's inliers about their level). A socket or a port is wider than its pipe, even with
    an undetected pipe running on behind it; an elbow or a body leaves the cylinder. Points nearer
    the axis than the pipe's surface (its end cap, the inside of an open end) are no fitting."""
    if len(pipe.inliers) == 0:
        return False
    t, rad = along_and_off_axis(points, end, out)
    beyond = t > cfg.own_beyond
    if not beyond.any():
        return False
    level, sigma = surface_level(pipe, all_points)
    if int((rad > pipe.radius + max(cfg.own_margin, cfg.own_sigmas * sigma)).sum()) >= cfg.min_own_points:
        return False
    return not wider_stretch(t[beyond] - cfg.own_beyond, rad[beyond] - level, sigma, cfg)


def wider_stretch(t: np.ndarray, offset: np.ndarray, sigma: float, cfg: ObjectConfig) -> bool:
    """Whether points at ``t`` (≥ 0) along an axis, ``offset`` outward from a pipe's surface, hold
    a stretch of two 2 cm bins (at least ``_TAIL_BIN_POINTS`` points) whose median offset exceeds
    ``tail_tolerance`` and ``tail_sigmas`` × 1.2533 ``sigma`` / √n (the noise of a median of n)."""
    stretch = (t / _TAIL_BIN).astype(np.int64)
    for s in range(int(stretch.max()) + 1 if len(stretch) else 0):
        w = (stretch == s) | (stretch == s + 1)
        n = int(w.sum())
        if n >= _TAIL_BIN_POINTS:
            need = max(cfg.tail_tolerance, cfg.tail_sigmas * 1.2533 * sigma / np.sqrt(n))
            if float(np.median(offset[w])) > need:
                return True
    return False


def collinear_stub(points: np.ndarray, end: np.ndarray, out: np.ndarray, radius: float, cfg: ObjectConfig) -> bool:
    """Whether a second pipe leaves the object at a lone pipe end on the far side, in line with the
    first: ``points`` (not pipe inliers) on that pipe's cylinder (``radius``) continued beyond the
    object (between ``stub_start`` and ``stub_reach`` from ``end``, outward unit ``out``), at least
    ``stub_points`` of them over at least ``stub_bins`` bins of 2 cm along the axis. A pipe too
    short to be detected (or partly hidden) still shows as such a stub; an object at the end of a
    single pipe has nothing there (its open port is a bore just beyond the end, nearer than
    ``stub_start``)."""
    x = points - end
    t = x @ out
    sel = (t >= cfg.stub_start) & (t <= cfg.stub_reach)
    x, t = x[sel], t[sel]
    rad = np.sqrt(np.maximum(row_dot(x, x) - t * t, 0.0))
    t = t[np.abs(rad - radius) <= cfg.stub_tolerance]
    if len(t) < cfg.stub_points:
        return False
    per_bin = np.bincount(((t - cfg.stub_start) / 0.02).astype(np.int64))
    return int((per_bin >= 2).sum()) >= cfg.stub_bins


def join_ends(ends: np.ndarray, out: np.ndarray, owner: np.ndarray, cfg: ObjectConfig) -> np.ndarray:
    """Group pipe ends that meet at one object (label per end).

    Two ends of different pipes meet at an in-line object when they face each other on one line
    (outward directions opposite within ``collinear_angle_deg``, lateral offset below
    ``line_tolerance``, gap below ``max_inline_gap``), and at a junction when their axes cross
    (closest approach below ``line_tolerance``) within ``max_port_distance`` beyond both ends.
    """
    n = len(ends)
    cos_c = np.cos(np.radians(cfg.collinear_angle_deg))
    i, j = np.triu_indices(n, 1)
    keep = owner[i] != owner[j]
    i, j = i[keep], j[keep]
    oi, oj = out[i], out[j]
    d = ends[j] - ends[i]
    dot = np.einsum("ij,ij->i", oi, oj)
    # in-line: facing each other on one line
    gap = np.einsum("ij,ij->i", d, oi)
    lateral = np.linalg.norm(d - gap[:, None] * oi, axis=1)
    inline = (
        (dot <= -cos_c) & (gap > -cfg.line_tolerance) & (gap <= cfg.max_inline_gap) & (lateral <= cfg.line_tolerance)
    )
    # junction: the two axes cross just beyond both ends
    den = np.maximum(1.0 - dot**2, 1e-12)
    e_i = np.einsum("ij,ij->i", oi, d)
    e_j = np.einsum("ij,ij->i", oj, d)
    s_i = (e_i - dot * e_j) / den  # along oi from ends[i]
    s_j = (dot * e_i - e_j) / den  # along oj from ends[j]
    miss = np.linalg.norm(ends[i] + s_i[:, None] * oi - ends[j] - s_j[:, None] * oj, axis=1)
    lo, hi = -cfg.line_tolerance, cfg.max_port_distance
    cross = (np.abs(dot) < cos_c) & (miss <= cfg.line_tolerance) & (s_i >= lo) & (s_i <= hi) & (s_j >= lo) & (s_j <= hi)
    link = inline | cross
    graph = coo_matrix((np.ones(link.sum(), np.int8), (i[link], j[link])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def _groups(group: np.ndarray) -> list[np.ndarray]:
    """Members (pipe-end indices) of every group label."""
    order = np.argsort(group, kind="stable")
    return np.split(order, np.flatnonzero(np.diff(group[order])) + 1)


class _Site(NamedTuple):
    """Where the object at a group of pipe ends is looked for."""

    center: np.ndarray
    R: np.ndarray  # box frame: along the first pipe, across, up
    members: np.ndarray  # pipe-end indices
    dirs: np.ndarray  # distinct pipe axes leaving the object (the first: the first member's)
    ends: np.ndarray  # of the members
    config: int
    flank: tuple[int, ...] = ()  # pipes on whose flank the (lone) member's end stands (:func:`flank_site`)


def distinct_directions(directions: np.ndarray, collinear_angle_deg: float) -> np.ndarray:
    """The directions (unit, K×3), each left out when within ``collinear_angle_deg`` of one already
    kept (in the same sense; greedy, in order), the first kept first."""
    cos_c = np.cos(np.radians(collinear_angle_deg))
    keep: list[int] = []
    for k, d in enumerate(directions):
        if all(d @ directions[j] < cos_c for j in keep):
            keep.append(k)
    return directions[keep]


def _outermost_end(ends: np.ndarray, dirs: np.ndarray, d: np.ndarray, collinear_angle_deg: float) -> np.ndarray:
    """Of the ends whose pipes leave in direction ``d`` (within the angle), the farthest along it."""
    same = np.flatnonzero(dirs @ d >= np.cos(np.radians(collinear_angle_deg)))
    return ends[same[np.argmax(ends[same] @ d)]]


def _local_up(up: np.ndarray, ground, at: np.ndarray) -> np.ndarray:
    """The ground's normal under ``at`` where the ground model knows it, else ``up``."""
    n = ground.normal(at) if ground is not None else None
    return up if n is None else n


def _site(members, ends, out, guess, up, cfg: ObjectConfig) -> _Site:
    dirs = -out[members]
    e = ends[members]
    # Connectivity counts the directions pipes leave in, not the pipe ends: a fitting's straight
    # body fitted as a short pipe between two collinear pipes adds two ends on their line (a tee
    # seen without its branch: four ends, two directions). Counted as a junction, its centre would
    # be the crossing of parallel lines, undetermined along them.
    distinct = distinct_directions(dirs, cfg.collinear_angle_deg)
    config = configuration_of(distinct, cfg.collinear_angle_deg)
    if config == 2:  # the middle of the gap between the pipes' ends (not a body piece's between them)
        center = 0.5 * sum(_outermost_end(e, dirs, d, cfg.collinear_angle_deg) for d in distinct)
    elif config in (3, 4):
        center = _line_intersection(e, dirs)
    else:
        center = guess[members[0]]
    return _Site(center, box_frame(dirs[0], up), members, distinct, e, config)


def flank_site(site: _Site, pipes: list[Pipe], lying: np.ndarray | None, up: np.ndarray, cfg: ObjectConfig) -> _Site:
    """A lone end of a pipe lying on the seabed that touches the flank of another lying pipe: the
    end's axis, extended by ``attach_distance`` beyond it, enters that pipe's cylinder (passes
    within its radius of its axis, square to it within ``collinear_angle_deg``: a tee's branch, the
    end not past that axis by more than ``line_tolerance``), where that pipe runs on both ways by at least the end's
    pipe radius (its whole port on the flank, away from the run's ends: those meet in
    :func:`join_ends`). That is a junction (a tee's branch against its run, which the run's fit
    took in): the branch's direction and the run's both ways, placed where the axes cross; not a
    lone end, whose seabed test (:func:`stands_over`, :func:`sleeve_over`) asks for a body rising
    over the branch where a tee's run lies beyond it. The seabed's stones and sand do not hold a
    pipe's end against another pipe's flank. Reported pipes only (not ``objects_only``: a short
    held run may be a stone's top). Any other site is returned as it is."""
    if site.config != 1 or lying is None or len(site.members) != 1:
        return site
    a = int(site.members[0] // 2)
    branch = pipes[a]
    if not lying[a] or branch.objects_only:
        return site
    e, o = site.ends[0], -site.dirs[0]  # the end and its outward direction
    sin_c = np.sin(np.radians(cfg.collinear_angle_deg))  # |cos| of the angle to the run, at most
    best = None
    for b, run in enumerate(pipes):
        if b == a or not lying[b] or run.objects_only:
            continue
        dot = float(o @ run.axis)
        if abs(dot) > sin_c:
            continue
        d = run.p - e
        e_o, e_a = float(o @ d), float(run.axis @ d)
        den = 1.0 - dot * dot
        s = (e_o - dot * e_a) / den  # along o from the end, to the closest approach
        u = (dot * e_o - e_a) / den  # along the run's axis from its p
        miss = float(np.linalg.norm(e + s * o - run.p - u * run.axis))
        if miss > run.radius or s < -cfg.line_tolerance:
            continue
        entry = s - np.sqrt(run.radius**2 - miss**2) / np.sqrt(den)  # where the axis enters the run's surface
        if entry > cfg.attach_distance or not (branch.radius <= u <= run.length - branch.radius):
            continue
        if best is None or entry < best[0]:
            best = (entry, b)
    if best is None:
        return site
    run = pipes[best[1]]
    center = _line_intersection(np.array([e, run.p]), np.array([o, run.axis]))
    dirs = np.array([-o, run.axis, -run.axis])
    config = configuration_of(dirs, cfg.collinear_angle_deg)
    return _Site(center, box_frame(dirs[0], up), site.members, dirs, site.ends, config, (best[1],))


def _crop(X: np.ndarray, rows: np.ndarray, site: _Site, cfg: ObjectConfig) -> np.ndarray:
    """The rows of ``X`` (among ``rows``) in the site's box, and for one connection or two collinear
    ones in the handle box above it (the mushroom: a valve's handle stands above its body)."""
    body, handle = np.asarray(cfg.body_size), np.asarray(cfg.handle_size)
    Xr = X.take(rows, axis=0)
    mask = in_box(Xr, site.center, site.R, body)
    if site.config in (1, 2):
        mask |= in_box(Xr, site.center + site.R[:, 2] * (body[2] + handle[2]) / 2, site.R, handle)
    return rows[mask]


_SHARED = 0.5  # two crops or clouds sharing this fraction of the smaller one's points are one object's


def _shared_points(index_sets: list[np.ndarray], n_points: int):
    """Sparse matrix of how many points each pair of index sets (into ``n_points``) shares."""
    sizes = np.array([len(c) for c in index_sets])
    rows = np.repeat(np.arange(len(index_sets)), sizes)
    cols = np.concatenate(index_sets) if len(rows) else rows
    C = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(index_sets), n_points)).tocsr()
    return (C @ C.T).tocsr()


def _merge_overlapping(
    sites: list[_Site], crops: list[np.ndarray], out, owner, n_points: int, cfg: ObjectConfig
) -> list[list[int]]:
    """Groups of sites that are one object: a lone pipe end that did not join the others (a pipe
    cut short before its fitting, so its end lies farther than ``max_port_distance``) and another
    site (lone or not) whose crops share at least half of the smaller one's points, and whose
    ends meet by the test of :func:`join_ends` with twice the port distance."""
    sizes = np.array([len(c) for c in crops])
    shared = _shared_points(crops, n_points).tocoo()
    lone = np.array([site.config == 1 for site in sites])
    small = np.minimum(sizes[shared.row], sizes[shared.col])
    cand = (
        (shared.row < shared.col)
        & (lone[shared.row] | lone[shared.col])
        & (shared.data >= _SHARED * np.maximum(small, 1))
    )
    relaxed = cfg.model_copy(update={"max_port_distance": 2 * cfg.max_port_distance})

    def meet(a: int, b: int) -> bool:
        m = np.concatenate([sites[a].members, sites[b].members])
        lab = join_ends(np.concatenate([sites[a].ends, sites[b].ends]), out[m], owner[m], relaxed)
        return bool(np.isin(lab[: len(sites[a].members)], lab[len(sites[a].members) :]).any())

    link = [(a, b) for a, b in zip(shared.row[cand], shared.col[cand]) if meet(a, b)]
    g = coo_matrix((np.ones(len(link)), tuple(np.array(link, int).reshape(-1, 2).T)), shape=(len(crops),) * 2)
    _, label = connected_components(g, directed=False)
    return [list(m) for m in _groups(label)]


def position_covariance(config: int, R: np.ndarray, cfg: ObjectConfig, held_run: bool = False) -> np.ndarray:
    """3×3 covariance of an object position found with connectivity ``config``, in {S}: the σ of
    ``cfg`` in the box frame ``R`` (along the pipe, across, up), rotated. ``held_run``: the object
    sits at the end of a short held-radius run given to the object stage only (``objects_only``,
    ``pipes.held_short_objects``): such a run is a narrow arc at the view's edge, whose end need not
    be the fitting's port, so along the pipe the position is known only to within the body box
    (σ of a uniform over ``body_size[0]``, at least the configuration's own)."""
    if config in (3, 4):
        sig = np.full(3, cfg.junction_sigma)
    else:
        along, across = cfg.inline_sigma if config == 2 else cfg.end_sigma
        if held_run:
            along = max(along, cfg.body_size[0] / np.sqrt(12.0))
        sig = np.array([along, across, across])
    return (R * sig**2) @ R.T


@single_threaded_blas
def segment_objects(
    points: np.ndarray,
    pipes: list[Pipe],
    up: np.ndarray,
    cfg: ObjectConfig,
    exclude: np.ndarray | None = None,
    ground=None,
    lying: np.ndarray | None = None,
    seen_beyond=None,
) -> list[SegmentedObject]:
    """Objects at the ends of ``pipes`` among the structure ``points`` (N×3, {S}); ``up`` is the
    unit up direction (against gravity) in {S}. ``exclude`` (mask): points that belong to no object
    (the ground); ``ground`` (a :class:`~frontends.laser.ground.GroundModel` or None): where it
    knows the ground under an object, the ground's normal is the object's "up" (on a slope, a valve
    stands square to the seabed, not to gravity). ``lying`` (bool per pipe, or None): the pipes
    lying on the ground, where the seabed's clutter (sand, stones) surrounds a pipe's end, so an
    object at a lone end of one, or between two in line, must stand over them (``stands_over``). ``seen_beyond`` (a callable
    (point, radius) → bool, or None): whether the scan saw the space at a point; a lone end beyond
    which it saw nothing within ``attach_distance`` (the view's edge, a hole in it) is where the
    view stops: an object there would be cut by it, and placed by half of its extent."""
    if not pipes:
        return []
    is_pipe = np.zeros(len(points), bool) if exclude is None else np.array(exclude, bool)
    for p in pipes:
        is_pipe[p.inliers] = True
    rest = np.flatnonzero(~is_pipe)
    X = points.take(rest, axis=0)
    body = np.asarray(cfg.body_size)

    # Pipe ends: position, outward direction (away from the pipe), guessed object centre.
    ends = np.array([e for p in pipes for e in (p.p, p.q)])
    out = np.array([o for p in pipes for o in (-p.axis, p.axis)])
    owner = np.repeat(np.arange(len(pipes)), 2)
    guess = ends + out * body[0] / 2
    group = join_ends(ends, out, owner, cfg)

    handle = np.asarray(cfg.handle_size)
    sites = []
    for members in _groups(group):
        site_up = _local_up(up, ground, guess[members[0]])
        sites.append(flank_site(_site(members, ends, out, guess, site_up, cfg), pipes, lying, site_up, cfg))
    # Points within reach of each site (all sites at once), then the exact boxes on those only.
    reach = np.linalg.norm(np.maximum(body, handle) / 2 + [0, 0, body[2] / 2 + handle[2] / 2])
    centres = np.array([site.center for site in sites])
    d2 = row_dot(X, X)[:, None] - 2.0 * X @ centres.T + (centres * centres).sum(axis=1)[None, :]
    crops = []
    for site, d2_site in zip(sites, d2.T):
        crop = rest[_crop(X, np.flatnonzero(d2_site <= reach**2), site, cfg)]
        if len(crop) < cfg.min_points and site.config >= 3:
            # Pipes meet here, so something joins them: a fitting whose surface the pipes' fits
            # took in (an elbow continues its pipes' cylinders). Crop it with the pipe points.
            crop = _crop(points, np.arange(len(points)), site, cfg)
        crops.append(crop)
    found = []  # (site, crop, its points, anchor masks) of every object with enough points
    for group in _merge_overlapping(sites, crops, out, owner, len(points), cfg):
        site = sites[group[0]]
        crop = crops[group[0]]
        if len(group) > 1:
            members = np.concatenate([sites[k].members for k in group])
            site = _site(members, ends, out, guess, _local_up(up, ground, guess[members[0]]), cfg)
            site = next((sites[k] for k in group if sites[k].flank), site)  # a junction on a flank stays one
            crop = np.unique(np.concatenate([crops[k] for k in group]))
        if len(crop) < cfg.min_points:
            continue
        P = points.take(crop, axis=0)  # (np.take: several times faster than points[crop])
        # A lone pipe end is no evidence by itself (the pipe may leave the view or be hidden):
        # the object must touch the end (its cluster anchored there) and have points of its own
        # beyond the pipe's surface. Its cloud adds the largest cluster reaching back to the end
        # along the pipe: a valve's handle over its body, its stem not seen.
        anchors = (None, None)
        if site.config == 1:
            t, rad = along_and_off_axis(P, site.ends[0], -site.dirs[0])
            anchors = ((t <= cfg.attach_distance) & (rad <= cfg.attach_distance), t <= cfg.attach_distance)
        found.append((site, crop, P, anchors))
    clusters = _largest_clusters([f[2] for f in found], cfg.cluster_distance, [f[3][0] for f in found])
    lone = [k for k, f in enumerate(found) if f[0].config == 1]
    reaching = dict(
        zip(lone, _largest_clusters([found[k][2] for k in lone], cfg.cluster_distance, [found[k][3][1] for k in lone]))
    )
    objects: list[SegmentedObject] = []
    for k, ((site, crop, _, _), cluster) in enumerate(zip(found, clusters)):
        center, dirs, e = site.center, site.dirs, site.ends
        if site.config == 1:
            pipe = pipes[site.members[0] // 2]
            P = points.take(crop[cluster], axis=0)  # the object's base, at the end: is it one?
            if own_points(P, e[0], -dirs[0], pipe.radius, cfg) < cfg.min_own_points:
                continue
            if pipe_continues(P, e[0], -dirs[0], pipe, points, cfg):
                continue
            if seen_beyond is not None and not seen_beyond(e[0] - dirs[0] * cfg.attach_distance, pipe.radius):
                continue
            cluster = np.union1d(cluster, reaching[k])
        crop = crop[cluster]
        if site.config == 2 and len(site.members) == 2 and gap_is_pipe(points, crop, site, pipes, cfg):
            continue
        if lying is not None and all(lying[m // 2] for m in site.members) and site.config <= 2:
            # on the seabed: something must rise over the pipe where it ends (config 1), or in the
            # gap between the two ends (config 2), and the scan must have seen that place
            pipe = pipes[site.members[0] // 2]
            # (a fitting starts at the end, or up to attach_distance beyond where the end is seen short)
            reach = float(np.ptp((e - e[0]) @ dirs[0])) + cfg.own_beyond
            if site.config == 1:
                reach = cfg.attach_distance + cfg.body_size[0] / 2
            P = points.take(crop, axis=0)
            if stands_over(P, e[0], -dirs[0], site.R[:, 2], pipe.radius, reach, cfg) < cfg.min_own_points and not (
                sleeve_over(P, e[0], -dirs[0], site.R[:, 2], pipe, points, reach, cfg)
            ):
                continue
            if seen_beyond is not None and not seen_beyond(center, pipe.radius):
                continue
        if len(crop) < cfg.min_points:
            continue
        config = site.config
        if site.config == 1:  # on the pipe's axis, at the middle of the object's own part
            radius = pipes[site.members[0] // 2].radius
            center = e[0] - dirs[0] * lone_end_depth(points.take(crop, axis=0), e[0], -dirs[0], radius, cfg)
            if collinear_stub(X, e[0], -dirs[0], pipes[site.members[0] // 2].radius, cfg):
                # a second pipe in line (not detected): two collinear connections; the position
                # is still the one found from the first pipe (and has its covariance)
                dirs, config = np.vstack([dirs, -dirs]), 2
        held_run = any(pipes[m // 2].objects_only for m in site.members)
        cov = position_covariance(site.config, site.R, cfg, held_run)
        pipe_ids = tuple(int(m // 2) for m in site.members) + site.flank
        objects.append(SegmentedObject(center, cov, crop, dirs, config, pipe_ids))
    return one_per_cluster(objects, pipes, len(points))


def gap_is_pipe(points: np.ndarray, crop: np.ndarray, site: _Site, pipes: list[Pipe], cfg: ObjectConfig) -> bool:
    """Whether an object's points (``crop`` of ``points``) at a site of exactly two collinear pipe
    ends facing each other are one pipe running on through the gap (cut in two by an occluder, a
    noisy fitting cut, a sparse stretch) rather than a part in line: fewer than ``min_own_points``
    off the pipes' common cylinder (by ``own_margin``; a valve's body and handle leave it), and the
    points between the two ends at the pipes' own radial level within ``tail_tolerance`` (a socket
    is wider than its pipes); a gap with no points in it (hidden) shows no part either. A gap shorter
    than ``min_inline_gap`` is the pipe stage's cut at a short bump of its surface (noise) unless
    ``min_inline_body`` points stand off the cylinder."""
    (e_a, e_b), (out_a, out_b) = site.ends[:2], -site.dirs[:2]
    axis = (out_a - out_b) / np.linalg.norm(out_a - out_b)
    mid = 0.5 * (e_a + e_b)
    t, rad = along_and_off_axis(points.take(crop, axis=0), mid, axis)
    two = [pipes[m // 2] for m in site.members[:2]]
    radius = float(np.mean([p.radius for p in two]))
    off = int((rad > radius + cfg.own_margin).sum())
    lo, hi = sorted(((e_a - mid) @ axis, (e_b - mid) @ axis))
    if hi - lo < cfg.min_inline_gap and off < cfg.min_inline_body:
        return True
    if off >= cfg.min_own_points:
        return False
    gap = (t >= lo) & (t <= hi)
    if gap.sum() < _TAIL_BIN_POINTS:
        return True
    level = float(np.mean([radial_level(p, points) for p in two]))
    return bool(abs(np.median(rad[gap]) - level) <= cfg.tail_tolerance)


def one_per_cluster(objects: list[SegmentedObject], pipes: list[Pipe], n_points: int) -> list[SegmentedObject]:
    """One object per cluster of points: of objects whose clouds share at least half of the smaller
    one's points, the one with the most attached pipes (a junction's crossing axes place it best),
    then the longest, then the larger cloud, is kept. A valve's own parts fitted as short pipes (its
    disc's rim, its stem, its lever) put more sites on its points, with their positions on those
    pieces' axes, 10-20 cm off."""
    if len(objects) < 2:
        return objects
    shared = _shared_points([o.indices for o in objects], n_points).toarray()  # a scan's few objects: dense
    sizes = np.array([len(o.indices) for o in objects])
    support = [sum(pipes[k].length for k in set(o.pipes)) for o in objects]
    n_pipes = [len(set(o.pipes)) for o in objects]
    order = sorted(range(len(objects)), key=lambda i: (-n_pipes[i], -support[i], -sizes[i], i))
    kept: list[int] = []
    for i in order:
        if not any(shared[i, j] >= _SHARED * min(sizes[i], sizes[j]) for j in kept):
            kept.append(i)
    return [objects[i] for i in sorted(kept)]
