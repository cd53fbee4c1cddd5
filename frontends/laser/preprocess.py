"""Pre-processing of a laser scan, and the neighbourhood geometry every later stage shares.

All points are in the sensor frame {S} (m), the sensor at the origin. The stages:

1. range crop (``min_range`` ≤ |p| ≤ ``max_range``);
2. voxel downsampling to the centroid of each occupied voxel (a :class:`VoxelGrid`), keeping for
   every raw point the index of its voxel (so a segment of the downsampled cloud maps back to the
   raw points);
3. the voxels' 26-neighbourhoods, looked up in the grid (no k-d tree: a 50-NN search of a 20k-voxel
   scan alone took 0.15 s), used three times: outlier removal (26-connected clusters of fewer
   than ``outlier_min_voxels`` voxels are stray returns, and so are clusters of a few tens of voxels
   holding about one point each: marine snow in front of a camera), normals and curvature, and the
   region-growing graph.

Normals and curvature come from the covariance of a neighbourhood grown ``normal_hops`` steps
through occupied neighbours: the moments of every voxel summed by ``normal_hops`` products with the
26-neighbourhood adjacency matrix. That is a cube of (2h+1)³ cells weighted towards its centre (the
number of paths of h steps), restricted to cells connected to the centre: at 3 cm and 3 steps, ~50
voxels of a plane — the paper's 50-point neighbourhood — for ~10 % of the cost of the 50-NN search.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from frontends.laser.config import PlaneConfig, PreprocessConfig
from frontends.laser.eigen import eigen3, eigen3_parts
from frontends.laser.grid import VoxelGrid, adjacency_of, single_threaded_blas


@dataclass
class Preprocessed:
    """The downsampled, cleaned cloud with its local geometry.

    ``points`` (M×3, float64, {S}); ``raw_to_voxel`` (N_raw,) index into ``points`` or −1 for raw
    points cropped or removed; ``neighbours`` (M×27) the occupied voxels of each voxel's 3×3×3
    neighbourhood (itself first, −1 where empty); ``normals`` (M×3, unit, oriented towards the
    sensor); ``curvature`` (M,) κ = λ0/(λ0+λ1+λ2) of the neighbourhood covariance.
    """

    points: np.ndarray
    raw_to_voxel: np.ndarray
    neighbours: np.ndarray
    normals: np.ndarray
    curvature: np.ndarray
    planarity: np.ndarray  # λ1/λ2 of the neighbourhood: ≈ 1 on a surface, ≪ 1 along a thin pipe
    counts: np.ndarray | None = None  # (M,) raw points in each voxel


def voxel_downsample(points: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Centroids of the occupied voxels and, for each input point, the index of its voxel."""
    grid = VoxelGrid(points, voxel)
    return grid.points, grid.inverse


def knn_search(points: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """k nearest neighbours (self included, first) with open3d's nanoflann-backed search."""
    k = min(k, len(points))
    t = o3d.core.Tensor(np.ascontiguousarray(points, dtype=np.float32))
    nns = o3d.core.nns.NearestNeighborSearch(t)
    nns.knn_index()
    idx, d2 = nns.knn_search(t, k)
    return idx.numpy().astype(np.int64), d2.numpy()


def neighbourhood_covariances(points: np.ndarray, knn: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
    """Covariance (R×3×3) of each neighbourhood ``knn`` (R×k indices into ``points``).

    All neighbourhoods at once as one sparse product: with A the R×N neighbour-incidence matrix and
    F the per-point moments, A·F sums every neighbourhood.
    """
    r, k = knn.shape
    A = csr_matrix((np.ones(r * k), knn.ravel(), np.arange(0, r * k + 1, k)), shape=(r, len(points)))
    return _covariances_from_sums(A @ _moments(points))


def _moments(points: np.ndarray, centre: np.ndarray | None = None) -> np.ndarray:
    """Per point (1, x, y, z, xx, xy, xz, yy, yz, zz) of coordinates centred on the cloud, or on
    ``centre`` when given (float64, so E[xxᵀ] − E[x]E[x]ᵀ loses nothing at these scales)."""
    x = points - (points.mean(axis=0) if centre is None else centre)
    return np.column_stack([np.ones(len(x)), x, x[:, [0, 0, 0, 1, 1, 2]] * x[:, [0, 1, 2, 1, 2, 2]]])


def _covariances_from_sums(S: np.ndarray) -> np.ndarray:
    """R×3×3 covariances from summed (weighted) moments (R×10, see :func:`_moments`)."""
    return _assemble(_covariance_parts(S))


def _covariance_parts(S: np.ndarray) -> np.ndarray:
    """The six distinct entries (xx, xy, xz, yy, yz, zz) of R covariances from summed (weighted)
    moments (R×10, see :func:`_moments`), as a 6×R array: what :func:`eigen3_parts` takes, without
    assembling R×3×3 matrices (12 strided column writes, most of the cost here)."""
    S = S[:, 1:] / np.maximum(S[:, :1], 1e-300)
    mean = S[:, :3]
    sec = S[:, 3:] - mean[:, [0, 0, 0, 1, 1, 2]] * mean[:, [0, 1, 2, 1, 2, 2]]
    return np.ascontiguousarray(sec.T)


def _assemble(parts: np.ndarray) -> np.ndarray:
    """R×3×3 symmetric matrices from their 6×R distinct entries (see :func:`_covariance_parts`)."""
    cov = np.empty((parts.shape[1], 3, 3))
    for col, (a, b) in enumerate([(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]):
        cov[:, a, b] = cov[:, b, a] = parts[col]
    return cov


@single_threaded_blas
def hop_covariance_parts(
    points: np.ndarray,
    adjacency: csr_matrix,
    hops: int,
    rows: np.ndarray | None = None,
    centre: np.ndarray | None = None,
) -> np.ndarray:
    """Covariances (6×R distinct entries, see :func:`_covariance_parts`) of each point's
    neighbourhood grown ``hops`` steps over ``adjacency`` (M×M, self-links included), every point
    weighted by its number of paths from the centre; for the points ``rows`` (all when None).
    ``centre``: see :func:`_moments`."""
    S = _moments(points, centre)
    for _ in range(hops):
        S = adjacency @ S
    return _covariance_parts(S if rows is None else S.take(rows, axis=0))


def hop_covariances(points, adjacency, hops, rows=None, centre=None) -> np.ndarray:
    """The covariances of :func:`hop_covariance_parts` as R×3×3 matrices."""
    return _assemble(hop_covariance_parts(points, adjacency, hops, rows, centre))


def smallest_eigen(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Smallest eigenvalue and its unit eigenvector of symmetric 3×3 matrices (see :func:`eigen3`)."""
    lam0, _, _, v = eigen3(cov)
    return lam0, v


def local_geometry(
    points: np.ndarray, knn: np.ndarray, rows: np.ndarray | None = None, viewpoint=(0.0, 0.0, 0.0)
) -> tuple[np.ndarray, np.ndarray]:
    """Normals (towards ``viewpoint``) and curvature κ = λ0/(λ0+λ1+λ2) of the neighbourhoods ``knn``
    (R×k indices into ``points``) of the points ``rows`` (all points when None)."""
    normals, curvature, _ = local_shape(points, knn, rows, viewpoint)
    return normals, curvature


def local_shape(points, knn, rows=None, viewpoint=(0.0, 0.0, 0.0)):
    """Normals, curvature and planarity λ1/λ2 of the neighbourhoods (see :func:`local_geometry`).

    Planarity tells a surface patch (≈ 1) from a line-like one (≪ 1): along a pipe thinner than the
    neighbourhood, the neighbourhood is a flat ribbon whose curvature alone looks like a plane's.
    """
    centre = points if rows is None else points[rows]
    return shape_of(neighbourhood_covariances(points, knn), centre, viewpoint)


@single_threaded_blas
def shape_of(cov: np.ndarray, centre: np.ndarray, viewpoint=(0.0, 0.0, 0.0)):
    """Normals (towards ``viewpoint``), curvature and planarity of neighbourhood covariances."""
    return _shape(*eigen3(cov), centre, viewpoint)


@single_threaded_blas
def shape_of_parts(parts: np.ndarray, centre: np.ndarray, viewpoint=(0.0, 0.0, 0.0)):
    """:func:`shape_of` of covariances given by their 6×R distinct entries (see :func:`eigen3_parts`)."""
    return _shape(*eigen3_parts(parts), centre, viewpoint)


def _shape(lam0, lam1, lam2, normals, centre, viewpoint):
    trace = lam0 + lam1 + lam2
    curvature = np.where(trace > 0, lam0 / np.maximum(trace, 1e-300), 0.0)
    planarity = np.where(lam2 > 0, lam1 / np.maximum(lam2, 1e-300), 0.0)
    flip = np.einsum("ij,ij->i", normals, np.asarray(viewpoint) - centre) < 0
    normals[flip] *= -1.0
    return normals, curvature, planarity


def small_clusters(
    adjacency: csr_matrix, min_voxels: int, counts: np.ndarray | None = None, sparse: tuple[int, float] = (0, 0.0)
) -> np.ndarray:
    """Mask of the voxels in 26-connected clusters of fewer than ``min_voxels`` (stray returns), or,
    with the raw ``counts`` per voxel, of fewer than ``sparse[0]`` voxels holding ``sparse[1]`` raw
    points or fewer on average (a cloud of particles: a point per voxel, where a surface near
    enough to make such a cluster has several)."""
    _, label = connected_components(adjacency, directed=False)
    size = np.bincount(label)
    stray = size < min_voxels
    if counts is not None and sparse[0] > 0:
        mean = np.bincount(label, weights=counts) / size
        stray |= (size < sparse[0]) & (mean <= sparse[1])
    return stray[label]


@single_threaded_blas
def preprocess(points: np.ndarray, pre: PreprocessConfig, planes: PlaneConfig) -> Preprocessed:
    """Crop, downsample, remove outliers and compute the local geometry of a raw scan (N×3, {S})."""
    raw = np.asarray(points, dtype=np.float64)
    rng = np.sqrt(np.einsum("ij,ij->i", raw, raw))
    keep = np.flatnonzero(np.isfinite(rng) & (rng >= pre.min_range) & (rng <= pre.max_range))
    raw_to_voxel = np.full(len(raw), -1, np.int64)
    if len(keep) == 0:
        return _empty(raw_to_voxel)
    grid = VoxelGrid(raw.take(keep, axis=0), pre.voxel_size)  # (np.take: ~4x faster than raw[keep] here)
    vox, inv, nb = grid.points, grid.inverse, grid.neighbours(1)
    A = adjacency_of(nb)
    stray = small_clusters(A, pre.outlier_min_voxels, grid.counts, (pre.sparse_cluster_voxels, pre.sparse_mean_points))
    all_vox, kept, counts = vox, None, grid.counts
    if stray.any():
        # A whole cluster goes, so no kept voxel had a removed one as neighbour: re-index only.
        # The adjacency stays as it is: the neighbourhoods of kept voxels never reach a stray one.
        good = ~stray
        kept = np.flatnonzero(good)
        # (−1 appended: an empty neighbour, −1, reads it; rows gathered by np.take: the same rows as
        # boolean indexing, faster)
        remap = np.append(np.where(good, np.cumsum(good) - 1, -1), -1)
        inv = remap[inv]
        vox, nb, counts = vox.take(kept, axis=0), nb.take(kept, axis=0), counts.take(kept)
        nb = remap.take(nb)
    if len(vox) == 0:
        return _empty(raw_to_voxel)
    raw_to_voxel[keep] = inv
    # (moments centred on the kept voxels' mean, as if the strays had never been there)
    cov = hop_covariance_parts(all_vox, A, planes.normal_hops, rows=kept, centre=vox.mean(axis=0))
    normals, curvature, planarity = shape_of_parts(cov, vox)
    return Preprocessed(vox, raw_to_voxel, nb, normals, curvature, planarity, counts)


def _empty(raw_to_voxel) -> Preprocessed:
    z3 = np.zeros((0, 3))
    return Preprocessed(z3, raw_to_voxel, np.zeros((0, 27), np.int64), z3, np.zeros(0), np.zeros(0), np.zeros(0, int))
