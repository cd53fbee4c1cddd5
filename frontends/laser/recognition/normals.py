"""Surface normals and curvature of a point cloud, as PCL's ``NormalEstimation``.

The normal of a point is the eigenvector of the smallest eigenvalue of the covariance of its
neighbourhood, flipped to face the viewpoint; the curvature (surface variation) is
λ0 / (λ0 + λ1 + λ2). Neighbourhoods come from Open3D's KD-tree (k nearest, optionally capped by a
radius); the eigen-decomposition is the closed-form 3×3 solver of the laser front-end
(:func:`frontends.laser.preprocess.eigen3`, ~20× faster than a batched ``numpy.linalg.eigh``).
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from frontends.laser.eigen import eigen3


def normals_and_curvature(
    cloud: np.ndarray,
    viewpoint: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
    *,
    k: int = 20,
    radius: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (N×3, facing ``viewpoint``) and curvature (N,) of an N×3 cloud.

    ``cloud`` and ``viewpoint`` are in the same frame (metres). With ``radius`` the neighbourhood
    is the at most ``k`` nearest points within ``radius``.
    """
    pts = np.asarray(cloud, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 3:
        raise ValueError(f"normals need an N×3 cloud with N ≥ 3, got shape {pts.shape}")
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    param = (
        o3d.geometry.KDTreeSearchParamKNN(k)
        if radius is None
        else o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=k)
    )
    pcd.estimate_covariances(param)
    cov = np.asarray(pcd.covariances)
    lam0, lam1, lam2, normals = eigen3(cov)
    flip = np.einsum("ij,ij->i", normals, np.asarray(viewpoint, dtype=np.float64) - pts) < 0
    normals[flip] *= -1.0
    total = lam0 + lam1 + lam2
    curvature = np.divide(lam0, total, out=np.zeros(len(pts)), where=total > 0)
    return normals, np.abs(curvature)
