"""6-DoF pose of a recognised object: ICP of its segmented cloud against the model (Open3D).

The initial guess is the camera pose T_CM of the best-matching database view, moved so that the
model's visible centroid lands on the segment's centroid, and tried at several rolls about the
viewing axis (ESF is rotation invariant, so the view fixes the viewing direction but not the
roll). Each guess gets a few point-to-plane ICP iterations against points sampled on the mesh,
the best few are refined to convergence, and the best two-sided fit (then lowest RMSE) wins.

Frames: the segment is in the sensor frame {S} (metres); the result is T_SM, model frame {M} →
{S}.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d


@dataclass(frozen=True)
class PoseEstimate:
    T_SM: np.ndarray  # 4×4
    fitness: float  # segment points explained × model points facing the sensor that were seen (0..1)
    rmse_m: float  # RMS distance of the segment's inlier correspondences


def _score(T, seg, target, surface, tol) -> PoseEstimate:
    """Two-sided fit of a pose: the fraction of segment points near the placed model, times the
    fraction of the model's sensor-facing points near the segment (a pose that explains the
    segment but puts unseen model surface in plain view scores low)."""
    T = np.asarray(T)
    model = o3d.geometry.PointCloud(surface.pcd).transform(T)
    d_seg = np.asarray(target.compute_point_cloud_distance(model))
    pts = np.asarray(model.points)
    nrm = np.asarray(model.normals)
    facing = np.einsum("ij,ij->i", nrm, -pts) > 0
    seen = (
        np.asarray(model.select_by_index(np.flatnonzero(facing)).compute_point_cloud_distance(target)) < 2 * tol
        if facing.any()
        else np.zeros(0)
    )
    inl = d_seg < tol
    frac_model = float(seen.mean()) if len(seen) else 0.0
    rmse = float(np.sqrt(np.mean(d_seg[inl] ** 2))) if inl.any() else np.inf
    return PoseEstimate(T.copy(), float(inl.mean()) * frac_model, rmse)


def _rot_about(axis: np.ndarray, angle: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


class ModelSurface:
    """Points and normals sampled uniformly on a model mesh, for ICP."""

    def __init__(self, mesh: o3d.geometry.TriangleMesh, n_points: int = 2000, seed: int = 0):
        m = o3d.geometry.TriangleMesh(mesh)
        m.compute_triangle_normals()
        m.compute_vertex_normals()
        o3d.utility.random.seed(seed)
        self.pcd = m.sample_points_uniformly(number_of_points=n_points, use_triangle_normal=True)
        self.points = np.asarray(self.pcd.points)


def estimate_pose(
    segment: np.ndarray,
    surface: ModelSurface,
    T_CM_init: np.ndarray,
    *,
    n_rolls: int = 8,
    max_correspondence_m: float = 0.02,
    max_iterations: int = 40,
    refine: int = 3,
) -> PoseEstimate:
    """T_SM of the model whose ``surface`` best explains ``segment`` (N×3, {S}), starting from
    database views' camera poses ``T_CM_init`` (4×4, or K×4×4 to try several views)."""
    seg = np.asarray(segment, dtype=np.float64)
    source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(seg))
    # ICP aligns the model (source) to the segment (target), so that T maps {M} to {S}.
    model_pcd = surface.pcd
    target = source
    target.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(20))
    target.orient_normals_towards_camera_location(np.zeros(3))
    c_seg = seg.mean(axis=0)
    # Coarse ICP from every initial guess, then the best few refined to convergence.
    coarse = o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=max(5, max_iterations // 6))
    fine = o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=max_iterations)
    p2plane = o3d.pipelines.registration.TransformationEstimationPointToPlane()
    inits = np.asarray(T_CM_init, dtype=np.float64).reshape(-1, 4, 4)
    candidates: list[PoseEstimate] = []
    for T_init, k in ((T, k) for T in inits for k in range(n_rolls)):
        R_roll = _rot_about(np.array([0.0, 0.0, 1.0]), 2 * np.pi * k / n_rolls)
        T0 = np.eye(4)
        T0[:3, :3] = R_roll @ T_init[:3, :3]
        # Visible model points face the camera: use the model points' centroid on the camera side.
        pts_c = surface.points @ T0[:3, :3].T
        front = pts_c[:, 2] <= np.median(pts_c[:, 2])
        T0[:3, 3] = c_seg - pts_c[front].mean(axis=0)
        reg = o3d.pipelines.registration.registration_icp(model_pcd, target, max_correspondence_m, T0, p2plane, coarse)
        candidates.append(_score(reg.transformation, seg, target, surface, max_correspondence_m))
    candidates.sort(key=lambda e: (e.fitness, -e.rmse_m), reverse=True)
    best: PoseEstimate | None = None
    for cand in candidates[:refine]:
        reg = o3d.pipelines.registration.registration_icp(
            model_pcd, target, max_correspondence_m, cand.T_SM, p2plane, fine
        )
        est = _score(reg.transformation, seg, target, surface, max_correspondence_m)
        if best is None or (est.fitness, -est.rmse_m) > (best.fitness, -best.rmse_m):
            best = est
    assert best is not None
    return best
