"""The EKF state and covariance: vehicle block first, landmark blocks appended, updated in place.

The covariance lives in a pre-allocated buffer that grows by doubling, so augmenting the state does
not copy it each time. Updates exploit the sparsity of H (the vehicle block plus the observed
landmarks): the Joseph form costs O(n² d) instead of O(n³).
"""

from __future__ import annotations

import numpy as np

from semslam.ekf.models import NX

_ROW_CHUNK = 512  # rows of P updated per gemm (bounds the temporaries for large maps)


class EkfState:
    def __init__(self, x0: np.ndarray, P0: np.ndarray, capacity: int = 64):
        cap = max(capacity, len(x0))
        self._x = np.zeros(cap)
        self._P = np.zeros((cap, cap))
        self.n = len(x0)
        self._x[: self.n] = x0
        self._P[: self.n, : self.n] = P0

    # -------------------------------------------------------------------------- access
    @property
    def x(self) -> np.ndarray:
        """The state vector (a view: writes go to the state)."""
        return self._x[: self.n]

    @property
    def P(self) -> np.ndarray:
        """The covariance (a view)."""
        return self._P[: self.n, : self.n]

    @property
    def xv(self) -> np.ndarray:
        return self._x[:NX]

    # ----------------------------------------------------------------------- prediction
    def predict_vehicle(self, xv_new: np.ndarray, F: np.ndarray, Q: np.ndarray) -> None:
        """x_v ← f(x_v), P_vv ← F P_vv Fᵀ + Q, P_vl ← F P_vl (landmarks are static)."""
        n = self.n
        self._x[:NX] = xv_new
        P = self._P
        P[:NX, :NX] = F @ P[:NX, :NX] @ F.T + Q
        if n > NX:
            P[:NX, NX:n] = F @ P[:NX, NX:n]
            P[NX:n, :NX] = P[:NX, NX:n].T

    # --------------------------------------------------------------------------- update
    def update(self, innovation: np.ndarray, cols: np.ndarray, H: np.ndarray, R: np.ndarray) -> float:
        """EKF update with ν = z − h(x) and H non-zero only on the state indices ``cols`` (H is d×len(cols)).

        Joseph form P⁺ = (I − KH) P (I − KH)ᵀ + K R Kᵀ, expanded as P − K(HP) − (HP)ᵀKᵀ + K S Kᵀ
        (valid for any gain). Returns the NIS νᵀ S⁻¹ ν.
        """
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
