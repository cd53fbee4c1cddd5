"""Plane removal by region growing over normals (Vallicrosa et al. 2021, §3.1).

Regions grow between neighbouring points whose normals are within ``max_normal_angle_deg`` of each
other; as in PCL's region growing, only smooth points (curvature below ``growth_curvature``)
propagate a region, so growth starts from the least-curved points and stops at edges and pipes.
Smooth must also mean surface-like (planarity λ1/λ2 ≥ ``min_planarity``): along a pipe thinner than
the neighbourhood, the neighbourhood is a flat ribbon facing the sensor, and a lattice of such
ribbons in one vertical plane would otherwise make a "wall".
It is computed at once: the graph of 26-neighbouring voxels keeps the edges that pass both tests and
``scipy.sparse.csgraph.connected_components`` labels the regions (no loop over points).

Each region is then flat or structure by its mean curvature (threshold 0.025). Flat alone is not
enough: an object's top face is flat too, and removing every flat region would remove it (the
coplanar failure of plain RANSAC that the paper describes, in another guise). So a flat region is a
*tank plane* only if it is also large (second principal extent ≥ ``min_plane_extent`` or area ≥ ``min_plane_area``, the
area counted as points × voxel² since the cloud is voxel-downsampled); smaller flat
regions join a tank plane only if they lie on it (same normal, centroid on the plane). Finally the
curved border strip where a plane meets a pipe or an object (its neighbourhoods mix both surfaces)
joins the plane point by point, only if adjacent to it and within ``plane_distance`` of it; the
pipe and object points a few millimetres above the plane are not adjacent-and-on-plane and stay.
Conversely a region that crept from the floor onto pipes (along a thin pipe a 50-point
neighbourhood is a flat ribbon facing the sensor, like the floor) gives back every point farther
than ``max_plane_offset`` from its plane.
All in the sensor frame {S}.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from frontends.laser.config import PlaneConfig
from frontends.laser.grid import single_threaded_blas
from frontends.laser.preprocess import Preprocessed


@dataclass
class PlaneResult:
    """``structure`` (M,) bool: points kept; ``region`` (M,) region label of every point;
    ``plane_of`` (M,) index of the tank plane a removed point belongs to (−1 if kept);
    ``planes`` list of (unit normal, offset d) with n·x = d, in {S}."""

    structure: np.ndarray
    region: np.ndarray
    plane_of: np.ndarray
    planes: list[tuple[np.ndarray, float]] = field(default_factory=list)


def grow_regions(pre: Preprocessed, cfg: PlaneConfig) -> np.ndarray:
    """Region label of every point (connected components of the smooth, normal-consistent graph)."""
    m = len(pre.points)
    smooth = (pre.curvature < cfg.growth_curvature) & (pre.planarity >= cfg.min_planarity)
    rows = np.flatnonzero(smooth)
    nb = pre.neighbours.take(rows, axis=0)[:, 1:]  # the 26-neighbours of smooth points (−1: empty cell)
    # Each undirected edge once (j > i: also drops the −1s), between smooth points only.
    keep = np.flatnonzero((nb > rows[:, None]) & np.append(smooth, False)[nb])
    # (gathers at the mask's flat positions: several times faster than boolean indexing)
    i = rows.take(keep // nb.shape[1])
    j = nb.take(keep)
    cos_min = np.cos(np.radians(cfg.max_normal_angle_deg))
    # (rows gathered by np.take: several times faster than fancy indexing of N×3 arrays)
    ok = np.flatnonzero(np.einsum("ij,ij->i", pre.normals.take(i, axis=0), pre.normals.take(j, axis=0)) >= cos_min)
    i, j = i.take(ok), j.take(ok)
    # The edges come sorted by i: the graph in CSR directly (no COO conversion in connected_components).
    indptr = np.concatenate(([0], np.cumsum(np.bincount(i, minlength=m))))
    graph = csr_matrix((np.ones(len(j)), j, indptr), shape=(m, m))
    _, labels = connected_components(graph, directed=False)
    return labels


def _region_moments(points: np.ndarray, labels: np.ndarray, n_labels: int):
    """Count, centroid and covariance of every region, from bincount sums (coordinates centred)."""
    origin = points.mean(axis=0)
    x = points - origin
    cnt = np.bincount(labels, minlength=n_labels).astype(float)
    s = np.stack([np.bincount(labels, x[:, a], n_labels) for a in range(3)], axis=1)
    ss = np.empty((n_labels, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            ss[:, a, b] = ss[:, b, a] = np.bincount(labels, x[:, a] * x[:, b], n_labels)
    c = np.maximum(cnt, 1.0)
    mean = s / c[:, None]
    cov = ss / c[:, None, None] - mean[:, :, None] * mean[:, None, :]
    return cnt, mean + origin, cov


@single_threaded_blas
def remove_planes(pre: Preprocessed, cfg: PlaneConfig, voxel_size: float) -> PlaneResult:
    """Label regions, find the tank planes among them and mark every point kept as structure."""
    m = len(pre.points)
    if m == 0:
        e = np.zeros(0, bool)
        return PlaneResult(e, np.zeros(0, np.int64), np.zeros(0, np.int64))
    labels = grow_regions(pre, cfg)
    n_labels = labels.max() + 1
    cnt, centroid, cov = _region_moments(pre.points, labels, n_labels)
    mean_kappa = np.bincount(labels, pre.curvature, n_labels) / np.maximum(cnt, 1)

    cand = np.flatnonzero((cnt >= 10) & (mean_kappa < cfg.flat_curvature))
    plane_of_region = np.full(n_labels, -1, np.int64)
    planes: list[tuple[np.ndarray, float]] = []
    if len(cand):
        evals, evecs = np.linalg.eigh(cov[cand])
        extent = np.sqrt(12.0 * np.clip(evals[:, 1], 0, None))
        normals = evecs[:, :, 0]
        big = (extent >= cfg.min_plane_extent) | (cnt[cand] * voxel_size**2 >= cfg.min_plane_area)
        for r, nrm in zip(cand[big], normals[big]):  # a handful of tank planes per scan
            plane_of_region[r] = len(planes)
            planes.append((nrm, float(nrm @ centroid[r])))
        if planes:
            # Small flat regions lying on a tank plane (the floor cut up by pipes and shadows) join it.
            P = np.array([p[0] for p in planes])
            D = np.array([p[1] for p in planes])
            small = cand[~big]
            cos_n = np.abs(normals[~big] @ P.T)  # regions × planes
            dist = np.abs(centroid[small] @ P.T - D)
            on = (cos_n >= np.cos(np.radians(cfg.max_normal_angle_deg))) & (dist <= cfg.plane_distance)
            has = on.any(axis=1)
            plane_of_region[small[has]] = np.argmin(np.where(on, dist, np.inf), axis=1)[has]

    plane_of = plane_of_region[labels]
    if planes:
        plane_of, planes = _keep_on_plane(pre.points, plane_of, planes, cfg.max_plane_offset)
    if planes and cfg.border_hops > 0:
        plane_of = _join_border(pre, plane_of, planes, cfg)
    return PlaneResult(plane_of < 0, labels, plane_of, planes)


def _keep_on_plane(points, plane_of, planes, max_offset: float):
    """Guard against leaks: a tank plane keeps only the points of its regions that lie on it.

    Along a thin pipe a 50-point neighbourhood is a ribbon, flat and facing the sensor like the
    floor, so a region can creep from the floor onto pipes. The planes are refitted to the points
    within ``max_offset`` of them, and every point farther away goes back to the structure.
    """
    P = np.array([p[0] for p in planes])
    D = np.array([p[1] for p in planes])
    idx = np.flatnonzero(plane_of >= 0)
    on, which = points.take(idx, axis=0), plane_of[idx]  # the points of the planes, and whose
    dist = np.abs(np.einsum("ij,ij->i", on, P[which]) - D[which])
    good = dist <= max_offset
    refit = []
    for k in range(len(planes)):  # a handful of planes
        pts = on.take(np.flatnonzero(good & (which == k)), axis=0)
        if len(pts) < 3:
            refit.append(planes[k])
            continue
        c = pts.mean(axis=0)
        n = np.linalg.eigh(np.cov((pts - c).T))[1][:, 0]
        n = n if n @ P[k] >= 0 else -n
        refit.append((n, float(n @ c)))
    P = np.array([p[0] for p in refit])
    D = np.array([p[1] for p in refit])
    dist = np.abs(np.einsum("ij,ij->i", on, P[which]) - D[which])
    plane_of = plane_of.copy()
    plane_of[idx[dist > max_offset]] = -1
    return plane_of, refit


def _join_border(pre: Preprocessed, plane_of: np.ndarray, planes, cfg: PlaneConfig) -> np.ndarray:
    """Grow the tank planes, a hop at a time, over adjacent points that lie on them."""
    nbr = pre.neighbours[:, 1:]
    P = np.array([p[0] for p in planes])
    D = np.array([p[1] for p in planes])
    plane_of = np.append(plane_of, -1)  # the slot of an empty neighbour (index −1)
    for _ in range(cfg.border_hops):
        free = np.flatnonzero(plane_of[:-1] < 0)
        if len(free) == 0:
            break
        nb_plane = plane_of[nbr[free]]  # free × 26
        touching = (nb_plane >= 0).any(axis=1)
        free, nb_plane = free[touching], nb_plane[touching]  # only points next to a plane may join
        adjacent = (nb_plane[:, :, None] == np.arange(len(P))).any(axis=1)  # free × planes
        dist = np.abs(pre.points[free] @ P.T - D)
        dist = np.where(adjacent, dist, np.inf)  # at a corner, either adjacent plane may take it
        best = dist.argmin(axis=1)
        join = dist[np.arange(len(free)), best] <= cfg.plane_distance
        if not join.any():
            break
        plane_of[free[join]] = best[join]
    return plane_of[:-1]
