"""Clustered Viewpoint Feature Histogram (CVFH), Aldoma et al. 2011, as PCL's ``CVFHEstimation``.

One VFH per stable smooth region of the cloud: points of high curvature (edges, noise) are
dropped, normals are re-estimated on the rest, the rest is split into smooth regions (neighbours
closer than ``cluster_tolerance`` whose normals differ by less than ``eps_angle``), and for every
region of at least ``min_points`` points a VFH of the *whole* cloud is computed with the region's
centroid and mean normal. With no such region, one VFH of the whole cloud.

Follows PCL ``features/impl/cvfh.hpp`` (read, re-implemented). PCL's defaults for a 5 mm leaf:
curvature threshold 0.03, cluster tolerance and normal radius 3 leaves (15 mm), angle 0.125 rad,
50 points. Deviations: PCL grows each region from a seed by a breadth-first search over
neighbours whose normals are close to the current point's — the regions are exactly the
connected components of that neighbour graph, which is how they are computed here (one
``query_pairs`` and a sparse connected-components pass); the VFH is ours (see ``vfh.py``), with
normalised bins.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from frontends.laser.recognition.normals import normals_and_curvature
from frontends.laser.recognition.vfh import vfh_from_normals


def smooth_regions(
    cloud: np.ndarray, normals: np.ndarray, *, tolerance: float, eps_angle: float, min_points: int
) -> list[np.ndarray]:
    """Index arrays of the smooth regions (≥ ``min_points``) of a cloud with unit normals."""
    pairs = cKDTree(cloud).query_pairs(tolerance, output_type="ndarray")
    if len(pairs):
        cosang = np.einsum("ij,ij->i", normals[pairs[:, 0]], normals[pairs[:, 1]])
        pairs = pairs[np.arccos(np.clip(cosang, -1.0, 1.0)) < eps_angle]
    n = len(cloud)
    graph = (
        coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        if len(pairs)
        else coo_matrix((n, n))
    )
    _, labels = connected_components(graph, directed=False)
    sizes = np.bincount(labels)
    return [np.flatnonzero(labels == lab) for lab in np.flatnonzero(sizes >= min_points)]


def stable_regions(
    cloud: np.ndarray,
    viewpoint: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
    *,
    leaf_size: float = 0.005,
    curvature_threshold: float = 0.03,
    eps_angle: float = 0.125,
    min_points: int = 50,
    k: int = 20,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cloud's normals (N×3, k nearest, facing ``viewpoint``) and its stable smooth regions'
    centroids (R×3) and unit mean normals (R×3); R may be 0.

    ``leaf_size`` (m) sets the neighbourhood scale: the cluster tolerance and the normal radius
    of the low-curvature points are 3 leaves, as PCL's defaults.
    """
    pts = np.asarray(cloud, dtype=np.float64)
    normals, curvature = normals_and_curvature(pts, viewpoint, k=k)
    keep = np.flatnonzero(curvature <= curvature_threshold)
    centroids, mean_normals = np.empty((0, 3)), np.empty((0, 3))
    if len(keep) >= min_points:
        sub = pts[keep]
        sub_normals, _ = normals_and_curvature(sub, viewpoint, k=k, radius=3 * leaf_size)
        regions = smooth_regions(sub, sub_normals, tolerance=3 * leaf_size, eps_angle=eps_angle, min_points=min_points)
        if regions:
            centroids = np.array([sub[idx].mean(axis=0) for idx in regions])
            mean_normals = np.array([sub_normals[idx].mean(axis=0) for idx in regions])
            mean_normals /= np.linalg.norm(mean_normals, axis=1, keepdims=True)
    return normals, centroids, mean_normals


def cvfh(
    cloud: np.ndarray,
    viewpoint: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
    **region_params,
) -> np.ndarray:
    """CVFH descriptors (R×308, one per stable region, at least one) of an N×3 cloud seen from
    ``viewpoint`` (same frame). ``region_params`` are those of :func:`stable_regions`."""
    pts = np.asarray(cloud, dtype=np.float64)
    normals, centroids, mean_normals = stable_regions(pts, viewpoint, **region_params)
    if len(centroids) == 0:
        return vfh_from_normals(pts, normals, viewpoint)[None, :]
    return np.stack(
        [vfh_from_normals(pts, normals, viewpoint, centroid=c, mean_normal=n) for c, n in zip(centroids, mean_normals)]
    )
