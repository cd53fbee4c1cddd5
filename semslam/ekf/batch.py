"""Vectorised versions of the EKF's landmark measurement models (:mod:`semslam.ekf.models`).

Association linearises every observation of a scan against every nearby feature; one call here
does all the pairs of a kind at once. Each function is the batch form of the scalar model named in
its docstring and is tested against it.
"""

from __future__ import annotations

import numpy as np

from factors.geometry import skew_batch
from semslam.ekf import geometry as geo
from semslam.ekf.models import ATT, NX, POS

_FLIP = np.array([-1.0, -1.0, 1.0])
_FLIP4 = np.array([-1.0, -1.0, 1.0, 1.0])


def so3_log_batch(R: np.ndarray) -> np.ndarray:
    """:func:`geometry.so3_log` of each (3, 3) matrix in R (K, 3, 3) → (K, 3)."""
    c = np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    t = np.arccos(c)
    v = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    small = t < 1e-7
    near_pi = np.pi - t < 1e-5
    scale = np.where(small | near_pi, 0.5, t / (2 * np.sin(np.where(small | near_pi, 1.0, t))))
    out = scale[:, None] * v
    for k in np.flatnonzero(near_pi):
        out[k] = geo.so3_log(R[k])
    return out


def so3_right_jacobian_inv_batch(w: np.ndarray) -> np.ndarray:
    """:func:`geometry.so3_right_jacobian_inv` of each row of w (K×3) → (K, 3, 3)."""
    t = np.linalg.norm(w, axis=1)
    K = skew_batch(w)
    KK = K @ K
    small = t < 1e-6
    ts = np.where(small, 1.0, t)
    coef = np.where(small, 1.0 / 12.0, 1 / ts**2 - (1 + np.cos(ts)) / (2 * ts * np.sin(ts)))
    return np.eye(3) + 0.5 * K + coef[:, None, None] * KK


def _dt_dx(R_WB: np.ndarray, E: np.ndarray, t_BS: np.ndarray) -> np.ndarray:
    J = np.zeros((3, NX))
    J[:, POS] = np.eye(3)
    J[:, ATT] = -R_WB @ geo.skew(t_BS) @ E
    return J


def sensor_pose(x: np.ndarray, R_BS: np.ndarray, t_BS: np.ndarray):
    """(R_WS, t_WS, R_WB, E) as :func:`models.sensor_pose`."""
    R_WB = geo.rot(x[3], x[4], x[5])
    E = geo.euler_rate_to_body(x[3], x[4])
    return R_WB @ R_BS, x[POS] + R_WB @ t_BS, R_WB, E


def point_measurements(x: np.ndarray, L: np.ndarray, R_BS: np.ndarray, t_BS: np.ndarray):
    """:func:`models.point_measurement` for every object L (K×3, in {W}) seen from one sensor pose.

    Returns (h K×3, H_x K×3×9, H_l 3×3 — the same for every object)."""
    R, t, R_WB, E = sensor_pose(x, R_BS, t_BS)
    h = (L - t) @ R
    H_x = np.empty((len(L), 3, NX))
    H_x[:] = -R.T @ _dt_dx(R_WB, E, t_BS)
    H_x[:, :, ATT] += skew_batch(h) @ (R_BS.T @ E)
    return h, H_x, R.T.copy()


def line_innovations(
    x: np.ndarray,
    L: np.ndarray,
    obs_U: np.ndarray,
    obs_rho: np.ndarray,
    obs_d: np.ndarray,
    obs_cov: np.ndarray,
    R_BS: np.ndarray,
    t_BS: np.ndarray,
    L_lin: np.ndarray | None = None,
    x_lin: np.ndarray | None = None,
    anchors: np.ndarray | None = None,
):
    """:func:`models.line_innovation` for K pairs (pipe L[k] = [α β γ ρ] in {W}, observed line k in
    {S} with orthonormal U (K×3×3), ρ (K,), direction d (K×3) and error covariance (K×4×4)), all seen
    from one sensor pose; the Jacobians at L_lin and the vehicle state x_lin when given (first
    estimates); each pipe's moment about its row of ``anchors`` (K×3, default the origin).
    Returns (ν K×4, H_x K×4×9, H_l K×4×4, R K×4×4)."""
    anchors = np.zeros((len(L), 3)) if anchors is None else np.asarray(anchors, float)
    nu, Rn, r, flip = _line_residuals(x, L, obs_U, obs_rho, obs_d, obs_cov, R_BS, t_BS, anchors)
    if L_lin is None and x_lin is None:
        H_x, H_l = _line_jacobians(x, L, r, R_BS, t_BS, anchors)
    else:  # r at the first estimates, with the observations flipped as at L
        H_x, H_l = _line_jacobians(
            x if x_lin is None else x_lin,
            L if L_lin is None else L_lin,
            None,
            R_BS,
            t_BS,
            anchors,
            obs_U=obs_U,
            flip=flip,
        )
    return nu, H_x, H_l, Rn


def _predicted_lines(x, L, R_BS, t_BS, anchors):
    """The pipes L (K×4, in {W}, moments about ``anchors`` K×3) in {S} as orthonormal (U_h, ρ_h) and Plücker (m_S, d_S)."""
    R, t, _, _ = sensor_pose(x, R_BS, t_BS)
    t = t - anchors  # {S} as seen from each pipe's anchor
    U_W = geo.rot_batch(L[:, :3])
    d_W = U_W[:, :, 1]
    m_W = L[:, 3:4] * U_W[:, :, 0]
    m_S = (m_W - np.cross(t, d_W)) @ R
    d_S = d_W @ R
    rho_h = np.linalg.norm(m_S, axis=1)
    h1 = m_S / rho_h[:, None]
    U_h = np.stack([h1, d_S, np.cross(h1, d_S)], axis=2)
    return U_h, rho_h, m_S, d_S


def _line_residuals(x, L, obs_U, obs_rho, obs_d, obs_cov, R_BS, t_BS, anchors, flip=None):
    """(ν, R, r, flip): innovation, its noise in the innovation's chart, the rotation part r and
    which observations were flipped to agree with the predicted direction."""
    U_h, rho_h, _, d_S = _predicted_lines(x, L, R_BS, t_BS, anchors)
    if flip is None:
        flip = np.einsum("ki,ki->k", obs_d, d_S) < 0
    U_z = np.where(flip[:, None, None], obs_U * _FLIP, obs_U)
    cov = np.where(flip[:, None, None], obs_cov * np.outer(_FLIP4, _FLIP4), obs_cov)
    r = so3_log_batch(np.transpose(U_h, (0, 2, 1)) @ U_z)
    nu = np.concatenate([r, (obs_rho - rho_h)[:, None]], axis=1)
    Gr = np.zeros((len(L), 4, 4))
    Gr[:, :3, :3] = so3_right_jacobian_inv_batch(r)
    Gr[:, 3, 3] = 1.0
    return nu, Gr @ cov @ np.transpose(Gr, (0, 2, 1)), r, flip


def _line_jacobians(x, L, r, R_BS, t_BS, anchors, obs_U=None, flip=None):
    """(H_x, H_l) of the line innovation at pipes L with rotation residuals r (or, when r is None,
    those of the observations obs_U, flipped where ``flip``, against L)."""
    K = len(L)
    R, t0, R_WB, E = sensor_pose(x, R_BS, t_BS)
    t = t0 - anchors  # (K, 3): {S} as seen from each pipe's anchor
    W = R_BS.T @ E  # ∂ω_S/∂e
    # the pipes in {W} as Plücker, then in {S} (line_to_sensor)
    U_W = geo.rot_batch(L[:, :3])
    rho_W = L[:, 3]
    d_W = U_W[:, :, 1]
    m_W = rho_W[:, None] * U_W[:, :, 0]
    m_S = (m_W - np.cross(t, d_W)) @ R
    d_S = d_W @ R
    J_x = np.zeros((K, 6, NX))
    J_x[:, :3] = R.T @ skew_batch(d_W) @ _dt_dx(R_WB, E, t_BS)
    J_x[:, :3, ATT] += skew_batch(m_S) @ W
    J_x[:, 3:, ATT] = skew_batch(d_S) @ W
    J_md = np.zeros((K, 6, 6))
    J_md[:, :3, :3] = R.T
    J_md[:, :3, 3:] = -R.T @ skew_batch(t)
    J_md[:, 3:, 3:] = R.T
    # ∂(m, d)/∂[α β γ ρ] = line_error_inverse(U, ρ) G, G = diag(E(α, β), 1)
    u1, u3 = U_W[:, :, 0], U_W[:, :, 2]
    Binv = np.zeros((K, 6, 4))
    Binv[:, 3:, 0] = u3
    Binv[:, :3, 1] = -rho_W[:, None] * u3
    Binv[:, :3, 2] = rho_W[:, None] * d_W
    Binv[:, 3:, 2] = -u1
    Binv[:, :3, 3] = u1
    ca, sa, cb, sb = np.cos(L[:, 0]), np.sin(L[:, 0]), np.cos(L[:, 1]), np.sin(L[:, 1])
    G = np.zeros((K, 4, 4))
    G[:, 0, 0] = 1.0
    G[:, 0, 2] = -sb
    G[:, 1, 1] = ca
    G[:, 1, 2] = sa * cb
    G[:, 2, 1] = -sa
    G[:, 2, 2] = ca * cb
    G[:, 3, 3] = 1.0
    J_l = J_md @ (Binv @ G)
    # predicted line in {S}: orthonormal (U_h, ρ_h); A = line_error_map(U_h, ρ_h)
    rho_h = np.linalg.norm(m_S, axis=1)
    h1 = m_S / rho_h[:, None]
    h3 = np.cross(h1, d_S)
    if r is None:
        U_h = np.stack([h1, d_S, h3], axis=2)
        U_z = np.where(flip[:, None, None], obs_U * _FLIP, obs_U)
        r = so3_log_batch(np.transpose(U_h, (0, 2, 1)) @ U_z)
    A = np.zeros((K, 4, 6))
    A[:, 0, 3:] = h3
    A[:, 1, :3] = -h3 / rho_h[:, None]
    A[:, 2, :3] = d_S / rho_h[:, None]
    A[:, 3, :3] = h1
    Gl = np.zeros((K, 4, 4))
    Gl[:, :3, :3] = so3_right_jacobian_inv_batch(-r)
    Gl[:, 3, 3] = 1.0
    GA = Gl @ A
    return GA @ J_x, GA @ J_l


def line_observation_models(p: np.ndarray, q: np.ndarray, cov_pq: np.ndarray):
    """:meth:`models.LineObservationModel.from_endpoints` for K segments (p, q: K×3, covariances
    K×6×6). Returns (m K×3, d K×3, U K×3×3, ρ K, line-error covariance K×4×4)."""
    diff = q - p
    L = np.linalg.norm(diff, axis=1)
    d = diff / L[:, None]
    m = np.cross(p, d)
    Pd = (np.eye(3) - d[:, :, None] * d[:, None, :]) / L[:, None, None]
    Sp = skew_batch(p)
    J = np.empty((len(p), 6, 6))
    J[:, 3:, :3] = -Pd
    J[:, 3:, 3:] = Pd
    J[:, :3, :3] = -skew_batch(d) - Sp @ Pd
    J[:, :3, 3:] = Sp @ Pd
    rho = np.linalg.norm(m, axis=1)
    u1 = m / rho[:, None]
    u3 = np.cross(u1, d)
    U = np.stack([u1, d, u3], axis=2)
    A = np.zeros((len(p), 4, 6))
    A[:, 0, 3:] = u3
    A[:, 1, :3] = -u3 / rho[:, None]
    A[:, 2, :3] = d / rho[:, None]
    A[:, 3, :3] = u1
    AJ = A @ J
    return m, d, U, rho, AJ @ cov_pq @ np.transpose(AJ, (0, 2, 1))
