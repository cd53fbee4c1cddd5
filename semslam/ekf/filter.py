"""The EKF state and covariance: vehicle block first, landmark blocks appended, updated in place.

The covariance lives in a pre-allocated buffer that grows by doubling, so augmenting the state does
not copy it each time. Updates exploit the sparsity of H (the vehicle block plus the observed
landmarks): the Joseph form costs O(n² d) instead of O(n³).

Navigation steps (predictions and DVL / AHRS / depth updates) touch only the vehicle block, and are
applied to the rest of the state in compressed form (Guivant & Nebot 2001, the "compressed EKF"):
with L₀ = P_lv at the last full update, every such step keeps

    P_lv = L₀ Φᵀ,   P_ll = P_ll⁰ − L₀ Ψ L₀ᵀ,   x_l = x_l⁰ + L₀ a

for 9×9 accumulators Φ (product of the (I − K_v H_v) and F factors), Ψ (Σ Φᵀ H_vᵀ S⁻¹ H_v Φ) and a
9-vector a (Σ Φᵀ H_vᵀ S⁻¹ ν). A navigation step therefore costs O(9³) whatever the map size, and the
accumulated steps reach the landmarks in one O(n² · 9) pass whenever the full state is read
(:attr:`x`, :attr:`P`) — the same estimate as updating the whole state at every step, up to rounding.
"""

from __future__ import annotations

import numpy as np

from semslam.ekf.models import NX

_ROW_CHUNK = 512  # rows of P updated per gemm (bounds the temporaries for large maps)
_I = np.eye(NX)


def inv_small(S: np.ndarray) -> np.ndarray:
    """Inverse of a small symmetric positive-definite matrix (closed form up to 3×3: numpy's per-call
    cost dominates at this size)."""
    d = S.shape[0]
    if d == 1:
        return np.array([[1.0 / S[0, 0]]])
    if d == 3:
        a, b, c = float(S[0, 0]), float(S[0, 1]), float(S[0, 2])
        e, f, i = float(S[1, 1]), float(S[1, 2]), float(S[2, 2])
        A, B, C = e * i - f * f, c * f - b * i, b * f - c * e
        det = a * A + b * B + c * C
        if det > 0.0:
            E, F, I = a * i - c * c, b * c - a * f, a * e - b * b
            r = 1.0 / det
            return np.array([[A * r, B * r, C * r], [B * r, E * r, F * r], [C * r, F * r, I * r]])
    return np.linalg.inv(S)


class EkfState:
    def __init__(self, x0: np.ndarray, P0: np.ndarray, capacity: int = 64):
        cap = max(capacity, len(x0))
        self._x = np.zeros(cap)
        self._P = np.zeros((cap, cap))
        self.n = len(x0)
        self._x[: self.n] = x0
        self._P[: self.n, : self.n] = P0
        # compressed navigation steps not yet applied to the landmarks
        self._pending = False
        self._Phi = np.eye(NX)
        self._Psi = np.zeros((NX, NX))
        self._a = np.zeros(NX)

    # -------------------------------------------------------------------------- access
    @property
    def x(self) -> np.ndarray:
        """The state vector (a view: writes go to the state)."""
        self.flush()
        return self._x[: self.n]

    @property
    def P(self) -> np.ndarray:
        """The covariance (a view)."""
        self.flush()
        return self._P[: self.n, : self.n]

    @property
    def xv(self) -> np.ndarray:
        """The vehicle state (a view; always current)."""
        return self._x[:NX]

    @property
    def Pvv(self) -> np.ndarray:
        """The vehicle covariance block (a view; always current)."""
        return self._P[:NX, :NX]

    def flush(self) -> None:
        """Apply the accumulated navigation steps to the landmark part of the state (exact)."""
        if not self._pending:
            return
        n, P = self.n, self._P
        L0 = P[NX:n, :NX].copy()  # P_lv at the last full update
        self._x[NX:n] += L0 @ self._a
        LPsi = L0 @ self._Psi
        for r0 in range(NX, n, _ROW_CHUNK):
            r1 = min(n, r0 + _ROW_CHUNK)
            P[r0:r1, NX:n] -= LPsi[r0 - NX : r1 - NX] @ L0.T
        Plv = L0 @ self._Phi.T
        P[NX:n, :NX] = Plv
        P[:NX, NX:n] = Plv.T
        self._Phi = np.eye(NX)
        self._Psi = np.zeros((NX, NX))
        self._a = np.zeros(NX)
        self._pending = False

    # ----------------------------------------------------------------------- prediction
    def predict_vehicle(self, xv_new: np.ndarray, F: np.ndarray, Q: np.ndarray) -> None:
        """x_v ← f(x_v), P_vv ← F P_vv Fᵀ + Q, P_vl ← F P_vl (landmarks are static)."""
        P = self._P
        self._x[:NX] = xv_new
        P[:NX, :NX] = F @ P[:NX, :NX] @ F.T + Q
        if self.n > NX:
            self._Phi = F @ self._Phi
            self._pending = True

    # --------------------------------------------------------------------------- update
    def update_vehicle(self, innovation: np.ndarray, H: np.ndarray, R: np.ndarray) -> float:
        """EKF update with H non-zero only on the vehicle block (H is d×9): Joseph form on P_vv, the
        landmarks through the compressed accumulators. Returns the NIS νᵀ S⁻¹ ν."""
        Pvv = self._P[:NX, :NX]
        PHt = Pvv @ H.T
        S = H @ PHt + R
        S_inv = inv_small(0.5 * (S + S.T))
        K = PHt @ S_inv
        self._x[:NX] += K @ innovation
        # Joseph form P − K(HP) − (HP)ᵀKᵀ + K S Kᵀ
        KHP = K @ PHt.T
        Pn = Pvv - KHP - KHP.T + (K @ S) @ K.T
        self._P[:NX, :NX] = 0.5 * (Pn + Pn.T)
        if self.n > NX:
            HPhi = H @ self._Phi
            W = S_inv @ HPhi
            self._a += innovation @ W
            self._Psi += HPhi.T @ W
            self._Phi -= K @ HPhi
            self._pending = True
        return float(innovation @ S_inv @ innovation)

    def update(self, innovation: np.ndarray, cols: np.ndarray, H: np.ndarray, R: np.ndarray) -> float:
        """EKF update with ν = z − h(x) and H non-zero only on the state indices ``cols`` (H is d×len(cols)).

        Joseph form P⁺ = (I − KH) P (I − KH)ᵀ + K R Kᵀ, expanded as P − K(HP) − (HP)ᵀKᵀ + K S Kᵀ
        (valid for any gain). Returns the NIS νᵀ S⁻¹ ν.
        """
        cols = np.asarray(cols)
        if len(cols) == NX and cols[0] == 0 and cols[-1] == NX - 1:
            return self.update_vehicle(innovation, H, R)
        self.flush()
        n = self.n
        P = self._P[:n, :n]
        PHt = P[:, cols] @ H.T  # n×d
        S = H @ PHt[cols] + R
        S = 0.5 * (S + S.T)
        S_inv = np.linalg.inv(S)
        K = PHt @ S_inv
        self._x[:n] += K @ innovation
        left = np.hstack([K, PHt, -K])  # n×3d
        right = np.vstack([PHt.T, K.T, S @ K.T])  # 3d×n
        for r0 in range(0, n, _ROW_CHUNK):
            r1 = min(n, r0 + _ROW_CHUNK)
            P[r0:r1] -= left[r0:r1] @ right
        return float(innovation @ S_inv @ innovation)

    # ------------------------------------------------------------------------ augmentation
    def augment(self, l: np.ndarray, G_x: np.ndarray, G_z: np.ndarray, R_z: np.ndarray) -> int:
        """Append landmark l = g(x_v, z) with ∂g/∂x_v = G_x, ∂g/∂z = G_z, Cov(z) = R_z (eqs. 39–45).

        P_ll = G_x P_vv G_xᵀ + G_z R_z G_zᵀ, P_l,· = G_x P_v,·. Returns the index of the new block.
        """
        self.flush()
        k = len(l)
        n = self.n
        self._reserve(n + k)
        P = self._P
        cross = G_x @ P[:NX, :n]  # k×n
        P[n : n + k, :n] = cross
        P[:n, n : n + k] = cross.T
        block = cross[:, :NX] @ G_x.T + G_z @ R_z @ G_z.T
        P[n : n + k, n : n + k] = 0.5 * (block + block.T)
        self._x[n : n + k] = l
        self.n = n + k
        return n

    def _reserve(self, size: int) -> None:
        cap = len(self._x)
        if size <= cap:
            return
        new_cap = max(size, 2 * cap)
        x = np.zeros(new_cap)
        x[: self.n] = self._x[: self.n]
        P = np.zeros((new_cap, new_cap))
        P[: self.n, : self.n] = self._P[: self.n, : self.n]
        self._x, self._P = x, P
