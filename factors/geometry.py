"""Small SO(3)/SE(3) helpers shared by the factors (numpy only).

Pose perturbations follow GTSAM: a Pose3 T = (R, t) is perturbed on the right,
T ⊕ ξ = T · Exp(ξ) with ξ = (ω, v) (rotation first), so to first order R → R (I + [ω]×) and
t → t + R v.
"""

from __future__ import annotations

import numpy as np


def skew(w: np.ndarray) -> np.ndarray:
    """[w]×, the cross-product matrix of a 3-vector."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: Exp(w) as a 3×3 rotation matrix."""
    th = float(np.linalg.norm(w))
    K = skew(w)
    if th < 1e-8:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + np.sin(th) / th * K + (1.0 - np.cos(th)) / th**2 * K @ K


def so3_right_jacobian(w: np.ndarray) -> np.ndarray:
    """J_r(w) with Exp(w + δ) ≈ Exp(w) Exp(J_r(w) δ)."""
    th = float(np.linalg.norm(w))
    K = skew(w)
    if th < 1e-6:
        return np.eye(3) - 0.5 * K + K @ K / 6.0
    return np.eye(3) - (1.0 - np.cos(th)) / th**2 * K + (th - np.sin(th)) / th**3 * K @ K


def euler_zyx_rate_matrix(roll: float, pitch: float) -> np.ndarray:
    """E with δθ_body = E · (δroll, δpitch, δyaw) for R = Rz(yaw) Ry(pitch) Rx(roll).

    Maps a (roll, pitch, yaw) error to the right-perturbation tangent of R (the body-frame angle
    error). Singular at pitch = ±90°, which an AUV does not reach.
    """
    sr, cr = np.sin(roll), np.cos(roll)
    sp, cp = np.sin(pitch), np.cos(pitch)
    return np.array([[1.0, 0.0, -sp], [0.0, cr, sr * cp], [0.0, -sr, cr * cp]])


def rot_to_roll_pitch(R: np.ndarray) -> tuple[float, float]:
    """Roll and pitch of R = Rz Ry Rx (ZYX Euler)."""
    pitch = float(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)))
    roll = float(np.arctan2(R[2, 1], R[2, 2]))
    return roll, pitch


def pose_point_jacobian(R: np.ndarray, p_B: np.ndarray) -> np.ndarray:
    """d(t + R p_B)/dξ (3×6) for a right perturbation ξ = (ω, v) of T = (R, t)."""
    return np.hstack([-R @ skew(p_B), R])
