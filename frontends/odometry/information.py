"""Small geometry of the registration's uncertainty: point-to-plane information and pose algebra
(numpy only: front-ends do not use GTSAM). Tangent order is GTSAM's Pose3: rotation, then
translation, for a perturbation on the right (T·Exp(ξ))."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from factors.geometry import skew_batch  # numpy only, as the prior's SO(3) helpers

#: σ (rad) of the rotation of a relative pose that constrains the translation alone (``factor_rotation: free``):
#: a radian is ~1000 times the held rotation σ between two scans (~0.05°), and keeps the covariance well conditioned
FREE_ROTATION_SIGMA_RAD = 1.0

#: the navigation frame's z (NED: down), which the odometry's map frames share
VERTICAL = np.array([0.0, 0.0, 1.0])


def translation_only(cov: np.ndarray) -> np.ndarray:
    """``cov`` (6×6, rotation then translation) with the translation's marginal kept, the rotation's variance
    FREE_ROTATION_SIGMA_RAD² per axis and no cross terms: a relative pose that carries its translation alone."""
    out = np.zeros((6, 6))
    out[:3, :3] = np.eye(3) * FREE_ROTATION_SIGMA_RAD**2
    out[3:, 3:] = cov[3:, 3:]
    return out


def translation_given_rotation(cov: np.ndarray) -> np.ndarray:
    """``cov`` (6×6, rotation then translation) with the rotation's own information taken out and
    FREE_ROTATION_SIGMA_RAD's put in its place, the rest of the information kept: the relative pose then
    constrains the translation *given* the rotation (t − K·θ, K the translation's error per rotation
    error: the scan's points are metres away) and says nothing of the rotation itself, which the graph
    has from its own gyro link (the same rates: counted twice otherwise). Unlike :func:`translation_only`,
    whose translation marginal carries K·Σ_θ·Kᵀ as if the rotation's error were unknown, the graph's
    rotation then moves the translation the factor expects."""
    info = np.linalg.inv(cov)
    info[:3, :3] += np.eye(3) / FREE_ROTATION_SIGMA_RAD**2 - np.linalg.inv(cov[:3, :3])
    out = np.linalg.inv(info)
    return (out + out.T) / 2


def adjoint(T: np.ndarray) -> np.ndarray:
    """Ad_T (6×6) for the (rotation, translation) tangent: Exp(Ad_T ξ) = T Exp(ξ) T⁻¹."""
    R, t = T[:3, :3], T[:3, 3]
    A = np.zeros((6, 6))
    A[:3, :3] = R
    A[3:, 3:] = R
    A[3:, :3] = skew_batch(t) @ R
    return A


def tangent(T: np.ndarray) -> np.ndarray:
    """(rotation vector, translation) of T: its tangent to first order, in the order above."""
    return np.concatenate([Rotation.from_matrix(T[:3, :3]).as_rotvec(), T[:3, 3]])


def mahalanobis2(x: np.ndarray, cov: np.ndarray) -> float | None:
    """xᵀ cov⁻¹ x, or None when cov is not positive definite (nothing known along some direction)."""
    try:
        L = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return None
    y = np.linalg.solve(L, x)
    return float(y @ y)


def rotation_angle(R: np.ndarray) -> float:
    """The angle (rad) of rotation matrix R."""
    return float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


def fitted_planes(neighbours: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unit normals (n, 3), centroids (n, 3)) of the planes fitted to each point's map ``neighbours`` (n, k, 3)."""
    centroids = neighbours.mean(axis=1)
    centred = neighbours - centroids[:, None]
    _, vecs = np.linalg.eigh(np.einsum("nki,nkj->nij", centred, centred))
    return vecs[..., 0], centroids  # the direction of least spread


def twist_angle(R: np.ndarray, axis: np.ndarray) -> float:
    """The angle of R's rotation about the unit ``axis`` (swing-twist decomposition: R = swing · twist,
    the swing about an axis perpendicular to it)."""
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return float(2.0 * np.arctan2(np.dot([x, y, z], axis), w))


def plane_information(
    source: np.ndarray, world: np.ndarray, normals: np.ndarray, centroids: np.ndarray, R: np.ndarray
) -> tuple[np.ndarray, int, float]:
    """Information (Σ JᵀJ, 6×6) of point-to-plane residuals nᵢ·(R pᵢ + t − qᵢ) about the pose T_OS,
    with each matched point's plane (unit ``normals``, ``centroids``: :func:`fitted_planes` of its map
    neighbours), and the residuals' variance. ``source`` are the scan points in {S}, ``world`` the same in {O}."""
    residual = np.einsum("ni,ni->n", normals, world - centroids)
    # d/dξ of n·(R(p + ω×p) + t + R v) = nᵀR [−[p]×, I]
    nR = normals @ R  # rows nᵀR
    J = np.concatenate([np.einsum("ni,nij->nj", nR, -skew_batch(source)), nR], axis=1)
    n = len(source)
    var = float(residual @ residual / max(n - 6, 1))
    return J.T @ J, n, var
