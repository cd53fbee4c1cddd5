"""Small SO(3)/SE(3) helpers shared by the factors (numpy only).

Pose perturbations follow GTSAM: a Pose3 T = (R, t) is perturbed on the right,
T ⊕ ξ = T · Exp(ξ) with ξ = (ω, v) (rotation first), so to first order R → R (I + [ω]×) and
t → t + R v.
"""

from __future__ import annotations

import math

import numpy as np


def skew(w: np.ndarray) -> np.ndarray:
    """[w]×, the cross-product matrix of a 3-vector: [w]× v = w × v."""
    x, y, z = w
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def skew_batch(v: np.ndarray) -> np.ndarray:
    """[v]× for each row of v (K×3) → (K, 3, 3)."""
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


# so3_exp and so3_log run per AHRS reading and per DVL sample (tens of thousands a mission): they
# are written out in scalars, ~5× faster than numpy's small-matrix products or scipy's Rotation.


def mat3_mul(a, b) -> tuple:
    """A B of two 3×3 matrices given as their nine entries row by row (tuples or lists of floats), the
    same; in Python floats, for the factors' callbacks (``gtsam.Rot3(*mat3_mul(a, b))`` builds the
    rotation from them at a fifth of the time an array takes)."""
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = a
    b00, b01, b02, b10, b11, b12, b20, b21, b22 = b
    return (
        a00 * b00 + a01 * b10 + a02 * b20,
        a00 * b01 + a01 * b11 + a02 * b21,
        a00 * b02 + a01 * b12 + a02 * b22,
        a10 * b00 + a11 * b10 + a12 * b20,
        a10 * b01 + a11 * b11 + a12 * b21,
        a10 * b02 + a11 * b12 + a12 * b22,
        a20 * b00 + a21 * b10 + a22 * b20,
        a20 * b01 + a21 * b11 + a22 * b21,
        a20 * b02 + a21 * b12 + a22 * b22,
    )


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: Exp(w) as a 3×3 rotation matrix."""
    x, y, z = float(w[0]), float(w[1]), float(w[2])
    th2 = x * x + y * y + z * z
    if th2 < 1e-16:  # second order: I + K + K²/2
        a, b = 1.0, 0.5
    else:
        th = math.sqrt(th2)
        a, b = math.sin(th) / th, (1.0 - math.cos(th)) / th2
    # I + a K + b K², with K² = w wᵀ − θ² I
    return np.array(
        [
            [1.0 - b * (y * y + z * z), b * x * y - a * z, b * x * z + a * y],
            [b * x * y + a * z, 1.0 - b * (x * x + z * z), b * y * z - a * x],
            [b * x * z - a * y, b * y * z + a * x, 1.0 - b * (x * x + y * y)],
        ]
    )


def so3_log(R: np.ndarray) -> np.ndarray:
    """Log(R) as a rotation vector, the inverse of :func:`so3_exp` (angle in [0, π])."""
    c = min(1.0, max(-1.0, 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)))
    t = math.acos(c)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if t < 1e-7:
        return 0.5 * v
    if math.pi - t < 1e-5:  # near π the antisymmetric part vanishes: the axis from the symmetric part
        B = 0.5 * (R + np.eye(3))
        k = int(np.argmax(np.diag(B)))
        axis = B[:, k] / math.sqrt(max(B[k, k], 1e-12))
        axis *= np.sign(axis @ v) if axis @ v != 0 else 1.0
        return t * axis / np.linalg.norm(axis)
    return t / (2 * math.sin(t)) * v


def quat_to_rot(q) -> np.ndarray:
    """Rotation matrix of a quaternion (x, y, z, w) (ROS order; normalised here), as scipy's Rotation."""
    x, y, z, w = (float(v) for v in q)
    s = 2.0 / (x * x + y * y + z * z + w * w)
    return np.array(
        [
            [1.0 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
            [s * (x * y + z * w), 1.0 - s * (x * x + z * z), s * (y * z - x * w)],
            [s * (x * z - y * w), s * (y * z + x * w), 1.0 - s * (x * x + y * y)],
        ]
    )


def so3_right_jacobian(w: np.ndarray) -> np.ndarray:
    """J_r(w) with Exp(w + δ) ≈ Exp(w) Exp(J_r(w) δ): I − a K + b K² with K = [w]×, K² = w wᵀ − θ² I,
    a = (1 − cos θ)/θ², b = (θ − sin θ)/θ³ (1/2 and 1/6 below θ = 1e-6); in scalars (per gyro reading)."""
    x, y, z = float(w[0]), float(w[1]), float(w[2])
    th = math.sqrt(x * x + y * y + z * z)
    if th < 1e-6:
        a, b = 0.5, 1.0 / 6.0
    else:
        a, b = (1.0 - math.cos(th)) / th**2, (th - math.sin(th)) / th**3
    return np.array(
        [
            [1.0 - b * (y * y + z * z), a * z + b * x * y, -a * y + b * x * z],
            [-a * z + b * x * y, 1.0 - b * (x * x + z * z), a * x + b * y * z],
            [a * y + b * x * z, -a * x + b * y * z, 1.0 - b * (x * x + y * y)],
        ]
    )


def euler_zyx_rate_matrix(roll: float, pitch: float) -> np.ndarray:
    """E with δθ_body = E · (δroll, δpitch, δyaw) for R = Rz(yaw) Ry(pitch) Rx(roll).

    Maps a (roll, pitch, yaw) error to the right-perturbation tangent of R (the body-frame angle
    error). Singular at pitch = ±90°, which an AUV does not reach.
    """
    sr, cr = math.sin(roll), math.cos(roll)
    sp, cp = math.sin(pitch), math.cos(pitch)
    return np.array([[1.0, 0.0, -sp], [0.0, cr, sr * cp], [0.0, -sr, cr * cp]])


def rot_to_roll_pitch(R: np.ndarray) -> tuple[float, float]:
    """Roll and pitch of R = Rz Ry Rx (ZYX Euler)."""
    r20, r21, r22 = float(R[2, 0]), float(R[2, 1]), float(R[2, 2])
    pitch = math.asin(min(1.0, max(-1.0, -r20)))
    roll = math.atan2(r21, r22)
    return roll, pitch


def pose_point_jacobian(R: np.ndarray, p_B: np.ndarray) -> np.ndarray:
    """d(t + R p_B)/dξ (3×6) for a right perturbation ξ = (ω, v) of T = (R, t)."""
    return np.hstack([-R @ skew(p_B), R])
