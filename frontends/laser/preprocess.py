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


def local_geometry(
    points: np.ndarray, knn: np.ndarray, rows: np.ndarray | None = None, viewpoint=(0.0, 0.0, 0.0)
) -> tuple[np.ndarray, np.ndarray]:
    """Normals (towards ``viewpoint``) and curvature λ0/(λ0+λ1+λ2) of the neighbourhoods ``knn``
    (R×k indices into ``points``) of the points ``rows`` (all points when None).

    The neighbourhood covariances are formed in one batch: neighbours are centred on their query
    point (float32 is then exact enough), the six second moments summed over the neighbourhood.
    """
    centre = points if rows is None else points[rows]
    q = (points[knn] - centre[:, None, :]).astype(np.float32)  # R×k×3
    k = knn.shape[1]
    mean = q.mean(axis=1)
    cov = np.empty((len(centre), 3, 3), np.float32)
    for a in range(3):
        for b in range(a, 3):
            cov[:, a, b] = cov[:, b, a] = (q[:, :, a] * q[:, :, b]).sum(axis=1) / k - mean[:, a] * mean[:, b]
    evals, evecs = np.linalg.eigh(cov)  # ascending
    evals = np.clip(evals, 0.0, None)
    curvature = evals[:, 0] / np.maximum(evals.sum(axis=1), 1e-20)
    normals = evecs[:, :, 0].astype(np.float64)
    flip = np.einsum("ij,ij->i", normals, np.asarray(viewpoint) - centre) < 0
    normals[flip] *= -1.0
    return normals, curvature.astype(np.float64)


def statistical_inliers(knn_dist2: np.ndarray, neighbors: int, std_ratio: float) -> np.ndarray:
    """open3d's statistical outlier rule: mean distance to the neighbours ≤ global mean + ratio × std."""
    d = np.sqrt(knn_dist2[:, 1 : neighbors + 1]).mean(axis=1)
    return d <= d.mean() + std_ratio * d.std()


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
    good = statistical_inliers(d2, pre.outlier_neighbors, pre.outlier_std_ratio)
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
    normals, curvature = local_geometry(vox, knn[:, : planes.neighbors])
    return Preprocessed(vox, raw_to_voxel, knn, d2, normals, curvature)


def _empty(raw_to_voxel) -> Preprocessed:
    z3 = np.zeros((0, 3))
    return Preprocessed(z3, raw_to_voxel, np.zeros((0, 1), np.int64), np.zeros((0, 1)), z3, np.zeros(0))
