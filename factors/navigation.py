"""Navigation factors: DVL body velocity (with lever arm), DVL/AHRS preintegration with a motion
model across dropouts, AHRS attitude, and depth (with lever arm).

State per keyframe k (see semslam.backend): ``X(k)`` = T_WB (gtsam.Pose3, {W} NED, {B} x fwd /
y right / z down) and ``V(k)`` = the body-frame velocity v_B of the vehicle origin (Vector3, m/s).
The body velocity is a state only so that DVL dropouts can be bridged by a motion model (velocity
as a Wiener process, white acceleration σ_a) whose uncertainty grows with the gap.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import gtsam
import numpy as np

from factors.geometry import euler_zyx_rate_matrix, mat3_mul, rot_to_roll_pitch, skew, skew_batch
from factors.heading_bias import RATE_UNIT_S, heading_bias_drift_covariance

# --------------------------------------------------------------------------------------------
# DVL velocity


def dvl_to_body(
    v_S: np.ndarray, cov_S: np.ndarray, T_BS: np.ndarray, omega_B: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Body velocity v_B and its covariance from a DVL reading v_S (DVL frame).

    The DVL head at t_BS moves with v_S = R_SB (v_B + ω_B × t_BS); the model is linear in v_B, so
    v_B = R_BS v_S − ω_B × t_BS exactly, with covariance R_BS Σ_S R_BSᵀ (ω_B, from the AHRS, is
    treated as known: its error times a lever arm of a few decimetres is negligible).
    """
    R_BS = np.ascontiguousarray(T_BS[:3, :3], float)
    v_B = np.dot(R_BS, np.asarray(v_S, float))
    if omega_B is not None:  # − ω × t_BS, in scalars (np.cross costs ten times as much on 3-vectors)
        w0, w1, w2 = (float(c) for c in omega_B)
        t0, t1, t2 = (float(c) for c in T_BS[:3, 3])
        v_B = v_B - np.array([w1 * t2 - w2 * t1, w2 * t0 - w0 * t2, w0 * t1 - w1 * t0])
    return v_B, np.dot(np.dot(R_BS, np.asarray(cov_S, float)), R_BS.T)


def dvl_residual(v_B: np.ndarray, v_S: np.ndarray, T_BS: np.ndarray, omega_B: np.ndarray) -> np.ndarray:
    """The DVL measurement residual in the DVL frame: R_SB (v_B + ω × t_BS) − v_S (for tests)."""
    R_BS, t_BS = T_BS[:3, :3], T_BS[:3, 3]
    return R_BS.T @ (v_B + np.cross(omega_B, t_BS)) - v_S


def dvl_velocity_factor(
    key: int, v_S: np.ndarray, cov_S: np.ndarray, T_BS: np.ndarray, omega_B=None, extra_var: float = 0.0
) -> gtsam.NonlinearFactor:
    """DVL factor on the body velocity V(k): built-in PriorFactorVector on v_B.

    Equivalent to the lever-arm residual :func:`dvl_residual` whitened by Σ_S (the map is affine
    and R_BS orthogonal, so the Mahalanobis norms are identical). ``extra_var`` (m²/s²) inflates
    it isotropically, e.g. σ_a²·age for a reading ``age`` seconds older than the keyframe.
    """
    v_B, cov_B = dvl_to_body(v_S, cov_S, T_BS, omega_B)
    cov_B = cov_B + extra_var * np.eye(3)
    return gtsam.PriorFactorVector(key, v_B, gtsam.noiseModel.Gaussian.Covariance(cov_B))


def velocity_random_walk_factor(key_i: int, key_j: int, dt: float, accel_sigma: float) -> gtsam.NonlinearFactor:
    """Motion model on the body velocity: v_j − v_i ~ N(0, σ_a² Δt I) (built-in BetweenFactorVector)."""
    sigma = accel_sigma * np.sqrt(max(dt, 1e-6))
    return gtsam.BetweenFactorVector(key_i, key_j, np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, sigma))


# --------------------------------------------------------------------------------------------
# Preintegration between keyframes


@dataclass
class DisplacementIntegral:
    """The displacement of the body origin between keyframes i and j, in {B_i}:

        R_iᵀ (p_j − p_i) = c + A v_i + B v_j + n,   n ~ N(0, Σ).

    ``c`` collects the DVL samples inside (t_i, t_j]; A and B weight the keyframe velocity states
    over the segments before the first and after the last sample (the whole interval in a dropout).
    """

    dt: float
    c: np.ndarray
    A: np.ndarray
    B: np.ndarray
    cov: np.ndarray
    n_samples: int
    last_sample_age: float | None  # t_j − stamp of the last DVL sample (None: no sample)
    last_sample: tuple[np.ndarray, np.ndarray] | None  # (v_B, Σ_B) of the last sample


# Unmodelled error of any displacement, however short (DVL time stamps, lever arm, the trapezoid
# rule): without it two keyframes 37 ms apart were tied by σ = 0.1 mm, and iSAM2 found the system
# indeterminate (sonar field mission, seed 0). Over a normal 2 s interval σ is ~7 mm: 1 mm in
# quadrature changes it by 1 %.
MIN_DISPLACEMENT_SIGMA_M = 1e-3


class DvlPreintegrator:
    """Integrates DVL body velocities with AHRS relative rotations from keyframe i on.

    The velocity profile is piecewise linear through the knots (v_i at t_i, every valid DVL sample,
    v_j at t_j) and the position integral uses the trapezoid rule, rotating each knot into {B_i}
    with the AHRS: ∫ R_i(t) v(t) dt ≈ Σ_knots w_k ΔR_k v_k with w_k = (t_{k+1} − t_{k−1}) / 2.
    Deviations of the true velocity from the linear interpolant between two knots Δt apart are a
    Brownian bridge whose integral has variance σ_a² Δt³ / 12 per axis; that is the motion-model
    noise, and over a dropout (no knot) it grows with the cube of the gap.

    The rotation into {B_i}: R_iᵀ R(t) from the AHRS readings (``R_i`` and each sample's ``R_WB``, each with
    its own error of σ ``attitude_sigma``), or, when every sample of the interval and its end come with the
    gyro's rotation since t_i (``dR_gyro`` of :meth:`add`, ``dR_j`` of :meth:`integrate` and :meth:`smoothed`),
    that one: the gyro's rates integrated since the keyframe, whose error is the rate noise integrated from
    t_i, a random walk of density ``rate_density`` common to the samples that follow (the readings' error
    of R_i is common to every sample of the interval and is no random walk of the keyframe's state).
    """

    def __init__(
        self, t_i: float, R_i: np.ndarray, accel_sigma: float, attitude_sigma: float = 0.0, rate_density: float = 0.0
    ):
        self.t_i = t_i
        self.R_i_T = np.asarray(R_i).T
        self.accel_sigma = accel_sigma
        self.attitude_sigma = attitude_sigma
        self.rate_density = rate_density  # the gyro's white rate noise (rad/s/√Hz), for its rotations
        self._t: list[float] = []
        self._dR: list[np.ndarray] = []
        self._dR_gyro: list[np.ndarray | None] = []
        self._v: list[np.ndarray] = []
        self._cov: list[np.ndarray] = []

    def add(
        self, t: float, R_WB: np.ndarray, v_B: np.ndarray, cov_B: np.ndarray, dR_gyro: np.ndarray | None = None
    ) -> None:
        """A valid DVL sample (already in the body frame, :func:`dvl_to_body`) at time t (s), with the AHRS's
        attitude R_WB at t and, when known, the gyro's rotation R_iᵀ R(t) since the keyframe."""
        if t <= self.t_i or (self._t and t <= self._t[-1]):
            return  # out of order or at the keyframe itself: the keyframe's own prior carries it
        self._t.append(t)
        self._dR.append(self.R_i_T @ R_WB)
        self._dR_gyro.append(dR_gyro)
        self._v.append(np.asarray(v_B, float))
        self._cov.append(np.asarray(cov_B, float))

    def drop_last(self) -> None:
        """Forget the newest sample (used when it becomes the next keyframe's velocity factor)."""
        for lst in (self._t, self._dR, self._dR_gyro, self._v, self._cov):
            lst.pop()

    def _by_gyro(self, dR_j: np.ndarray | None) -> bool:
        """Whether the interval's samples are turned by the gyro: its rotation to the end and to every sample."""
        return dR_j is not None and all(d is not None for d in self._dR_gyro)

    def _gyro_rotation_cov(self, w_u: np.ndarray, dR: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The displacement's covariance from the gyro's rotation error, the samples (the gyro's rotations ``dR``,
        M×3×3, velocities ``v``, M×3) weighted by ``w_u``: the rate noise integrated since t_i, θ(t_k) =
        Σ_{m≤k} η_m with η_m ~ N(0, q (t_m − t_{m−1}) I), turns sample k by δ = −w_k ΔR_k [v_k]× θ(t_k), so
        Σ = Σ_m q (t_m − t_{m−1}) T_m T_mᵀ with T_m the sum of w_k ΔR_k [v_k]× over k ≥ m (the samples after
        a step share it)."""
        T = np.cumsum((w_u[:, None, None] * (dR @ skew_batch(v)))[::-1], axis=0)[::-1]
        steps = np.diff(np.r_[self.t_i, self._t]) * self.rate_density**2
        return np.sum(steps[:, None, None] * (T @ T.transpose(0, 2, 1)), axis=0)

    @property
    def last_stamp(self) -> float | None:
        return self._t[-1] if self._t else None

    @property
    def n_samples(self) -> int:
        return len(self._t)

    def integrate(self, t_j: float, R_j: np.ndarray, dR_j: np.ndarray | None = None) -> DisplacementIntegral:
        """The displacement to t_j, where the AHRS's attitude is ``R_j`` and the gyro's rotation since t_i
        ``dR_j`` (None: no gyro's; the samples are then turned by the readings)."""
        dt = t_j - self.t_i
        knots_t = np.array([self.t_i, *self._t, t_j])
        seg = np.diff(knots_t)
        w = np.zeros(len(knots_t))
        w[:-1] += seg / 2
        w[1:] += seg / 2
        gyro = self._by_gyro(dR_j)
        dR_j = dR_j if gyro else self.R_i_T @ R_j
        c = np.zeros(3)
        cov = np.eye(3) * (self.accel_sigma**2 * float(np.sum(seg**3)) / 12.0 + MIN_DISPLACEMENT_SIGMA_M**2)
        for k in range(len(self._t)):
            wk, dR, v = w[k + 1], (self._dR_gyro if gyro else self._dR)[k], self._v[k]
            c += wk * (dR @ v)
            cov += wk**2 * (dR @ self._cov[k] @ dR.T)
            if self.attitude_sigma > 0 and not gyro:  # attitude noise rotates the sample: δ = −ΔR [v]× δθ
                Sv = dR @ skew(v)
                cov += wk**2 * self.attitude_sigma**2 * (Sv @ Sv.T)
        if gyro and self._t:
            cov += self._gyro_rotation_cov(w[1:-1], np.array(self._dR_gyro), np.array(self._v))
        last = (self._v[-1], self._cov[-1]) if self._t else None
        return DisplacementIntegral(
            dt=dt,
            c=c,
            A=w[0] * np.eye(3),
            B=w[-1] * dR_j,
            cov=cov,
            n_samples=len(self._t),
            last_sample_age=(t_j - self._t[-1]) if self._t else None,
            last_sample=last,
        )

    def smoothed(self, t_j: float, R_j: np.ndarray, dR_j: np.ndarray | None = None) -> SmoothedInterval:
        """The interval as the whole Wiener-velocity model sees it: the displacement δ = R_iᵀ(p_j − p_i)
        and the velocity states v_i, v_j jointly, every DVL sample inside informing both.

        :meth:`integrate` takes each sample as the velocity at its time (a knot), so the samples say
        nothing about v_i and v_j: a velocity state is the one reading at its keyframe, and across a
        dropout the ramp between the two readings at its edges holds their noise over the gap. Here
        the true velocities u_m at the samples' times are latent: the samples measure them (σ of the
        DVL), the displacement is the trapezoid over (v_i, u_1 … u_M, v_j) plus the Brownian bridges
        between the knots (σ_a² Σ seg³ / 12, independent of the knot values), and the velocity is a
        random walk of density σ_a through v_i, u_1 … u_M, v_j. The u_m are eliminated exactly (a
        linear Gaussian Schur complement): what is left is a Gaussian on z = [δ, v_i, v_j], whitened
        as r = Cᵀ (z − z0). Without samples it would be :meth:`integrate`'s displacement with the velocity
        random walk between v_i and v_j, of rank 6 (nothing absolute in z): for intervals with samples only.
        ``R_j``, ``dR_j``: as :meth:`integrate`'s."""
        dt = t_j - self.t_i
        knots_t = np.array([self.t_i, *self._t, t_j])
        seg = np.diff(knots_t)  # the trapezoid's weights sum to t_j − t_i exactly, a sample at t_j itself included
        w = np.zeros(len(knots_t))
        w[:-1] += seg / 2
        w[1:] += seg / 2
        M = len(self._t)
        if not M:
            raise ValueError("no DVL sample in the interval: use integrate() and the velocity random walk")
        n = 9 + 3 * M  # y = [δ, v_i, v_j, u_1 … u_M]
        q = self.accel_sigma**2
        cov_d = np.eye(3) * (q * float(np.sum(seg**3)) / 12.0 + MIN_DISPLACEMENT_SIGMA_M**2)
        # the samples at once (stacked: numpy's per-call overhead on 3×3 blocks was most of the time)
        gyro = self._by_gyro(dR_j)
        dR, v, w_u = np.array(self._dR_gyro if gyro else self._dR), np.array(self._v), w[1:-1]
        J = np.zeros((3, n))
        J[:, 0:3] = np.eye(3)
        J[:, 3:6] = -w[0] * np.eye(3)
        J[:, 6:9] = -w[-1] * (dR_j if gyro else self.R_i_T @ R_j)
        J[:, 9:] = (-w_u[:, None, None] * dR).transpose(1, 0, 2).reshape(3, 3 * M)
        if gyro:
            cov_d += self._gyro_rotation_cov(w_u, dR, v)
        elif self.attitude_sigma > 0:  # attitude noise rotates the sample: δ = −ΔR [v]× δθ
            Sv = dR @ skew_batch(v)
            cov_d += self.attitude_sigma**2 * np.sum((w_u**2)[:, None, None] * (Sv @ Sv.transpose(0, 2, 1)), axis=0)
        info = np.linalg.inv(np.array(self._cov))
        H = np.zeros((n, n))
        for m in range(M):
            H[9 + 3 * m : 12 + 3 * m, 9 + 3 * m : 12 + 3 * m] = info[m]
        g = np.zeros(n)
        g[9:] = (info @ v[:, :, None]).ravel()
        H += J.T @ np.linalg.solve(cov_d, J)
        # the random walk, knot to knot along v_i, u_1 … u_M, v_j: k = 1/(σ_a² Δt) on each knot's
        # diagonal per neighbour, −k between neighbours
        pos = np.r_[3, 9 + 3 * np.arange(M), 6]
        k = 1.0 / (q * np.maximum(seg, 1e-3))  # a sample at t_j itself: a stiff, not singular, link
        diag = np.zeros(M + 2)
        diag[:-1] += k
        diag[1:] += k
        for i in range(3):
            H[pos + i, pos + i] += diag
            H[pos[:-1] + i, pos[1:] + i] -= k
            H[pos[1:] + i, pos[:-1] + i] -= k
        Huu_inv_Huz = np.linalg.solve(H[9:, 9:], np.column_stack([H[9:, :9], g[9:]]))
        Lam = H[:9, :9] - H[:9, 9:] @ Huu_inv_Huz[:, :9]
        eta = g[:9] - H[:9, 9:] @ Huu_inv_Huz[:, 9]
        Lam = 0.5 * (Lam + Lam.T)
        return SmoothedInterval(dt=dt, z0=np.linalg.solve(Lam, eta), C_T=np.linalg.cholesky(Lam).T, n_samples=M)


@dataclass
class SmoothedInterval:
    """A Gaussian on z = [δ, v_i, v_j] (δ = R_iᵀ(p_j − p_i)): ‖Cᵀ (z − z0)‖² (:meth:`DvlPreintegrator.smoothed`)."""

    dt: float
    z0: np.ndarray
    C_T: np.ndarray
    n_samples: int


def smoothed_displacement_factor(xi: int, xj: int, vi: int, vj: int, s: SmoothedInterval) -> gtsam.CustomFactor:
    """The interval's displacement and velocity states jointly (CustomFactor on X_i, X_j, V_i, V_j, a
    9-dimensional whitened residual Cᵀ (z − z0)); replaces :func:`displacement_factor` and the
    velocity random walk between V_i and V_j. The callback takes δ and its Jacobians
    (:func:`relative_position`) in scalar arithmetic; the same numbers (tested)."""
    C_T = np.asarray(s.C_T, float)
    C_d, z0 = C_T[:, 0:3].copy(), np.asarray(s.z0, float)
    H_vi, H_vj = C_T[:, 3:6].copy(), C_T[:, 6:9].copy()

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H):
        # :func:`relative_position` in scalars (numpy's per-call overhead on 3-vectors dominated it)
        (R00, R01, R02, ti0), (R10, R11, R12, ti1), (R20, R21, R22, ti2), _ = values.atPose3(xi).matrix().tolist()
        (S00, S01, S02, tj0), (S10, S11, S12, tj1), (S20, S21, S22, tj2), _ = values.atPose3(xj).matrix().tolist()
        d0, d1, d2 = tj0 - ti0, tj1 - ti1, tj2 - ti2
        x = R00 * d0 + R10 * d1 + R20 * d2  # δ = R_iᵀ (p_j − p_i)
        y = R01 * d0 + R11 * d1 + R21 * d2
        z = R02 * d0 + R12 * d1 + R22 * d2
        r = np.dot(C_T, np.array([x, y, z, *values.atVector(vi).tolist(), *values.atVector(vj).tolist()]) - z0)
        if H is not None:
            m00, m01, m02, m10, m11, m12, m20, m21, m22 = mat3_mul(
                (R00, R10, R20, R01, R11, R21, R02, R12, R22), (S00, S01, S02, S10, S11, S12, S20, S21, S22)
            )  # R_iᵀ R_j
            H[0] = np.dot(
                C_d,
                np.array([[0.0, -z, y, -1.0, 0.0, 0.0], [z, 0.0, -x, 0.0, -1.0, 0.0], [-y, x, 0.0, 0.0, 0.0, -1.0]]),
            )
            H[1] = np.dot(
                C_d,
                np.array(
                    [[0.0, 0.0, 0.0, m00, m01, m02], [0.0, 0.0, 0.0, m10, m11, m12], [0.0, 0.0, 0.0, m20, m21, m22]]
                ),
            )
            H[2], H[3] = H_vi, H_vj
        return r

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(9), [xi, xj, vi, vj], error)


def displacement_residual(T_i: gtsam.Pose3, T_j: gtsam.Pose3, v_i, v_j, d: DisplacementIntegral, jac: bool = False):
    """r = R_iᵀ (p_j − p_i) − c − A v_i − B v_j and, with ``jac``, its Jacobians
    (3×6 wrt X_i, 3×6 wrt X_j, 3×3 wrt V_i, 3×3 wrt V_j)."""
    delta, H_i, H_j = relative_position(T_i, T_j)
    r = delta - d.c - d.A @ v_i - d.B @ v_j
    if not jac:
        return r
    return r, (H_i, H_j, -d.A, -d.B)


def relative_position(T_i: gtsam.Pose3, T_j: gtsam.Pose3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """δ = R_iᵀ (p_j − p_i), the position of X_j in {B_i}, and its Jacobians (3×6) wrt X_i and X_j."""
    Ri = T_i.rotation().matrix()
    delta = Ri.T @ (T_j.translation() - T_i.translation())
    H_i = np.hstack([skew(delta), -np.eye(3)])
    H_j = np.hstack([np.zeros((3, 3)), Ri.T @ T_j.rotation().matrix()])
    return delta, H_i, H_j


def displacement_factor(xi: int, xj: int, vi: int, vj: int, d: DisplacementIntegral) -> gtsam.CustomFactor:
    """Preintegrated DVL/AHRS displacement between keyframes (CustomFactor on X_i, X_j, V_i, V_j).

    No built-in expresses a position-only displacement in {B_i} with velocity states; the
    rotations are left to the absolute AHRS factors so that the AHRS is not counted twice.
    The callback is :func:`displacement_residual` written out in scalar arithmetic (iSAM2 calls
    it for every relinearised keyframe, and numpy's per-call overhead on 3-vectors dominated it),
    with the constant Jacobians −A, −B made once. Same numbers (tested).
    """
    c0, c1, c2 = np.asarray(d.c, float).tolist()
    (A00, A01, A02), (A10, A11, A12), (A20, A21, A22) = np.asarray(d.A, float).tolist()
    (B00, B01, B02), (B10, B11, B12), (B20, B21, B22) = np.asarray(d.B, float).tolist()
    H_vi, H_vj = -np.array(d.A, float), -np.array(d.B, float)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H):
        (R00, R01, R02, ti0), (R10, R11, R12, ti1), (R20, R21, R22, ti2), _ = values.atPose3(xi).matrix().tolist()
        (S00, S01, S02, tj0), (S10, S11, S12, tj1), (S20, S21, S22, tj2), _ = values.atPose3(xj).matrix().tolist()
        a0, a1, a2 = values.atVector(vi).tolist()
        b0, b1, b2 = values.atVector(vj).tolist()
        d0, d1, d2 = tj0 - ti0, tj1 - ti1, tj2 - ti2
        x = R00 * d0 + R10 * d1 + R20 * d2  # δ = R_iᵀ (p_j − p_i)
        y = R01 * d0 + R11 * d1 + R21 * d2
        z = R02 * d0 + R12 * d1 + R22 * d2
        r = np.array(
            [
                x - c0 - (A00 * a0 + A01 * a1 + A02 * a2) - (B00 * b0 + B01 * b1 + B02 * b2),
                y - c1 - (A10 * a0 + A11 * a1 + A12 * a2) - (B10 * b0 + B11 * b1 + B12 * b2),
                z - c2 - (A20 * a0 + A21 * a1 + A22 * a2) - (B20 * b0 + B21 * b1 + B22 * b2),
            ]
        )
        if H is None:
            return r
        H[0] = np.array(
            [[0.0, -z, y, -1.0, 0.0, 0.0], [z, 0.0, -x, 0.0, -1.0, 0.0], [-y, x, 0.0, 0.0, 0.0, -1.0]]
        )  # [[δ]×, −I]
        H[1] = np.array(  # [0, R_iᵀ R_j]
            [
                [
                    0.0,
                    0.0,
                    0.0,
                    R00 * S00 + R10 * S10 + R20 * S20,
                    R00 * S01 + R10 * S11 + R20 * S21,
                    R00 * S02 + R10 * S12 + R20 * S22,
                ],
                [
                    0.0,
                    0.0,
                    0.0,
                    R01 * S00 + R11 * S10 + R21 * S20,
                    R01 * S01 + R11 * S11 + R21 * S21,
                    R01 * S02 + R11 * S12 + R21 * S22,
                ],
                [
                    0.0,
                    0.0,
                    0.0,
                    R02 * S00 + R12 * S10 + R22 * S20,
                    R02 * S01 + R12 * S11 + R22 * S21,
                    R02 * S02 + R12 * S12 + R22 * S22,
                ],
            ]
        )
        H[2] = H_vi
        H[3] = H_vj
        return r

    return gtsam.CustomFactor(gtsam.noiseModel.Gaussian.Covariance(d.cov), [xi, xj, vi, vj], error)


# --------------------------------------------------------------------------------------------
# AHRS


def ahrs_body_rotation(R_WS: np.ndarray, cov_rpy: np.ndarray, R_BS: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R_WB = R_WS R_BSᵀ from an AHRS reading and the covariance of its right-tangent error.

    The AHRS covariance is over (roll, pitch, yaw) of R_WS; the Euler-rate matrix E maps it to the
    sensor-frame angle error (R_WS → R_WS Exp(E δ)), and R_WB → R_WB Exp(R_BS E δ).
    """
    roll, pitch = rot_to_roll_pitch(R_WS)
    J = np.dot(R_BS, euler_zyx_rate_matrix(roll, pitch))  # np.dot: a third of `@`'s time on 3×3
    return np.dot(R_WS, R_BS.T), np.dot(np.dot(J, cov_rpy), J.T)


def attitude_factor(key: int, R_WB: np.ndarray, cov_tangent: np.ndarray) -> gtsam.NonlinearFactor:
    """AHRS roll, pitch and heading on X(k): built-in PoseRotationPrior3D (rotation part only)."""
    return gtsam.PoseRotationPrior3D(key, gtsam.Rot3(R_WB), gtsam.noiseModel.Gaussian.Covariance(cov_tangent))


def rotation_carry_factor(
    xi: int, xj: int, R_ij: np.ndarray, t_ij: np.ndarray, rot_sigma: float
) -> gtsam.NonlinearFactor:
    """X(j)'s rotation carried from X(i) by the angular rate ``R_ij`` = R_iᵀ R_j (the body rates integrated
    between the two keyframes, or the AHRS's last reading carried when none arrived between them; built-in
    BetweenFactorPose3, rotation σ ``rot_sigma``). Its translation part, ``t_ij`` at σ 1 km, carries no
    information: the displacement factor holds the translation."""
    sigmas = np.r_[[max(rot_sigma, 1e-6)] * 3, [1e3] * 3]
    return gtsam.BetweenFactorPose3(
        xi, xj, gtsam.Pose3(gtsam.Rot3(R_ij), np.asarray(t_ij, float)), gtsam.noiseModel.Diagonal.Sigmas(sigmas)
    )


# The gyro bias's state G(k) is held in rad per GYRO_BIAS_UNIT_S seconds (β = b τ): a bias in rad/s is
# ~10⁻⁵–10⁻⁴ and its random walk's information ~10¹⁴ beside a position's ~10⁴ (as the heading bias's rate).
GYRO_BIAS_UNIT_S = 100.0


def gyro_rotation_residual(
    T_i: gtsam.Pose3, T_j: gtsam.Pose3, g: np.ndarray, R_ij: np.ndarray, J_b: np.ndarray, b_bar: np.ndarray, jac=False
):
    """r = Log((ΔR̄ Exp(J_b (g − b̄)/τ))ᵀ R_iᵀ R_j): the body rates integrated with the bias b̄/τ (``R_ij`` =
    ΔR̄) corrected to first order for the bias g/τ (g and b̄ in rad per τ = GYRO_BIAS_UNIT_S s, body axes),
    J_b = ∂ΔR/∂b (b in rad/s) from the integration (right perturbation, as IMU preintegration has it:
    ΔR(b̄ + δ) ≈ ΔR̄ Exp(J_b δ)). Jacobians 3×6 wrt X(i), X(j) (right perturbation, rotation first) and
    3×3 wrt g."""
    Ri, Rj = T_i.rotation().matrix(), T_j.rotation().matrix()
    J_b = np.asarray(J_b) / GYRO_BIAS_UNIT_S
    H_exp = np.zeros((3, 3), order="F")
    A = gtsam.Rot3.Expmap(-J_b @ (np.asarray(g, float) - b_bar), H_exp).matrix()  # Exp(J_b δ)ᵀ
    E = np.asarray(R_ij).T @ Ri.T @ Rj
    H_log = np.zeros((3, 3), order="F")
    r = np.asarray(gtsam.Rot3.Logmap(gtsam.Rot3(A @ E), H_log), float)
    if not jac:
        return r
    H_i, H_j = np.zeros((3, 6)), np.zeros((3, 6))
    H_i[:, :3] = -H_log @ Rj.T @ Ri
    H_j[:, :3] = H_log
    H_g = -H_log @ E.T @ H_exp @ J_b
    return r, H_i, H_j, H_g


# [I, 0]: a rotation's Jacobian block placed in a pose's (rotation first): H_log [I, 0] = [H_log, 0] in one product
_ROTATION_BLOCK = np.hstack([np.eye(3), np.zeros((3, 3))])


def _exp_coefficients(t2: float) -> tuple[float, float, float]:
    """sin θ/θ, (1 − cos θ)/θ², (θ − sin θ)/θ³ at θ² = t2 (their series below θ = 1e-2, where the closed forms
    cancel: the terms left out are below 1e-16 relative)."""
    if t2 < 1e-4:
        return (
            1.0 - t2 / 6.0 + t2 * t2 / 120.0,
            0.5 - t2 / 24.0 + t2 * t2 / 720.0,
            1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0,
        )
    t = math.sqrt(t2)
    s = math.sin(t)
    return s / t, (1.0 - math.cos(t)) / t2, (t - s) / (t2 * t)


def gyro_rotation_factor(
    xi: int, xj: int, g: int, R_ij: np.ndarray, J_b: np.ndarray, b_bar: np.ndarray, rot_sigma: float
) -> gtsam.CustomFactor:
    """X(j)'s rotation carried from X(i) by the body rates integrated between the two keyframes, with the
    gyro's bias G(i) (a 3-vector in rad per GYRO_BIAS_UNIT_S s, body axes; ``b_bar`` too) estimated: :func:`gyro_rotation_residual` at σ
    ``rot_sigma`` a rotation axis (CustomFactor: GTSAM's AHRSFactor holds the same residual on Rot3 keys,
    not on our Pose3 ones).

    The callback is :func:`gyro_rotation_residual` with Exp(−J_b (g − b̄)/τ) ΔR̄ᵀ R_iᵀ R_j written out in scalar
    arithmetic and the Jacobians' 3×3 products by ``np.dot`` (numpy's per-call overhead on 3×3 matrices, and
    ``@``'s above ``np.dot``'s, dominated it); the same numbers (tested)."""
    J = np.array(J_b, float) / GYRO_BIAS_UNIT_S
    (J00, J01, J02), (J10, J11, J12), (J20, J21, J22) = J.tolist()
    minus_J = tuple((-J).ravel().tolist())
    dR_bar_T = tuple(np.array(R_ij, float).T.ravel().tolist())
    c0, c1, c2 = np.array(b_bar, float).tolist()

    def error(this, values, H):
        (a00, a01, a02, _), (a10, a11, a12, _), (a20, a21, a22, _), _ = values.atPose3(xi).matrix().tolist()
        (b00, b01, b02, _), (b10, b11, b12, _), (b20, b21, b22, _), _ = values.atPose3(xj).matrix().tolist()
        d0, d1, d2 = values.atVector(g).tolist()
        d0, d1, d2 = d0 - c0, d1 - c1, d2 - c2
        # φ = −J (g − b̄): Exp(φ) = Exp(J δ)ᵀ
        p0 = -(J00 * d0 + J01 * d1 + J02 * d2)
        p1 = -(J10 * d0 + J11 * d1 + J12 * d2)
        p2 = -(J20 * d0 + J21 * d1 + J22 * d2)
        s, a, bq = _exp_coefficients(p0 * p0 + p1 * p1 + p2 * p2)
        # Exp(φ) = I + s K + a K² with K = [φ]×, K² = φφᵀ − θ² I
        exp_phi = (
            *(1.0 - a * (p1 * p1 + p2 * p2), a * p0 * p1 - s * p2, a * p0 * p2 + s * p1),
            *(a * p0 * p1 + s * p2, 1.0 - a * (p0 * p0 + p2 * p2), a * p1 * p2 - s * p0),
            *(a * p0 * p2 - s * p1, a * p1 * p2 + s * p0, 1.0 - a * (p0 * p0 + p1 * p1)),
        )
        M = mat3_mul((a00, a10, a20, a01, a11, a21, a02, a12, a22), (b00, b01, b02, b10, b11, b12, b20, b21, b22))
        E = mat3_mul(dR_bar_T, M)  # ΔR̄ᵀ R_iᵀ R_j
        F = gtsam.Rot3(*mat3_mul(exp_phi, E))
        if H is None:
            return gtsam.Rot3.Logmap(F)
        H_log = np.zeros((3, 3), order="F")
        r = gtsam.Rot3.Logmap(F, H_log)
        m00, m01, m02, m10, m11, m12, m20, m21, m22 = M
        H[0] = np.dot(  # [−H_log R_jᵀ R_i, 0]
            H_log,
            np.array(
                [
                    [-m00, -m10, -m20, 0.0, 0.0, 0.0],
                    [-m01, -m11, -m21, 0.0, 0.0, 0.0],
                    [-m02, -m12, -m22, 0.0, 0.0, 0.0],
                ]
            ),
        )
        H[1] = np.dot(H_log, _ROTATION_BLOCK)  # [H_log, 0]
        # −H_log Eᵀ J_r(φ) J with J_r(φ) = I − a K + b K²
        Jr = (
            *(1.0 - bq * (p1 * p1 + p2 * p2), a * p2 + bq * p0 * p1, -a * p1 + bq * p0 * p2),
            *(-a * p2 + bq * p0 * p1, 1.0 - bq * (p0 * p0 + p2 * p2), a * p0 + bq * p1 * p2),
            *(a * p1 + bq * p0 * p2, -a * p0 + bq * p1 * p2, 1.0 - bq * (p0 * p0 + p1 * p1)),
        )
        e00, e01, e02, e10, e11, e12, e20, e21, e22 = E
        T = mat3_mul(mat3_mul((e00, e10, e20, e01, e11, e21, e02, e12, e22), Jr), minus_J)
        H[2] = np.dot(H_log, np.array([T[0:3], T[3:6], T[6:9]]))
        return r

    noise = gtsam.noiseModel.Isotropic.Sigma(3, max(rot_sigma, 1e-6))
    return gtsam.CustomFactor(noise, [xi, xj, g], error)


def biased_attitude_residual(T_WB: gtsam.Pose3, b: float, R_meas: np.ndarray, jac: bool = False):
    """r = Log(R_measᵀ Rz(b) R_WB): an AHRS whose heading reads the true one plus a bias b (rad)
    about the world's vertical, R_meas = Rz(b) R_WB. Jacobians 3×6 wrt X (right perturbation,
    rotation first) and 3×1 wrt b (Rz(b + δ) = Rz(b) Exp(δ e_z), carried to the right by R_WBᵀ)."""
    R = T_WB.rotation().matrix()
    c, s = np.cos(b), np.sin(b)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    E = R_meas.T @ Rz @ R
    H_log = np.zeros((3, 3), order="F")
    r = np.asarray(gtsam.Rot3.Logmap(gtsam.Rot3(E), H_log), float)
    if not jac:
        return r
    H_x = np.hstack([H_log, np.zeros((3, 3))])
    H_b = (H_log @ R.T @ np.array([0.0, 0.0, 1.0])).reshape(3, 1)
    return r, H_x, H_b


def biased_attitude_factor(x: int, b: int, R_meas: np.ndarray, cov_tangent: np.ndarray) -> gtsam.CustomFactor:
    """AHRS attitude on X(k) with the heading bias B(k) (a 1-vector) estimated beside it
    (CustomFactor: no built-in rotation prior has a bias about a fixed world axis).

    The callback is :func:`biased_attitude_residual` with R_measᵀ Rz(b) R_WB written out in scalar
    arithmetic (numpy's per-call overhead on 3×3 matrices dominated it); the same numbers (tested)."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = np.asarray(R_meas, float).T.tolist()  # R_measᵀ

    def error(this, values, H):
        (R00, R01, R02, _), (R10, R11, R12, _), (R20, R21, R22, _), _ = values.atPose3(x).matrix().tolist()
        bias = float(values.atVector(b)[0])
        c, s = math.cos(bias), math.sin(bias)
        # N = R_measᵀ Rz(b): columns (c m₀ + s m₁, c m₁ − s m₀, m₂) of R_measᵀ's columns m₀, m₁, m₂
        n00, n01 = c * m00 + s * m01, c * m01 - s * m00
        n10, n11 = c * m10 + s * m11, c * m11 - s * m10
        n20, n21 = c * m20 + s * m21, c * m21 - s * m20
        E = gtsam.Rot3(
            *mat3_mul((n00, n01, m02, n10, n11, m12, n20, n21, m22), (R00, R01, R02, R10, R11, R12, R20, R21, R22))
        )
        if H is None:
            return gtsam.Rot3.Logmap(E)
        H_log = np.zeros((3, 3), order="F")
        r = gtsam.Rot3.Logmap(E, H_log)
        H[0] = np.dot(H_log, _ROTATION_BLOCK)  # [H_log, 0]
        H[1] = np.dot(H_log, np.array([[R20], [R21], [R22]]))  # R_WBᵀ e_z = third row of R_WB
        return r

    return gtsam.CustomFactor(gtsam.noiseModel.Gaussian.Covariance(np.asarray(cov_tangent, float)), [x, b], error)


def heading_bias_walk_factor(b_i: int, b_j: int, dt: float, walk_sigma: float) -> gtsam.NonlinearFactor:
    """The heading bias as a random walk: b_j − b_i ~ N(0, σ_b² Δt) (built-in BetweenFactorVector)."""
    sigma = walk_sigma * np.sqrt(max(dt, 1e-6))
    return gtsam.BetweenFactorVector(b_i, b_j, np.zeros(1), gtsam.noiseModel.Isotropic.Sigma(1, max(sigma, 1e-9)))


def heading_bias_drift_factor(
    b_i: int, d_i: int, b_j: int, d_j: int, dt: float, walk_sigma: float, rate_walk_sigma: float
) -> gtsam.CustomFactor:
    """The heading bias with a drift rate: b_j = b_i + r_i Δt + walk, ρ_j = ρ_i + walk (ρ = r τ, in rad
    per τ = RATE_UNIT_S seconds; the keys D(k) hold ρ). Linear; covariance
    :func:`heading_bias_drift_covariance`. A learned rate carries the bias on where nothing observes it."""
    a = dt / RATE_UNIT_S
    H_bi, H_di = np.array([[-1.0], [0.0]]), np.array([[-a], [-1.0]])
    H_bj, H_dj = np.array([[1.0], [0.0]]), np.array([[0.0], [1.0]])

    def error(this, values, H):
        bi, di = float(values.atVector(b_i)[0]), float(values.atVector(d_i)[0])
        bj, dj = float(values.atVector(b_j)[0]), float(values.atVector(d_j)[0])
        if H is not None:
            H[0], H[1], H[2], H[3] = H_bi, H_di, H_bj, H_dj
        return np.array([bj - bi - a * di, dj - di])

    cov = heading_bias_drift_covariance(dt, walk_sigma, rate_walk_sigma)
    return gtsam.CustomFactor(gtsam.noiseModel.Gaussian.Covariance(cov), [b_i, d_i, b_j, d_j], error)


# --------------------------------------------------------------------------------------------
# Depth


def depth_residual(T_WB: gtsam.Pose3, t_BS: np.ndarray, depth: float, jac: bool = False):
    """r = [p_W,S]_z − depth with p_W,S = t + R t_BS (the pressure sensor's position); 1×6 Jacobian."""
    R = T_WB.rotation().matrix()
    r = np.array([T_WB.translation()[2] + R[2] @ t_BS - depth])
    if not jac:
        return r
    H = np.hstack([-(R @ skew(t_BS))[2], R[2]]).reshape(1, 6)
    return r, H


def depth_factor(key: int, depth: float, variance: float, t_BS: np.ndarray) -> gtsam.NonlinearFactor:
    """Depth of the pressure sensor on X(k) with its lever arm: built-in GPSFactorArm, whose error
    t + R t_BS − m is the world position of the sensor minus a measured one, with m = (0, 0, depth)
    and zero information on the two horizontal rows (Diagonal precisions (0, 0, 1/σ²)). Its
    whitened error is (0, 0, r/σ) with r = :func:`depth_residual` exactly; a built-in, because the
    CustomFactor it replaces cost ~40 µs per linearisation against a few."""
    return gtsam.GPSFactorArm(
        key,
        np.array([0.0, 0.0, float(depth)]),
        np.asarray(t_BS, float),
        gtsam.noiseModel.Diagonal.Precisions(np.array([0.0, 0.0, 1.0 / float(variance)])),
    )


def _hold_integral(kt: list[float], t: float) -> list[float]:
    """F with F · v = ∫_{kt[0]}^{t} v(s) ds, v linear between the knots (times ``kt``, increasing, values v)
    and held at the end values outside them (signed: t < kt[0] gives a negative integral): a knot's
    full hat up to the interval that holds t, the partial trapezoid of that interval."""
    n = len(kt)
    if n == 1 or t <= kt[0]:
        return [t - kt[0]] + [0.0] * (n - 1)
    hs = [kt[m + 1] - kt[m] for m in range(n - 1)]
    full = [(hs[j - 1] if j else 0.0) / 2 + hs[j] / 2 for j in range(n - 1)]
    if t >= kt[-1]:
        return [*full, hs[-1] / 2 + (t - kt[-1])]
    i = bisect.bisect_right(kt, t) - 1  # kt[i] <= t < kt[i + 1]
    h = hs[i]
    lam = (t - kt[i]) / h
    F = full[:i] + [0.0] * (n - i)
    F[i] = (hs[i - 1] / 2 if i else 0.0) + h * (lam - lam * lam / 2)
    F[i + 1] = h * lam * lam / 2
    return F


def hold_interp_weights(knots_t: np.ndarray, t_from: float, t_to: float) -> np.ndarray:
    """w with ∫_{t_from}^{t_to} v(t) dt = w · v, v(t) linear between the knots (times ``knots_t``,
    increasing, values v) and held at the end values outside them; signed (t_to < t_from: −w)."""
    kt = [float(k) for k in knots_t]
    return np.subtract(_hold_integral(kt, float(t_to)), _hold_integral(kt, float(t_from)))


def referred_depth(
    readings: list[tuple[float, float, float, np.ndarray]],
    t_key: float,
    R_key: np.ndarray,
    t_BS: np.ndarray,
    knots: list[tuple[float, float, float]],
    accel_sigma: float,
) -> tuple[float, float]:
    """Depth readings (t, depth, variance, R_WB at t) of the pressure sensor at ``t_BS`` brought to
    ``t_key`` (attitude ``R_key``) and averaged: each reading plus the vertical displacement from its
    time to t_key (∫ v_z dt, v_z the world vertical velocity of the DVL samples ``knots`` (t, v_z,
    variance), linear between them, held outside; none: v_z = 0 ± 1 cm/s) and the lever arm's change
    [(R_key − R) t_BS]_z. Returns (mean, variance of the mean): the readings' own noise averages down,
    the displacement's is shared (the same DVL samples for every reading) and is kept whole — each
    knot's weight is its mean weight over the readings — as is the motion model's (σ_a² h³/3 over the
    reading's longest stretch h without a knot, plus σ_a² age h² where the stretch lies wholly beyond
    the knots and holds a velocity already ``age`` old, taken as common to all readings: an upper bound).

    Written out over Python floats (a handful of readings and knots a keyframe: numpy's per-call
    overhead, an interpolation per knot and reading, was most of a keyframe update)."""
    t_key = float(t_key)
    x0, x1, x2 = (float(v) for v in t_BS)
    lever_key = float(R_key[2, 0]) * x0 + float(R_key[2, 1]) * x1 + float(R_key[2, 2]) * x2
    info = [1.0 / float(r[2]) for r in readings]
    total = sum(info)
    a = [w / total for w in info]
    t_r = [float(r[0]) for r in readings]
    # each reading, the lever arm's change [(R_key − R) t_BS]_z
    z = [
        float(r[1]) + lever_key - (float(r[3][2, 0]) * x0 + float(r[3][2, 1]) * x1 + float(r[3][2, 2]) * x2)
        for r in readings
    ]
    if knots:
        kt = [float(k[0]) for k in knots]
        vz = [float(k[1]) for k in knots]
        F_key = _hold_integral(kt, t_key)
        w_mean = [0.0] * len(kt)
        h, age = [], []
        for m, t in enumerate(t_r):
            W = [fk - fr for fk, fr in zip(F_key, _hold_integral(kt, t))]  # ∫ from the reading to t_key
            z[m] += sum(w * v for w, v in zip(W, vz))
            w_mean = [acc + a[m] * w for acc, w in zip(w_mean, W)]
            lo, hi = min(t, t_key), max(t, t_key)
            inside = [lo, *kt[bisect.bisect_right(kt, lo) : bisect.bisect_left(kt, hi)], hi]
            h.append(max(q - p for p, q in zip(inside[:-1], inside[1:])))
            # a stretch wholly beyond the knots holds a velocity already that old when it starts
            age.append(max(lo - kt[-1], kt[0] - hi, 0.0))
        var_disp = sum(w * w * float(k[2]) for w, k in zip(w_mean, knots))
    else:
        var_disp = (0.01 * sum(am * abs(t_key - t) for am, t in zip(a, t_r))) ** 2
        h, age = [abs(t_key - t) for t in t_r], [0.0] * len(t_r)
    # the walk over a stretch h from a velocity known `age` before it: σ_a² (h³/3 + age·h²)
    var_model = sum(am * accel_sigma * math.sqrt(hm**3 / 3.0 + ag * hm**2) for am, hm, ag in zip(a, h, age)) ** 2
    var_r = sum(am * am * float(r[2]) for am, r in zip(a, readings))
    return sum(am * zm for am, zm in zip(a, z)), var_r + var_disp + var_model
