"""Landmark factors: object point, pipe line (minimal 4-DoF), CAD structure (6-DoF).

All observations are in the sensor frame {S} of a sensor mounted at T_BS on the body; the
vehicle variable is X = T_WB (gtsam.Pose3, right perturbation ξ = (ω, v)).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from factors.geometry import skew, so3_exp, so3_right_jacobian

# --------------------------------------------------------------------------------------------
# Object point


def point_residual(T_WB: gtsam.Pose3, l_W: np.ndarray, T_BS: np.ndarray, z_S: np.ndarray, jac: bool = False):
    """r = R_BSᵀ (R_WBᵀ (l − t_WB) − t_BS) − z_S; Jacobians 3×6 wrt X and 3×3 wrt l."""
    return point_residual_at(T_WB.rotation().matrix(), T_WB.translation(), l_W, T_BS, z_S, jac)


def point_residual_at(R: np.ndarray, t: np.ndarray, l_W, T_BS: np.ndarray, z_S: np.ndarray, jac: bool = False):
    """:func:`point_residual` from the pose's pieces (R, t), for callers that pair one pose with many
    landmarks."""
    R_SB = T_BS[:3, :3].T
    l_B = (np.asarray(l_W, float) - t) @ R  # R_WBᵀ (l − t)
    r = R_SB @ (l_B - T_BS[:3, 3]) - z_S
    if not jac:
        return r
    H_x = np.empty((3, 6))
    H_x[:, :3] = R_SB @ skew(l_B)
    H_x[:, 3:] = -R_SB
    return r, H_x, R_SB @ R.T


def point_factor(x: int, l: int, z_S, cov_S, T_BS, robust=None) -> gtsam.NonlinearFactor:
    """Object position z_S seen from the sensor: built-in BearingRangeFactor3D on X, L.

    The point is moved into {B} (z_B = R_BS z_S + t_BS, Σ_B = R_BS Σ_S R_BSᵀ, exact: T_BS is
    fixed) and its Cartesian covariance carried to (bearing, range) by J = [Bᵀ / r; uᵀ], with u
    the measured bearing and B its tangent basis (GTSAM's Unit3 local coordinates). To first order
    in σ / r the whitened error equals that of :func:`point_residual` (tested); the laser's 5 mm at
    ≥ 0.2 m is far inside that. A built-in, because the CustomFactor it replaces cost 284 µs per
    linearisation against 13 µs, and relinearisation after a loop closure calls it thousands of
    times."""
    T_BS = np.asarray(T_BS, float)
    R_BS = T_BS[:3, :3]
    z_B = R_BS @ np.asarray(z_S, float) + T_BS[:3, 3]
    r = float(np.linalg.norm(z_B))
    bearing = gtsam.Unit3(z_B)
    basis = np.asarray(bearing.basis())  # 3×2
    J = np.vstack([basis.T / r, (z_B / r)[None]])
    cov = J @ (R_BS @ np.asarray(cov_S, float) @ R_BS.T) @ J.T
    return gtsam.BearingRangeFactor3D(x, l, bearing, r, _noise(0.5 * (cov + cov.T), robust))


# --------------------------------------------------------------------------------------------
# Pipe line


@dataclass(frozen=True)
class LineAnchor:
    """The fixed chart of a line landmark, chosen once at initialisation.

    A line is stored as the 4-vector θ = (α, β, a, b):
        R_L(θ) = R0 · Exp([α, β, 0]),  direction d = R_L e_z,  point on the line c0 + R_L (a, b, 0).
    (α, β) tilt the direction about the anchor point c0; (a, b) shift the line perpendicular to it.
    Four parameters for four degrees of freedom: no gauge (rotation about the line and sliding
    along it are not parameters), so one observed segment gives a full-rank 4×4 system.
    Singularities: the chart covers directions within π of the anchor direction R0 e_z (|(α,β)| = π
    is singular); near the anchor — where the estimate stays, since c0 and R0 come from the
    first observations — it is smooth, and unlike Plücker/(point, direction) forms it has no special
    case for lines through the world origin or parallel to an axis. The observed segment has to
    have non-zero length (its endpoints give the four perpendicular offsets).
    """

    R0: np.ndarray  # 3×3
    c0: np.ndarray  # (3,)

    @staticmethod
    def from_points(p: np.ndarray, q: np.ndarray) -> LineAnchor:
        """Anchor at the midpoint of p, q with e_z along q − p."""
        d = (q - p) / np.linalg.norm(q - p)
        helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        x = np.cross(helper, d)
        x /= np.linalg.norm(x)
        y = np.cross(d, x)
        return LineAnchor(np.column_stack([x, y, d]), 0.5 * (p + q))

    def rotation(self, theta: np.ndarray) -> np.ndarray:
        # The same θ is asked for many times between updates (direction, point, extents): keep the last.
        key = (float(theta[0]), float(theta[1]))
        last = self.__dict__.get("_last")
        if last is not None and last[0] == key:
            return last[1]
        R = self.R0 @ so3_exp(np.array([key[0], key[1], 0.0]))
        R.flags.writeable = False
        object.__setattr__(self, "_last", (key, R))
        return R

    def frame_rows(self, theta):
        """R_L(θ) and the two used columns of J_r at (α, β, 0) as nested lists of floats (rows), for
        the factor callbacks; the last θ is kept (every factor of the landmark asks for the same)."""
        key = (float(theta[0]), float(theta[1]))
        last = self.__dict__.get("_last_rows")
        if last is not None and last[0] == key:
            return last[1]
        phi = np.array([key[0], key[1], 0.0])
        rows = (*(self.R0 @ so3_exp(phi)).tolist(), so3_right_jacobian(phi)[:, :2].tolist())
        object.__setattr__(self, "_last_rows", (key, rows))
        return rows

    def direction(self, theta) -> np.ndarray:
        return self.rotation(theta)[:, 2]

    def point(self, theta) -> np.ndarray:
        """The point of the line closest to c0 (foot of the anchor)."""
        return self.c0 + self.rotation(theta) @ np.array([theta[2], theta[3], 0.0])

    def to_line_frame(self, theta, e_W: np.ndarray) -> np.ndarray:
        """Coordinates of world points (N,3) in the line frame centred at c0."""
        return (np.atleast_2d(e_W) - self.c0) @ self.rotation(theta)


def line_frame(anchor: LineAnchor, theta) -> tuple[np.ndarray, np.ndarray]:
    """R_L(θ) and the two used columns of the right Jacobian of Exp at (α, β, 0)."""
    phi = np.array([theta[0], theta[1], 0.0])
    return anchor.R0 @ so3_exp(phi), so3_right_jacobian(phi)[:, :2]


def line_residual_at(
    R: np.ndarray,
    t: np.ndarray,
    RL: np.ndarray,
    Jr2: np.ndarray,
    c0: np.ndarray,
    ab,
    e_B: np.ndarray,
    jac: bool = False,
):
    """:func:`line_residual` from its pieces: the pose (R, t), the line frame (R_L, J_r columns,
    anchor c0, offsets ab) and the endpoints in the body frame e_B (2×3). Both endpoints at once."""
    e_W = t + e_B @ R.T
    e_L = (e_W - c0) @ RL  # rows: R_Lᵀ (e_W − c0)
    r = (e_L[:, :2] - np.asarray(ab)).reshape(4)
    if not jac:
        return r
    A = RL.T @ R  # 3×3
    H_x = np.zeros((4, 6))
    H_l = np.zeros((4, 4))
    for k in range(2):
        H_x[2 * k : 2 * k + 2, :3] = -(A @ skew(e_B[k]))[:2]
        H_x[2 * k : 2 * k + 2, 3:] = A[:2]
        H_l[2 * k : 2 * k + 2, :2] = (skew(e_L[k]) @ Jr2)[:2]
        H_l[2 * k : 2 * k + 2, 2:] = -np.eye(2)
    return r, H_x, H_l


def line_residual(
    T_WB: gtsam.Pose3, theta: np.ndarray, anchor: LineAnchor, T_BS: np.ndarray, p_S, q_S, jac: bool = False
):
    """Perpendicular offsets (4,) of the observed endpoints from the line:
    r = P (R_Lᵀ (e_W − c0)) − (a, b) for e ∈ {p, q}, P the x,y rows.

    Jacobians: 4×6 wrt X, 4×4 wrt θ. The residual ignores where along the line the endpoints lie
    (a segment's ends are arbitrary along the pipe axis).
    """
    R_BS, t_BS = T_BS[:3, :3], T_BS[:3, 3]
    e_B = np.stack([R_BS @ np.asarray(p_S, float) + t_BS, R_BS @ np.asarray(q_S, float) + t_BS])
    RL, Jr2 = line_frame(anchor, theta) if jac else (anchor.rotation(theta), None)
    return line_residual_at(T_WB.rotation().matrix(), T_WB.translation(), RL, Jr2, anchor.c0, theta[2:4], e_B, jac)


def line_observation_covariance(
    T_WB: gtsam.Pose3, theta, anchor: LineAnchor, T_BS: np.ndarray, cov_pq_S: np.ndarray, RL: np.ndarray | None = None
) -> np.ndarray:
    """Covariance (4×4) of the line residual from the 6×6 endpoint covariance (sensor frame):
    each endpoint's covariance rotated into the line frame and projected perpendicular to it.
    ``RL``: R_L(θ) when the caller has it already."""
    RL = anchor.rotation(theta) if RL is None else RL
    M = (RL.T @ T_WB.rotation().matrix() @ T_BS[:3, :3])[:2]  # 2×3
    J = np.zeros((4, 6))
    J[:2, :3] = M
    J[2:, 3:] = M
    return J @ cov_pq_S @ J.T


def line_factor(x: int, l: int, anchor: LineAnchor, p_S, q_S, cov4: np.ndarray, T_BS, robust=None):
    """Pipe segment p_S, q_S seen from the sensor, on X and the 4-vector line landmark L
    (CustomFactor: GTSAM's Python API has no line type). ``cov4`` from
    :func:`line_observation_covariance` at the linearisation point of creation.

    The callback is :func:`line_residual` (with its Jacobians) written out in scalar arithmetic:
    iSAM2 calls it for every observation of every relinearised pipe and pose, and numpy's
    per-call overhead on 3-vectors made it ~200 µs; the line frame (R_L, J_r) is shared by all
    the factors of one landmark through :meth:`LineAnchor.frame_rows`. Same numbers (tested)."""
    T_BS = np.asarray(T_BS, float)
    R_BS, t_BS = T_BS[:3, :3], T_BS[:3, 3]
    (p0, p1, p2), (q0, q1, q2) = (
        (R_BS @ np.asarray(p_S, float) + t_BS).tolist(),
        (R_BS @ np.asarray(q_S, float) + t_BS).tolist(),
    )
    c0x, c0y, c0z = anchor.c0.tolist()

    def error(this, values, H):
        (R00, R01, R02, tx), (R10, R11, R12, ty), (R20, R21, R22, tz), _ = values.atPose3(x).matrix().tolist()
        th = values.atVector(l)
        (L00, L01, L02), (L10, L11, L12), (L20, L21, L22), J = anchor.frame_rows(th)
        a, b = float(th[2]), float(th[3])
        # A = R_Lᵀ R (rows A0, A1, A2); u = R_Lᵀ (t − c0); e_L = u + A e_B for each endpoint
        dx, dy, dz = tx - c0x, ty - c0y, tz - c0z
        A00, A01, A02 = (
            L00 * R00 + L10 * R10 + L20 * R20,
            L00 * R01 + L10 * R11 + L20 * R21,
            L00 * R02 + L10 * R12 + L20 * R22,
        )
        A10, A11, A12 = (
            L01 * R00 + L11 * R10 + L21 * R20,
            L01 * R01 + L11 * R11 + L21 * R21,
            L01 * R02 + L11 * R12 + L21 * R22,
        )
        u0 = L00 * dx + L10 * dy + L20 * dz
        u1 = L01 * dx + L11 * dy + L21 * dz
        pl0, pl1 = u0 + A00 * p0 + A01 * p1 + A02 * p2, u1 + A10 * p0 + A11 * p1 + A12 * p2
        ql0, ql1 = u0 + A00 * q0 + A01 * q1 + A02 * q2, u1 + A10 * q0 + A11 * q1 + A12 * q2
        r = np.array([pl0 - a, pl1 - b, ql0 - a, ql1 - b])
        if H is None:
            return r
        A20, A21, A22 = (
            L02 * R00 + L12 * R10 + L22 * R20,
            L02 * R01 + L12 * R11 + L22 * R21,
            L02 * R02 + L12 * R12 + L22 * R22,
        )
        u2 = L02 * dx + L12 * dy + L22 * dz
        pl2 = u2 + A20 * p0 + A21 * p1 + A22 * p2
        ql2 = u2 + A20 * q0 + A21 * q1 + A22 * q2
        # wrt X: rows −A_i [e_B]× = e_B × A_i (rotation), A_i (translation), i = 0, 1
        H[0] = np.array(
            [
                [p1 * A02 - p2 * A01, p2 * A00 - p0 * A02, p0 * A01 - p1 * A00, A00, A01, A02],
                [p1 * A12 - p2 * A11, p2 * A10 - p0 * A12, p0 * A11 - p1 * A10, A10, A11, A12],
                [q1 * A02 - q2 * A01, q2 * A00 - q0 * A02, q0 * A01 - q1 * A00, A00, A01, A02],
                [q1 * A12 - q2 * A11, q2 * A10 - q0 * A12, q0 * A11 - q1 * A10, A10, A11, A12],
            ]
        )
        # wrt θ: rows 0, 1 of [e_L]× J_r (two columns), then −I for (a, b)
        (J00, J01), (J10, J11), (J20, J21) = J
        H[1] = np.array(
            [
                [pl1 * J20 - pl2 * J10, pl1 * J21 - pl2 * J11, -1.0, 0.0],
                [pl2 * J00 - pl0 * J20, pl2 * J01 - pl0 * J21, 0.0, -1.0],
                [ql1 * J20 - ql2 * J10, ql1 * J21 - ql2 * J11, -1.0, 0.0],
                [ql2 * J00 - ql0 * J20, ql2 * J01 - ql0 * J21, 0.0, -1.0],
            ]
        )
        return r

    return gtsam.CustomFactor(_noise(cov4, robust), [x, l], error)


# --------------------------------------------------------------------------------------------
# Structure


def structure_factor(x: int, s: int, T_S_model: np.ndarray, cov6: np.ndarray, T_BS: np.ndarray, robust=None):
    """CAD model pose T_S,model on X and the structure landmark M = T_W,model: built-in
    BetweenFactorPose3(X, M, T_BS·T_S,model). Exact: the covariance is on the model side (right
    perturbation), and T_BS T_S,model Exp(ξ) = T_B,model Exp(ξ)."""
    meas = gtsam.Pose3(np.asarray(T_BS, float) @ np.asarray(T_S_model, float))
    return gtsam.BetweenFactorPose3(x, s, meas, _noise(np.asarray(cov6, float), robust))


def structure_residual(T_WB: gtsam.Pose3, M: gtsam.Pose3, T_BS: np.ndarray, T_S_model: np.ndarray, jac=False):
    """Residual Log((T_BS T_S,model)⁻¹ T_WB⁻¹ M) of the structure factor, with its Jacobians
    (6×6 wrt X, 6×6 wrt M), for data association."""
    meas = gtsam.Pose3(np.asarray(T_BS, float) @ np.asarray(T_S_model, float))
    H1 = np.zeros((6, 6), order="F")
    H2 = np.zeros((6, 6), order="F")
    between = T_WB.between(M, H1, H2)
    Hlog = np.zeros((6, 6), order="F")
    err = gtsam.Pose3.Logmap(meas.between(between), Hlog)
    if not jac:
        return err
    return err, Hlog @ H1, Hlog @ H2


# --------------------------------------------------------------------------------------------


def robust_kernel(name: str, k: float):
    """gtsam m-estimator by name ('huber', 'cauchy', 'tukey', 'none')."""
    name = name.lower()
    if name == "none":
        return None
    table = {
        "huber": gtsam.noiseModel.mEstimator.Huber,
        "cauchy": gtsam.noiseModel.mEstimator.Cauchy,
        "tukey": gtsam.noiseModel.mEstimator.Tukey,
    }
    return table[name].Create(k)


def _noise(cov: np.ndarray, robust):
    base = gtsam.noiseModel.Gaussian.Covariance(cov)
    return base if robust is None else gtsam.noiseModel.Robust.Create(robust, base)
