"""Reference forms of the EKF's hand-optimised models, which the fast versions are tested against."""

from __future__ import annotations

import numpy as np

from semslam.ekf.geometry import body_to_euler_rate, euler_rate_jacobian, euler_rate_to_body, rot, skew, wrap
from semslam.ekf.models import ATT, NX, POS, VEL


def predict_reference(x: np.ndarray, omega_B: np.ndarray, dt: float, accel_sigma: float, rate_sigma: float):
    """:func:`semslam.ekf.models.predict` in matrix form."""
    R = rot(*x[ATT])
    v = x[VEL]
    Einv = body_to_euler_rate(x[3], x[4])
    xn = x.copy()
    xn[POS] = x[POS] + R @ v * dt
    xn[ATT] = x[ATT] + Einv @ omega_B * dt
    xn[3] = wrap(xn[3])
    xn[5] = wrap(xn[5])
    F = np.eye(NX)
    F[POS, ATT] = -R @ skew(v) @ euler_rate_to_body(x[3], x[4]) * dt
    F[POS, VEL] = R * dt
    F[ATT, ATT] += euler_rate_jacobian(x[3], x[4], omega_B) * dt
    qa, qw = accel_sigma**2, rate_sigma**2
    Q = np.zeros((NX, NX))
    Q[POS, POS] = np.eye(3) * qa * dt**3 / 3.0
    Q[POS, VEL] = R * qa * dt**2 / 2.0
    Q[VEL, POS] = Q[POS, VEL].T
    Q[VEL, VEL] = np.eye(3) * qa * dt
    Q[ATT, ATT] = Einv @ Einv.T * qw * dt
    return xn, F, Q
