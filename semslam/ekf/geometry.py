"""Rotations, Euler angles and the orthonormal line representation used by the EKF.

Conventions
-----------
- Euler angles (φ, θ, ψ) = (roll, pitch, yaw), R = Rz(ψ) Ry(θ) Rx(φ) (NED, Z-Y-X Tait–Bryan).
- Rotation perturbations are taken on the right (body side): R(e + δe) ≈ R(e) Exp(E(e) δe), where
  E maps Euler-angle rates to body angular rates (ω = E ė).
- Lines (Vallicrosa et al. 2021, eqs. 2–16): Plücker coordinates (m, d) with a unit direction d and
  moment m = p × d for any point p on the line. The orthonormal representation is
  U = [m/|m|, d, (m × d)/|m × d|] ∈ SO(3) and the distance ρ = |m| of the line from the origin
  (W ∈ SO(2) of Bartoli & Sturm with W ∝ [[ρ, -1], [1, ρ]]). The EKF stores a line as
  l = [α, β, γ, ρ] with U = R(α, β, γ) — singular where β = ±90°, i.e. where the plane through
  the origin and the line is horizontal (never for a pipe below the world origin at the surface).
- A "line error" is the 4-vector (ε, δρ) with U → U Exp(ε); ``line_error_map`` maps Plücker
  perturbations (δm, δd) to it and ``line_error_inverse`` back.
"""

from __future__ import annotations

import math

import numpy as np

from factors.geometry import quat_to_rot, skew, so3_exp, so3_log  # noqa: F401 (shared with the graph; re-exported)


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b for 3-vectors (np.cross is slow on single vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def wrap(a):
    """Angle(s) wrapped to [-π, π)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def wrap_angle(a: float) -> float:
    """One angle wrapped to [-π, π) (a float: no array overhead)."""
    return (float(a) + math.pi) % (2 * math.pi) - math.pi


def rot(phi: float, theta: float, psi: float) -> np.ndarray:
    """R = Rz(ψ) Ry(θ) Rx(φ)."""
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    return np.array(
        [
            [cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf],
            [sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf],
            [-st, ct * sf, ct * cf],
        ]
    )


def rot_batch(e: np.ndarray) -> np.ndarray:
    """R = Rz(ψ) Ry(θ) Rx(φ) for each row (φ, θ, ψ) of e (K×3) → (K, 3, 3)."""
    cf, sf = np.cos(e[:, 0]), np.sin(e[:, 0])
    ct, st = np.cos(e[:, 1]), np.sin(e[:, 1])
    cp, sp = np.cos(e[:, 2]), np.sin(e[:, 2])
    return np.stack(
        [
            np.stack([cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf], axis=-1),
            np.stack([sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf], axis=-1),
            np.stack([-st, ct * sf, ct * cf], axis=-1),
        ],
        axis=1,
    )


def euler(R: np.ndarray) -> np.ndarray:
    """(φ, θ, ψ) of R = Rz(ψ) Ry(θ) Rx(φ)."""
    theta = -math.asin(min(1.0, max(-1.0, float(R[2, 0]))))
    return np.array([math.atan2(R[2, 1], R[2, 2]), theta, math.atan2(R[1, 0], R[0, 0])])


def euler_rate_to_body(phi: float, theta: float) -> np.ndarray:
    """E with ω_body = E (φ̇, θ̇, ψ̇)."""
    cf, sf, ct, st = math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta)
    return np.array([[1.0, 0.0, -st], [0.0, cf, sf * ct], [0.0, -sf, cf * ct]])


def body_to_euler_rate(phi: float, theta: float) -> np.ndarray:
    """E⁻¹ with (φ̇, θ̇, ψ̇) = E⁻¹ ω_body (singular at θ = ±90°)."""
    cf, sf, ct, tt = math.cos(phi), math.sin(phi), math.cos(theta), math.tan(theta)
    return np.array([[1.0, sf * tt, cf * tt], [0.0, cf, -sf], [0.0, sf / ct, cf / ct]])


def euler_rate_jacobian(phi: float, theta: float, w: np.ndarray) -> np.ndarray:
    """∂(E⁻¹(φ, θ) ω)/∂(φ, θ, ψ) at fixed ω (3×3)."""
    cf, sf, ct, st = math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta)
    a = w[1] * sf + w[2] * cf
    b = w[1] * cf - w[2] * sf
    return np.array(
        [
            [b * st / ct, a / ct**2, 0.0],
            [-a, 0.0, 0.0],
            [b / ct, a * st / ct**2, 0.0],
        ]
    )


def so3_right_jacobian_inv(w: np.ndarray) -> np.ndarray:
    """J_r⁻¹(w): Log(Exp(w) Exp(δ)) ≈ w + J_r⁻¹(w) δ."""
    t = np.linalg.norm(w)
    K = skew(w)
    if t < 1e-6:
        return np.eye(3) + 0.5 * K + K @ K / 12.0
    return np.eye(3) + 0.5 * K + (1 / t**2 - (1 + np.cos(t)) / (2 * t * np.sin(t))) * K @ K


def so3_left_jacobian_inv(w: np.ndarray) -> np.ndarray:
    """J_l⁻¹(w) = J_r⁻¹(-w): Log(Exp(δ) Exp(w)) ≈ w + J_l⁻¹(w) δ."""
    return so3_right_jacobian_inv(-w)


# --------------------------------------------------------------------------------------- lines
def plucker_from_endpoints(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(m, d, J) of the line through p and q: unit d = (q - p)/|q - p|, m = p × d, and
    J = ∂(m, d)/∂(p, q) (6×6)."""
    diff = q - p
    L = np.linalg.norm(diff)
    d = diff / L
    m = cross3(p, d)
    Pd = (np.eye(3) - np.outer(d, d)) / L
    J = np.zeros((6, 6))
    J[3:, :3] = -Pd
    J[3:, 3:] = Pd
    J[:3, :3] = -skew(d) + skew(p) @ J[3:, :3]
    J[:3, 3:] = skew(p) @ J[3:, 3:]
    return m, d, J


def orthonormal_from_plucker(m: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, float]:
    """(U, ρ) from Plücker (m, d) with unit d and m ≠ 0."""
    rho = float(np.linalg.norm(m))
    u1 = m / rho
    u3 = cross3(u1, d)
    return np.column_stack([u1, d, u3]), rho


def line_error_map(U: np.ndarray, rho: float) -> np.ndarray:
    """A (4×6): (ε, δρ) = A (δm, δd) for U → U Exp(ε), ρ → ρ + δρ (first order)."""
    u1, d, u3 = U[:, 0], U[:, 1], U[:, 2]
    A = np.zeros((4, 6))
    A[0, 3:] = u3
    A[1, :3] = -u3 / rho
    A[2, :3] = d / rho
    A[3, :3] = u1
    return A


def line_error_inverse(U: np.ndarray, rho: float) -> np.ndarray:
    """B (6×4): (δm, δd) = B (ε, δρ), the inverse of :func:`line_error_map` on valid perturbations."""
    u1, d, u3 = U[:, 0], U[:, 1], U[:, 2]
    B = np.zeros((6, 4))
    B[3:, 0] = u3
    B[:3, 1] = -rho * u3
    B[:3, 2] = rho * d
    B[3:, 2] = -u1
    B[:3, 3] = u1
    return B


def line_params(m: np.ndarray, d: np.ndarray) -> np.ndarray:
    """[α, β, γ, ρ] of the line (m, d)."""
    U, rho = orthonormal_from_plucker(m, d)
    return np.append(euler(U), rho)


def line_plucker(l: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(m, d) of the line [α, β, γ, ρ]."""
    U = rot(l[0], l[1], l[2])
    return l[3] * U[:, 0], U[:, 1].copy()


def line_params_jacobian(l: np.ndarray) -> np.ndarray:
    """∂(m, d)/∂[α, β, γ, ρ] (6×4)."""
    U = rot(l[0], l[1], l[2])
    G = np.zeros((4, 4))
    G[:3, :3] = euler_rate_to_body(l[0], l[1])
    G[3, 3] = 1.0
    return line_error_inverse(U, l[3]) @ G


def line_params_from_error(l: np.ndarray) -> np.ndarray:
    """∂[α, β, γ, ρ]/∂(ε, δρ) (4×4) at l (singular at β = ±90°)."""
    G = np.zeros((4, 4))
    G[:3, :3] = body_to_euler_rate(l[0], l[1])
    G[3, 3] = 1.0
    return G


def line_anchor(c: np.ndarray, d: np.ndarray, distance: float) -> np.ndarray:
    """The point a pipe's moment is taken about: ``distance`` from point ``c`` of the line (d its unit
    direction), square to the line and as vertical as that allows (above a level pipe, level beside a
    vertical one), so the plane through it and the line is never level (the Euler singularity of
    [α β γ ρ]).

    Why not the world origin: for a line passing near it (ρ a few decimetres: a vertical pipe under
    the origin, or one tilted a few degrees by a short first view), the moment's direction swings
    with every centimetre the line moves and the closest point lies metres from the seen segment, so
    the filter's linearisation fails and the pipe is mapped away from its views, then mapped again
    (experiments/estimators/README.md). About a point square to the seen segment the closest point
    is the segment itself and ρ is the chosen distance."""
    up = np.array([0.0, 0.0, -1.0]) - d * (-d[2])  # NED: up is -z; its part square to d
    if np.linalg.norm(up) < 0.3:  # a (near-)vertical pipe: a level direction square to it
        up = cross3(d, np.array([1.0, 0.0, 0.0]))
        if np.linalg.norm(up) < 0.3:
            up = cross3(d, np.array([0.0, 1.0, 0.0]))
    return c + distance * up / np.linalg.norm(up)


def anchored_plucker(l: np.ndarray, anchor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(m, d) in {W} about its origin of the line [α, β, γ, ρ] whose moment is about ``anchor``:
    m_W = m + anchor × d."""
    m, d = line_plucker(l)
    return m + cross3(anchor, d), d


def closest_point(m: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Point of the line nearest the origin: d × m."""
    return cross3(d, m)


def project_on_line(points: np.ndarray, m: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Orthogonal projection of points (N×3) onto the line (m, d)."""
    c = closest_point(m, d)
    s = (np.atleast_2d(points) - c) @ d
    return c + s[:, None] * d


_FLIP = np.diag([-1.0, -1.0, 1.0])  # U of the same line with its direction reversed: (m, d) → (−m, −d)


def line_difference(la: np.ndarray, lb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ν, H_a, H_b): the line error (ε, δρ) that takes line a = [α, β, γ, ρ] to line b, with b's
    direction taken along a's, and its Jacobians (4×4) with respect to a and b. ν = 0 exactly when
    the two are the same line (:func:`orthonormal_difference`, with U → U Exp(E δe) for the Euler
    angles)."""
    Ua, Ub = rot(la[0], la[1], la[2]), rot(lb[0], lb[1], lb[2])
    nu, G_a, G_b = orthonormal_difference(Ua, la[3], Ub, lb[3])
    E = np.eye(4)
    E[:3, :3] = euler_rate_to_body(la[0], la[1])
    H_a = G_a @ E
    E[:3, :3] = euler_rate_to_body(lb[0], lb[1])
    return nu, H_a, G_b @ E


def orthonormal_difference(
    Ua: np.ndarray, rho_a: float, Ub: np.ndarray, rho_b: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ν, G_a, G_b): the line error (ε, δρ) that takes line a (U_a, ρ_a) to line b, b's direction
    taken along a's, and its Jacobians (4×4) on each line's error (ε, δρ) (:func:`line_error_map`).
    From U_b' = U_a Exp(ε), ρ_b = ρ_a + δρ, with right perturbations U → U Exp(δε):
    ε ≈ ε₀ + J_r⁻¹(ε₀) F δε_b − J_l⁻¹(ε₀) δε_a (F: the direction flip)."""
    F = _FLIP if Ua[:, 1] @ Ub[:, 1] < 0 else np.eye(3)
    eps = so3_log(Ua.T @ Ub @ F)
    G_a, G_b = np.zeros((4, 4)), np.zeros((4, 4))
    G_a[:3, :3] = -so3_left_jacobian_inv(eps)
    G_b[:3, :3] = so3_right_jacobian_inv(eps) @ F
    G_a[3, 3], G_b[3, 3] = -1.0, 1.0
    return np.append(eps, rho_b - rho_a), G_a, G_b
