"""Pre-processing of a laser scan, and the neighbourhood geometry every later stage shares.

All points are in the sensor frame {S} (m), the sensor at the origin. The stages:

1. range crop (``min_range`` ≤ |p| ≤ ``max_range``);
2. voxel downsampling to the centroid of each occupied voxel, keeping for every raw point the
   index of its voxel (so a segment of the downsampled cloud maps back to the raw points);
3. one k-nearest-neighbour search (open3d) on the downsampled cloud, used three times: statistical
   outlier removal (mean distance to the first ``outlier_neighbors``, as open3d's
   ``remove_statistical_outlier``), normals and curvature (the paper's 50-point neighbourhood),
   and the region-growing graph.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.sparse import csr_matrix

from frontends.laser.config import PlaneConfig, PreprocessConfig


@dataclass
class Preprocessed:
    """The downsampled, cleaned cloud with its local geometry.

    ``points`` (M×3, float64, {S}); ``raw_to_voxel`` (N_raw,) index into ``points`` or −1 for raw
    points cropped or removed; ``knn`` (M×k) neighbour indices (self first) and ``knn_dist2`` their
    squared distances; ``normals`` (M×3, unit, oriented towards the sensor); ``curvature`` (M,)
    κ = λ0/(λ0+λ1+λ2) of the neighbourhood covariance.
    """

    points: np.ndarray
    raw_to_voxel: np.ndarray
    knn: np.ndarray
    knn_dist2: np.ndarray
    normals: np.ndarray
    curvature: np.ndarray
    planarity: np.ndarray  # λ1/λ2 of the neighbourhood: ≈ 1 on a surface, ≪ 1 along a thin pipe


def voxel_downsample(points: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Centroids of the occupied voxels and, for each input point, the index of its voxel."""
    keys = np.floor(points / voxel).astype(np.int64)
    keys -= keys.min(axis=0)
    dims = keys.max(axis=0) + 1
    flat = (keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2]
    _, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)
    sums = np.stack([np.bincount(inverse, weights=points[:, j], minlength=len(counts)) for j in range(3)], axis=1)
    return sums / counts[:, None], inverse


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
    F the per-point moments (x, y, z, xx, xy, xz, yy, yz, zz) of coordinates centred on the cloud
    (float64, so E[xxᵀ] − E[x]E[x]ᵀ loses nothing at these scales), A·F sums every neighbourhood.
    """
    r, k = knn.shape
    n = len(points)
    A = csr_matrix((np.ones(r * k), knn.ravel(), np.arange(0, r * k + 1, k)), shape=(r, n))
    x = points - points.mean(axis=0)
    F = np.column_stack([x, x[:, [0, 0, 0, 1, 1, 2]] * x[:, [0, 1, 2, 1, 2, 2]]])
    S = (A @ F) / k
    mean = S[:, :3]
    sec = S[:, 3:] - mean[:, [0, 0, 0, 1, 1, 2]] * mean[:, [0, 1, 2, 1, 2, 2]]
    cov = np.empty((r, 3, 3))
    for col, (a, b) in enumerate([(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]):
        cov[:, a, b] = cov[:, b, a] = sec[:, col]
    return cov


def smallest_eigen(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Smallest eigenvalue and its unit eigenvector of symmetric 3×3 matrices (see :func:`eigen3`)."""
    lam0, _, _, v = eigen3(cov)
    return lam0, v


def eigen3(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Eigenvalues λ0 ≤ λ1 ≤ λ2 of symmetric 3×3 matrices and the unit eigenvector of λ0, in closed form.

    Eigenvalues by the trigonometric solution of the characteristic cubic (Smith 1961); the
    eigenvector is the largest cross product of two rows of (C − λ0·I), which span its complement.
    Much faster than a batched LAPACK call on tens of thousands of 3×3 matrices.
    """
    a00, a11, a22 = cov[:, 0, 0], cov[:, 1, 1], cov[:, 2, 2]
    a01, a02, a12 = cov[:, 0, 1], cov[:, 0, 2], cov[:, 1, 2]
    q = (a00 + a11 + a22) / 3.0
    p1 = a01**2 + a02**2 + a12**2
    p2 = (a00 - q) ** 2 + (a11 - q) ** 2 + (a22 - q) ** 2 + 2.0 * p1
    p = np.sqrt(np.maximum(p2 / 6.0, 1e-300))
    b00, b11, b22 = (a00 - q) / p, (a11 - q) / p, (a22 - q) / p
    b01, b02, b12 = a01 / p, a02 / p, a12 / p
    det = b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02)
    phi = np.arccos(np.clip(det / 2.0, -1.0, 1.0)) / 3.0
    lam0 = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    lam2 = q + 2.0 * p * np.cos(phi)
    lam1 = 3.0 * q - lam0 - lam2
    return np.maximum(lam0, 0.0), np.maximum(lam1, 0.0), np.maximum(lam2, 0.0), _null_vector(cov, lam0)


def _null_vector(cov, lam0):
    M = cov - lam0[:, None, None] * np.eye(3)
    c = np.stack([np.cross(M[:, 0], M[:, 1]), np.cross(M[:, 0], M[:, 2]), np.cross(M[:, 1], M[:, 2])], axis=1)
    norms = np.linalg.norm(c, axis=2)
    best = norms.argmax(axis=1)
    v = c[np.arange(len(cov)), best]
    nv = norms[np.arange(len(cov)), best]
    degenerate = nv < 1e-300  # isotropic or zero covariance: no preferred normal
    return np.where(degenerate[:, None], np.array([0.0, 0.0, 1.0]), v / np.where(degenerate, 1.0, nv)[:, None])


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
    cov = neighbourhood_covariances(points, knn)
    lam0, lam1, lam2, normals = eigen3(cov)
    trace = lam0 + lam1 + lam2
    curvature = np.where(trace > 0, lam0 / np.maximum(trace, 1e-300), 0.0)
    planarity = np.where(lam2 > 0, lam1 / np.maximum(lam2, 1e-300), 0.0)
    flip = np.einsum("ij,ij->i", normals, np.asarray(viewpoint) - centre) < 0
    normals[flip] *= -1.0
    return normals, curvature, planarity


def statistical_inliers(knn_dist2: np.ndarray, neighbors: int, std_ratio: float, min_distance: float = 0.0) -> np.ndarray:
    """open3d's statistical outlier rule: mean distance to the neighbours ≤ global mean + ratio × std
    (or ≤ ``min_distance``, an absolute floor under the statistical threshold)."""
    d = np.sqrt(knn_dist2[:, 1 : neighbors + 1]).mean(axis=1)
    return d <= max(d.mean() + std_ratio * d.std(), min_distance)


def preprocess(points: np.ndarray, pre: PreprocessConfig, planes: PlaneConfig) -> Preprocessed:
    """Crop, downsample, remove outliers and compute the local geometry of a raw scan (N×3, {S})."""
    raw = np.asarray(points, dtype=np.float64)
    rng = np.linalg.norm(raw, axis=1)
    keep = np.isfinite(rng) & (rng >= pre.min_range) & (rng <= pre.max_range)
    raw_to_voxel = np.full(len(raw), -1, np.int64)
    if keep.sum() == 0:
        return _empty(raw_to_voxel)
    vox, inv = voxel_downsample(raw[keep], pre.voxel_size)
    k = max(planes.neighbors, pre.outlier_neighbors + 1, planes.graph_neighbors + 1)
    if len(vox) <= k:
        return _empty(raw_to_voxel)
    knn, d2 = knn_search(vox, k)
    good = statistical_inliers(d2, pre.outlier_neighbors, pre.outlier_std_ratio, pre.outlier_min_distance)
    if not good.all():
        # Outliers are isolated, so they are rarely anyone's neighbour: drop their rows and, where
        # one appears in a neighbour list, put the query point itself there instead of searching again.
        remap = np.where(good, np.cumsum(good) - 1, -1)
        inv = remap[inv]
        vox, knn, d2 = vox[good], remap[knn[good]], d2[good]
        bad = knn < 0
        if bad.any():
            knn = np.where(bad, knn[:, :1], knn)
            d2 = np.where(bad, 0.0, d2)
    raw_to_voxel[keep] = inv
    normals, curvature, planarity = local_shape(vox, knn[:, : planes.neighbors])
    return Preprocessed(vox, raw_to_voxel, knn, d2, normals, curvature, planarity)


def _empty(raw_to_voxel) -> Preprocessed:
    z3 = np.zeros((0, 3))
    return Preprocessed(z3, raw_to_voxel, np.zeros((0, 1), np.int64), np.zeros((0, 1)), z3, np.zeros(0), np.zeros(0))
