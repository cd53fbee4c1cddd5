"""Motion and measurement models of the EKF (Vallicrosa et al. 2021, Section 4), with Jacobians.

Vehicle state x = [x y z φ θ ψ u v w]: position of the body origin in {W} (NED, m), Euler attitude
of {B} in {W} (rad, R_WB = Rz(ψ) Ry(θ) Rx(φ)), velocity of the body origin in {B} (m/s).
Landmarks: objects as points [x y z] in {W}; pipes as lines [α β γ ρ] in {W} (see
:mod:`semslam.ekf.geometry`). A sensor S has the extrinsic T_BS = (R_BS, t_BS).

Every ``*_jacobians`` function returns Jacobians with respect to the 9-vector vehicle state (only the
pose columns are non-zero for landmark measurements) and to the landmark block, so that the filter
can assemble a sparse H.

AHRS heading bias (an extension; the paper has none): when the mission's sensor model declares one
(``SensorModelConfig.heading_bias_walk``), the vehicle state gains a 10th entry b (rad, index
:data:`BIAS`), a random walk (:func:`predict_biased`) — with its drift rate modelled too
(``heading_bias_rate_sigma``), an 11th, ρ at BIAS + 1, that carries b on (:mod:`factors.heading_bias`) — and the AHRS reads the heading plus b
(:func:`biased_attitude_update`): R_meas = Rz(b) R_WB, the graph back-end's
``factors.navigation.biased_attitude_residual``. Every other model sees only the first 9 entries; its
Jacobian column for b is zero. The gyro's bias b_g (3, body axes), when modelled, is the vehicle
block's last entries (:data:`GYRO_BIAS_SIZE`): the prediction integrates ω_B − b_g and the DVL's lever arm
turns at it (:func:`predict`, :func:`dvl_update`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from factors.heading_bias import RATE_UNIT_S, heading_bias_drift_covariance
from semslam.ekf.geometry import (
    body_to_euler_rate,
    cross3,
    euler,
    euler_rate_to_body,
    line_error_map,
    line_params,
    line_params_from_error,
    line_params_jacobian,
    line_plucker,
    orthonormal_from_plucker,
    plucker_from_endpoints,
    rot,
    skew,
    so3_left_jacobian_inv,
    so3_log,
    so3_right_jacobian_inv,
    wrap,
    wrap_angle,
)

NX = 9  # vehicle state size (the paper's: pose and body velocity)
BIAS = NX  # index of the AHRS heading bias, when the vehicle state carries one (10 entries)
GYRO_BIAS_SIZE = 3  # the gyro's bias (body axes), when modelled the vehicle block's last entries
_I3 = np.eye(3)
POS, ATT, VEL = slice(0, 3), slice(3, 6), slice(6, 9)


# ------------------------------------------------------------------------------ prediction
def predict(
    x: np.ndarray,
    omega_B: np.ndarray,
    dt: float,
    accel_sigma: float,
    rate_sigma: float,
    bias_walk: float | None = None,
    bias_rate_walk: float | None = None,
    gyro_bias_walk: float | None = None,
):
    """Constant-velocity model with the AHRS body rate ω_B as input (eqs. 20–22).

    p' = p + R_WB v Δt, e' = e + E⁻¹(φ, θ) ω_B Δt, v' = v. Noise: white linear acceleration in
    {B} and white angular rate, continuous densities ``accel_sigma`` (m/s²/√Hz) and ``rate_sigma``
    (rad/s/√Hz), i.e. Var(Δv) = σ_a² Δt, discretised exactly for the p–v pair (Δt³/3, Δt²/2, Δt).

    Returns (x', F, Q) with F = ∂x'/∂x and Q the discrete process noise (9×9). (Written out in
    scalars: it runs at every navigation measurement, where numpy's per-call cost dominates.)
    With ``bias_walk``, the same for the 10-state [x_v; b] (:func:`predict_biased`); with
    ``bias_rate_walk`` too, for the 11-state [x_v; b; ρ] (the bias's drift rate, :mod:`factors.heading_bias`).
    With ``gyro_bias_walk``, x ends with the gyro's bias b_g (3, body axes, :data:`GYRO_BIAS_SIZE`), a random
    walk of that intensity (rad/s/√s): the rate integrated is ω_B − b_g, ∂e'/∂b_g = −E⁻¹ Δt.
    """
    px, py, pz, phi, theta, psi, u, v, w = x.tolist()[:NX]
    wx, wy, wz = map(float, omega_B)
    if gyro_bias_walk is not None:
        gx, gy, gz = x.tolist()[-GYRO_BIAS_SIZE:]
        wx, wy, wz = wx - gx, wy - gy, wz - gz
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    tt = st / ct
    # R = Rz(ψ) Ry(θ) Rx(φ)
    r00, r01, r02 = cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf
    r10, r11, r12 = sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf
    r20, r21, r22 = -st, ct * sf, ct * cf
    # E⁻¹ (Euler rates from body rates) and the new state
    e00, e01, e02 = 1.0, sf * tt, cf * tt
    _e10, e11, e12 = 0.0, cf, -sf
    _e20, e21, e22 = 0.0, sf / ct, cf / ct
    xn = [
        px + (r00 * u + r01 * v + r02 * w) * dt,
        py + (r10 * u + r11 * v + r12 * w) * dt,
        pz + (r20 * u + r21 * v + r22 * w) * dt,
        wrap_angle(phi + (e00 * wx + e01 * wy + e02 * wz) * dt),
        theta + (e11 * wy + e12 * wz) * dt,
        wrap_angle(psi + (e21 * wy + e22 * wz) * dt),
        u,
        v,
        w,
    ]
    # ∂p'/∂e = -R [v]× E dt with E = [[1, 0, -st], [0, cf, sf ct], [0, -sf, cf ct]]
    m00, m01, m02 = 0.0, -w * cf - v * sf, -w * sf * ct + v * cf * ct  # [v]× E, [v]× = [[0,-w,v],[w,0,-u],[-v,u,0]]
    m10, m11, m12 = w, u * sf, -w * st - u * cf * ct
    m20, m21, m22 = -v, u * cf, v * st + u * sf * ct
    a00 = -(r00 * m00 + r01 * m10 + r02 * m20) * dt
    a01 = -(r00 * m01 + r01 * m11 + r02 * m21) * dt
    a02 = -(r00 * m02 + r01 * m12 + r02 * m22) * dt
    a10 = -(r10 * m00 + r11 * m10 + r12 * m20) * dt
    a11 = -(r10 * m01 + r11 * m11 + r12 * m21) * dt
    a12 = -(r10 * m02 + r11 * m12 + r12 * m22) * dt
    a20 = -(r20 * m00 + r21 * m10 + r22 * m20) * dt
    a21 = -(r20 * m01 + r21 * m11 + r22 * m21) * dt
    a22 = -(r20 * m02 + r21 * m12 + r22 * m22) * dt
    # ∂(E⁻¹ ω)/∂(φ, θ) (euler_rate_jacobian)
    a = wy * sf + wz * cf
    b = wy * cf - wz * sf
    j00, j01 = b * tt * dt, a / ct**2 * dt
    j10 = -a * dt
    j20, j21 = b / ct * dt, a * st / ct**2 * dt
    F = [
        [1.0, 0.0, 0.0, a00, a01, a02, r00 * dt, r01 * dt, r02 * dt],
        [0.0, 1.0, 0.0, a10, a11, a12, r10 * dt, r11 * dt, r12 * dt],
        [0.0, 0.0, 1.0, a20, a21, a22, r20 * dt, r21 * dt, r22 * dt],
        [0.0, 0.0, 0.0, 1.0 + j00, j01, 0.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, j10, 1.0, 0.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, j20, j21, 1.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
    ]
    qa, qw = accel_sigma**2, rate_sigma**2
    q3, q2, q1 = qa * dt**3 / 3.0, qa * dt**2 / 2.0, qa * dt
    qe = qw * dt
    # E⁻¹ E⁻ᵀ (rows of E⁻¹: (1, sf tt, cf tt), (0, cf, -sf), (0, sf/ct, cf/ct))
    g00 = (1.0 + tt * tt) * qe
    g01 = (sf * tt * cf - cf * tt * sf) * qe
    g02 = (sf * tt * sf / ct + cf * tt * cf / ct) * qe
    g11 = qe
    g12 = (cf * sf / ct - sf * cf / ct) * qe
    g22 = (1.0 / ct**2) * qe
    Q = [
        [q3, 0.0, 0.0, 0.0, 0.0, 0.0, r00 * q2, r01 * q2, r02 * q2],
        [0.0, q3, 0.0, 0.0, 0.0, 0.0, r10 * q2, r11 * q2, r12 * q2],
        [0.0, 0.0, q3, 0.0, 0.0, 0.0, r20 * q2, r21 * q2, r22 * q2],
        [0.0, 0.0, 0.0, g00, g01, g02, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, g01, g11, g12, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, g02, g12, g22, 0.0, 0.0, 0.0],
        [r00 * q2, r10 * q2, r20 * q2, 0.0, 0.0, 0.0, q1, 0.0, 0.0],
        [r01 * q2, r11 * q2, r21 * q2, 0.0, 0.0, 0.0, 0.0, q1, 0.0],
        [r02 * q2, r12 * q2, r22 * q2, 0.0, 0.0, 0.0, 0.0, 0.0, q1],
    ]
    if bias_rate_walk is not None:  # b' = b + ρ Δt/τ, ρ' = ρ: an integrated random walk
        a = dt / RATE_UNIT_S
        xn += [float(x[BIAS]) + a * float(x[BIAS + 1]), float(x[BIAS + 1])]
        for row in F:
            row += [0.0, 0.0]
        for row in Q:
            row += [0.0, 0.0]
        (q00, q01), (_, q11) = heading_bias_drift_covariance(dt, bias_walk, bias_rate_walk).tolist()
        F += [[0.0] * NX + [1.0, a], [0.0] * NX + [0.0, 1.0]]
        Q += [[0.0] * NX + [q00, q01], [0.0] * NX + [q01, q11]]
    elif bias_walk is not None:  # b' = b, a random walk (the rows and columns built here: no 10×10 copies)
        xn.append(float(x[BIAS]))
        for row in F:
            row.append(0.0)
        for row in Q:
            row.append(0.0)
        F.append([0.0] * NX + [1.0])
        Q.append([0.0] * NX + [bias_walk**2 * dt])
    if gyro_bias_walk is None:
        return np.array(xn), np.array(F), np.array(Q)
    # the gyro's bias b_g' = b_g, a random walk; e' = e + E⁻¹ (ω − b_g) Δt
    n = len(F) + GYRO_BIAS_SIZE
    xg = np.empty(n)
    xg[:-GYRO_BIAS_SIZE] = xn
    xg[-GYRO_BIAS_SIZE:] = x[-GYRO_BIAS_SIZE:]
    Fg, Qg = np.zeros((n, n)), np.zeros((n, n))
    Fg[:-GYRO_BIAS_SIZE, :-GYRO_BIAS_SIZE] = F
    Qg[:-GYRO_BIAS_SIZE, :-GYRO_BIAS_SIZE] = Q
    Fg[-GYRO_BIAS_SIZE:, -GYRO_BIAS_SIZE:] = _I3
    Fg[ATT, -GYRO_BIAS_SIZE:] = [
        [-e00 * dt, -e01 * dt, -e02 * dt],
        [0.0, -e11 * dt, -e12 * dt],
        [0.0, -e21 * dt, -e22 * dt],
    ]
    Qg[-GYRO_BIAS_SIZE:, -GYRO_BIAS_SIZE:] = _I3 * (gyro_bias_walk**2 * dt)
    return xg, Fg, Qg


def predict_biased(
    x: np.ndarray,
    omega_B: np.ndarray,
    dt: float,
    accel_sigma: float,
    rate_sigma: float,
    bias_walk: float | None,
    bias_rate_walk: float | None = None,
    gyro_bias_walk: float | None = None,
):
    """:func:`predict` for the 10-state [x_v; b] with the AHRS heading bias b a random walk of intensity
    ``bias_walk`` (rad/√s): b' = b, Var(b' − b) = σ_b² Δt (the graph's ``heading_bias_walk_factor``).
    With ``bias_rate_walk``, the 11-state [x_v; b; ρ] with the bias's drift rate ρ (rad per
    ``RATE_UNIT_S`` s), b' = b + ρ Δt/τ (the graph's ``heading_bias_drift_factor``).
    The heading bias does not enter the motion (the body rate input is the gyro's, not the biased heading's);
    the gyro's bias does (``gyro_bias_walk``, :func:`predict`)."""
    return predict(x, omega_B, dt, accel_sigma, rate_sigma, bias_walk, bias_rate_walk, gyro_bias_walk)


# ------------------------------------------------------------------------- linear updates
@dataclass
class NavUpdate:
    """A navigation update z ≈ h(x) + H δx: innovation ν (angles wrapped), H over the vehicle, R."""

    innovation: np.ndarray
    H: np.ndarray
    R: np.ndarray


def depth_update(x: np.ndarray, depth: float, variance: float, t_BS: np.ndarray) -> NavUpdate:
    """Pressure sensor at lever arm t_BS: z = p_z + (R_WB t_BS)_z (eq. 23, with the lever arm)."""
    phi, theta = float(x[3]), float(x[4])
    cf, sf, ct, st = math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta)
    tx, ty, tz = float(t_BS[0]), float(t_BS[1]), float(t_BS[2])
    h = float(x[2]) - st * tx + ct * sf * ty + ct * cf * tz  # z + (R_WB t_BS)_z, row 2 of R = (-sθ, cθ sφ, cθ cφ)
    H = np.zeros((1, NX))
    H[0, 2] = 1.0
    H[0, 3] = ct * cf * ty - ct * sf * tz
    H[0, 4] = -ct * tx - st * sf * ty - st * cf * tz
    return NavUpdate(np.array([depth - h]), H, np.array([[variance]]))


def attitude_in_body(R_WS: np.ndarray, cov_S: np.ndarray, R_BS: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Euler angles of R_WB = R_WS R_BSᵀ and their covariance, from the AHRS's (φ, θ, ψ) covariance.

    Perturbing the sensor angles rotates {S} by ω_S = E(e_S) δe_S, i.e. {B} by R_BS ω_S, so
    δe_B = E⁻¹(e_B) R_BS E(e_S) δe_S.
    """
    R_WB = R_WS @ R_BS.T
    e_B, e_S = euler(R_WB), euler(R_WS)
    J = body_to_euler_rate(e_B[0], e_B[1]) @ R_BS @ euler_rate_to_body(e_S[0], e_S[1])
    return e_B, J @ cov_S @ J.T


_H_ATT = np.zeros((3, NX))
_H_ATT[:, ATT] = np.eye(3)
_H_ATT.flags.writeable = False


def attitude_update(x: np.ndarray, e_B: np.ndarray, cov_B: np.ndarray) -> NavUpdate:
    """AHRS: z = (φ, θ, ψ) of {B} (eq. 24), linear."""
    return NavUpdate(wrap(e_B - x[ATT]), _H_ATT, cov_B)


_H_ATT_B = np.zeros((3, NX + 1))
_H_ATT_B[:, ATT] = np.eye(3)
_H_ATT_B[2, BIAS] = 1.0
_H_ATT_B.flags.writeable = False


def biased_attitude_update(x: np.ndarray, e_B: np.ndarray, cov_B: np.ndarray) -> NavUpdate:
    """AHRS with a heading bias, x = [x_v; b]: the reading is R_meas = Rz(b) R_WB, whose Euler angles
    are exactly (φ, θ, ψ + b) (Rz(b) Rz(ψ) = Rz(ψ + b)), so z = (φ, θ, ψ + b), linear; H is 3×10."""
    h = np.array([x[3], x[4], x[5] + x[BIAS]])
    return NavUpdate(wrap(e_B - h), _H_ATT_B, cov_B)


def dvl_update(
    x: np.ndarray,
    v_S: np.ndarray,
    cov_S: np.ndarray,
    R_BS: np.ndarray,
    t_BS: np.ndarray,
    omega_B: np.ndarray,
    gyro_bias: bool = False,
) -> NavUpdate:
    """DVL: z = R_BSᵀ (v_B + ω_B × t_BS) in the DVL frame (eqs. 25–29), linear in v_B (ω_B is the input).
    With ``gyro_bias`` x ends with the gyro's bias b_g and ω_B is the gyro's reading: the lever arm turns
    at ω_B − b_g, ∂z/∂b_g = R_BSᵀ [t_BS]× (H over the whole of x)."""
    if gyro_bias:
        H = np.zeros((3, len(x)))
        H[:, -GYRO_BIAS_SIZE:] = R_BS.T @ skew(t_BS)
        omega_B = omega_B - x[-GYRO_BIAS_SIZE:]
    else:
        H = np.zeros((3, NX))
    H[:, VEL] = R_BS.T
    h = R_BS.T @ (x[VEL] + cross3(omega_B, t_BS))
    return NavUpdate(v_S - h, H, cov_S)


# ------------------------------------------------------------------------ sensor pose
def sensor_pose(x: np.ndarray, R_BS: np.ndarray, t_BS: np.ndarray):
    """(R_WS, t_WS, R_WB, Ω) where Ω = ∂ω_S/∂e (3×3): a vehicle Euler perturbation δe rotates {S}
    by ω_S = R_BSᵀ E(φ, θ) δe (right side)."""
    R_WB = rot(*x[ATT])
    E = euler_rate_to_body(x[3], x[4])
    return R_WB @ R_BS, x[POS] + R_WB @ t_BS, R_WB, E


def _dt_dx(R_WB: np.ndarray, E: np.ndarray, t_BS: np.ndarray) -> np.ndarray:
    """∂t_WS/∂x (3×9)."""
    J = np.zeros((3, NX))
    J[:, POS] = np.eye(3)
    J[:, ATT] = -R_WB @ skew(t_BS) @ E
    return J


# ------------------------------------------------------------------------------- points
def point_measurement(x: np.ndarray, l: np.ndarray, R_BS: np.ndarray, t_BS: np.ndarray):
    """Object l (in {W}) seen in {S}: h = R_WSᵀ (l - t_WS) (eqs. 30–32). Returns (h, H_x 3×9, H_l 3×3)."""
    R, t, R_WB, E = sensor_pose(x, R_BS, t_BS)
    h = R.T @ (l - t)
    H_x = -R.T @ _dt_dx(R_WB, E, t_BS)
    H_x[:, ATT] += skew(h) @ R_BS.T @ E
    return h, H_x, R.T.copy()


def point_initialise(x: np.ndarray, z: np.ndarray, R_BS: np.ndarray, t_BS: np.ndarray):
    """New object from z in {S}: l = t_WS + R_WS z (eqs. 39–41). Returns (l, G_x 3×9, G_z 3×3)."""
    R, t, R_WB, E = sensor_pose(x, R_BS, t_BS)
    l = t + R @ z
    G_x = _dt_dx(R_WB, E, t_BS)
    G_x[:, ATT] += -R @ skew(z) @ R_BS.T @ E
    return l, G_x, R.copy()


# -------------------------------------------------------------------------------- lines
def line_to_sensor(x: np.ndarray, l: np.ndarray, R_BS: np.ndarray, t_BS: np.ndarray, anchor: np.ndarray | None = None):
    """Pipe l = [α β γ ρ] in {W} as Plücker (m_S, d_S) in {S} (eqs. 13–16, 33–35):
    d_S = R_WSᵀ d_W, m_S = R_WSᵀ (m_W - t_WS × d_W).

    ``anchor`` (a point in {W}, default its origin): the point l's moment is taken about,
    m = (p − anchor) × d (see :func:`semslam.ekf.geometry.line_anchor`); it moves {S}'s position to
    t_WS − anchor and changes nothing else. Returns (m_S, d_S, J_x 6×9, J_l 6×4), Jacobians of (m_S, d_S).
    """
    R, t, R_WB, E = sensor_pose(x, R_BS, t_BS)
    if anchor is not None:
        t = t - anchor
    m_W, d_W = line_plucker(l)
    m_S = R.T @ (m_W - cross3(t, d_W))
    d_S = R.T @ d_W
    W = R_BS.T @ E  # ∂ω_S/∂e
    J_x = np.zeros((6, NX))
    J_x[:3] = R.T @ skew(d_W) @ _dt_dx(R_WB, E, t_BS)
    J_x[:3, ATT] += skew(m_S) @ W
    J_x[3:, ATT] = skew(d_S) @ W
    J_md = np.zeros((6, 6))  # ∂(m_S, d_S)/∂(m_W, d_W)
    J_md[:3, :3] = R.T
    J_md[:3, 3:] = -R.T @ skew(t)
    J_md[3:, 3:] = R.T
    return m_S, d_S, J_x, J_md @ line_params_jacobian(l)


@dataclass
class LineObservationModel:
    """An observed segment (p, q) in {S} as a line: Plücker (m, d), orthonormal (U, ρ), and the 4×4
    covariance of its line error (ε, δρ) at U (from the 6×6 endpoint covariance)."""

    m: np.ndarray
    d: np.ndarray
    U: np.ndarray
    rho: float
    cov: np.ndarray

    @classmethod
    def from_endpoints(cls, p: np.ndarray, q: np.ndarray, cov_pq: np.ndarray) -> LineObservationModel:
        m, d, J = plucker_from_endpoints(p, q)
        U, rho = orthonormal_from_plucker(m, d)
        A = line_error_map(U, rho) @ J
        return cls(m, d, U, rho, A @ cov_pq @ A.T)

    def flipped(self) -> LineObservationModel:
        """The same line with the opposite direction: (m, d) → (-m, -d), U → U diag(-1, -1, 1);
        the error covariance changes sign in ε₁ and ε₂ (D Σ D, D = diag(-1, -1, 1, 1))."""
        D = np.array([-1.0, -1.0, 1.0, 1.0])
        return LineObservationModel(
            -self.m, -self.d, self.U * np.array([-1.0, -1.0, 1.0]), self.rho, self.cov * np.outer(D, D)
        )


def line_innovation(
    x: np.ndarray,
    l: np.ndarray,
    obs: LineObservationModel,
    R_BS: np.ndarray,
    t_BS: np.ndarray,
    l_lin: np.ndarray | None = None,
    x_lin: np.ndarray | None = None,
    anchor: np.ndarray | None = None,
):
    """Innovation of an observed line against pipe l (moment about ``anchor``), on the manifold of the orthonormal representation.

    ν = [Log(U_hᵀ U_z); ρ_z − ρ_h] where (U_h, ρ_h) is the pipe in {S} and the observed direction is
    flipped to agree with the predicted one. This is the paper's comparison of orthonormal
    parameters in the sensor frame (eqs. 30–37) without the Euler singularity of the sensor-frame
    angles. Returns (ν, H_x 4×9, H_l 4×4, R 4×4) with ν ≈ ν₀ − H_x δx − H_l δl (H = ∂h/∂state).

    ``l_lin``, ``x_lin``: evaluate the Jacobians H_x, H_l at this pipe and vehicle estimate instead of
    l and x (the first-estimates Jacobian, see :mod:`semslam.ekf.estimator`); ν and R are always at
    (x, l).
    """
    m_S, d_S, J_x, J_l = line_to_sensor(x, l, R_BS, t_BS, anchor)
    U_h, rho_h = orthonormal_from_plucker(m_S, d_S)
    if obs.d @ d_S < 0:
        obs = obs.flipped()
    r = so3_log(U_h.T @ obs.U)
    nu = np.append(r, obs.rho - rho_h)
    Gr = np.eye(4)
    Gr[:3, :3] = so3_right_jacobian_inv(r)
    R = Gr @ obs.cov @ Gr.T
    if l_lin is not None or x_lin is not None:
        m_S, d_S, J_x, J_l = line_to_sensor(
            x if x_lin is None else x_lin, l if l_lin is None else l_lin, R_BS, t_BS, anchor
        )
        U_h, rho_h = orthonormal_from_plucker(m_S, d_S)
        r = so3_log(U_h.T @ obs.U)
    A = line_error_map(U_h, rho_h)
    G = np.eye(4)
    G[:3, :3] = so3_left_jacobian_inv(r)
    H_x = G @ A @ J_x
    H_l = G @ A @ J_l
    return nu, H_x, H_l, R


def line_world(
    x: np.ndarray, p: np.ndarray, q: np.ndarray, R_BS: np.ndarray, t_BS: np.ndarray, anchor: np.ndarray | None = None
):
    """An observed segment (p, q) in {S} as Plücker (m_W, d_W) in {W}: d_W = R_WS d_S,
    m_W = R_WS m_S + t_WS × d_W (eqs. 42–44), the moment about ``anchor`` (default the origin).
    Returns (m_W, d_W, J_x 6×9, J_pq 6×6)."""
    R, t, R_WB, E = sensor_pose(x, R_BS, t_BS)
    if anchor is not None:
        t = t - anchor
    m_S, d_S, J_pq = plucker_from_endpoints(p, q)
    d_W = R @ d_S
    m_W = R @ m_S + cross3(t, d_W)
    W = R_BS.T @ E
    Jx = np.zeros((6, NX))
    Jx[3:, ATT] = -R @ skew(d_S) @ W
    Jx[:3, ATT] = -R @ skew(m_S) @ W + skew(t) @ Jx[3:, ATT]
    Jx[:3] += -skew(d_W) @ _dt_dx(R_WB, E, t_BS)
    Jz = np.zeros((6, 6))  # ∂(m_W, d_W)/∂(m_S, d_S)
    Jz[3:, 3:] = R
    Jz[:3, :3] = R
    Jz[:3, 3:] = skew(t) @ R
    return m_W, d_W, Jx, Jz @ J_pq


def line_initialise(
    x: np.ndarray, p: np.ndarray, q: np.ndarray, R_BS: np.ndarray, t_BS: np.ndarray, anchor: np.ndarray | None = None
):
    """New pipe [α β γ ρ] (moment about ``anchor``) from an observed segment (p, q) in {S} (eqs. 42–45).
    Returns (l, G_x 4×9, G_pq 4×6)."""
    m_W, d_W, Jx, Jpq = line_world(x, p, q, R_BS, t_BS, anchor)
    l = line_params(m_W, d_W)
    U_W = rot(l[0], l[1], l[2])
    T = line_params_from_error(l) @ line_error_map(U_W, l[3])
    return l, T @ Jx, T @ Jpq
