"""The EKF state and covariance: vehicle block first, landmark blocks appended, updated in place.

The covariance lives in a pre-allocated buffer that grows by doubling, so augmenting the state does
not copy it each time. Updates exploit the sparsity of H (the vehicle block plus the observed
landmarks): the Joseph form costs O(n² d) instead of O(n³).

Navigation steps (predictions and DVL / AHRS / depth updates) touch only the vehicle block, and are
applied to the rest of the state in compressed form (Guivant & Nebot 2001, the "compressed EKF").
At the last full update the landmarks are l = A y + e with y the vehicle state then, A = P_lv P_vv⁻¹
and e independent of y; vehicle-only steps involve only y, process and measurement noise, never e.
So they run on the 2·n_v-state [x_v; y] (y a clone of the vehicle at that time), and reach the
landmarks in one O(n² · n_v) pass whenever the full state is read (:attr:`x`, :attr:`P`):

    x_l += A (ŷ − ŷ₀),   P_ll −= A (P_yy⁰ − P_yy) Aᵀ,   P_lv = A P_yv

— the same estimate as updating the whole state at every step, up to rounding, at a cost per step
independent of the map size.

The vehicle block is the first ``nv`` entries: the 9 of :mod:`semslam.ekf.models` (pose, body
velocity), plus the AHRS heading bias when it is modelled (``nv`` = 10) and its drift rate (``nv`` = 11), plus the
gyro's bias (3 more, last) when modelled. Every navigation step
(including the bias's random walk and the AHRS update that sees it) is vehicle-only, so the
compression holds unchanged. Landmark measurements and augmentations may give their vehicle
Jacobians over the first 9 entries only (their column for the bias is zero).
"""

from __future__ import annotations

import numpy as np

from semslam.mapping.association import inv_small

_ROW_CHUNK = 512  # rows of P updated per gemm (bounds the temporaries for large maps)


class EkfState:
    """``x0``, ``P0``: the vehicle state (its size is the vehicle block's, ``nv``) and covariance."""

    def __init__(self, x0: np.ndarray, P0: np.ndarray, capacity: int = 64):
        cap = max(capacity, len(x0))
        self._x = np.zeros(cap)
        self._P = np.zeros((cap, cap))
        self.n = len(x0)
        self.nv = len(x0)  # the vehicle block
        self._x[: self.n] = x0
        self._P[: self.n, : self.n] = P0
        # compressed navigation steps: the 2·nv-state [x_v; y] (None when nothing is pending)
        self._C: np.ndarray | None = None  # its covariance (the vehicle block P_vv lives here meanwhile)
        self._y = np.zeros(self.nv)  # the clone's estimate
        self._y0 = np.zeros(self.nv)  # ... and its value when the compression started

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
        return self._x[: self.nv]

    @property
    def Pvv(self) -> np.ndarray:
        """The vehicle covariance block (a view; always current)."""
        nv = self.nv
        return self._P[:nv, :nv] if self._C is None else self._C[:nv, :nv]

    def _compress(self) -> None:
        """Start a compression: the clone y = x_v, fully correlated with it."""
        nv = self.nv
        Pvv = self._P[:nv, :nv]
        C = np.empty((2 * nv, 2 * nv))
        C[:nv, :nv] = C[:nv, nv:] = C[nv:, :nv] = C[nv:, nv:] = Pvv
        self._C = C
        self._y[:] = self._x[:nv]
        self._y0[:] = self._x[:nv]

    def flush(self) -> None:
        """Apply the pending navigation steps to the landmark part of the state (exact)."""
        C = self._C
        if C is None:
            return
        self._C = None
        n, P, nv = self.n, self._P, self.nv
        Pyy0 = P[:nv, :nv]  # the vehicle block when the compression started
        A = np.linalg.solve(Pyy0, P[:nv, nv:n]).T  # P_lv P_vv⁻¹ (n_l × nv)
        self._x[nv:n] += A @ (self._y - self._y0)
        AD = A @ (Pyy0 - C[nv:, nv:])
        for r0 in range(nv, n, _ROW_CHUNK):
            r1 = min(n, r0 + _ROW_CHUNK)
            P[r0:r1, nv:n] -= AD[r0 - nv : r1 - nv] @ A.T
        Plv = A @ C[nv:, :nv]
        P[nv:n, :nv] = Plv
        P[:nv, nv:n] = Plv.T
        P[:nv, :nv] = C[:nv, :nv]

    # ----------------------------------------------------------------------- prediction
    def predict_vehicle(self, xv_new: np.ndarray, F: np.ndarray, Q: np.ndarray) -> None:
        """x_v ← f(x_v), P_vv ← F P_vv Fᵀ + Q, P_vl ← F P_vl (landmarks are static); F, Q are nv×nv."""
        nv = self.nv
        self._x[:nv] = xv_new
        if self.n == nv:
            P = self._P
            P[:nv, :nv] = F @ P[:nv, :nv] @ F.T + Q
            return
        if self._C is None:
            self._compress()
        C = self._C
        C[:nv, :nv] = F @ C[:nv, :nv] @ F.T + Q
        C[:nv, nv:] = F @ C[:nv, nv:]
        C[nv:, :nv] = C[:nv, nv:].T

    # --------------------------------------------------------------------------- update
    def update_vehicle(self, innovation: np.ndarray, H: np.ndarray, R: np.ndarray, nis: bool = True) -> float | None:
        """EKF update with H non-zero only on the vehicle block (H is d×nv, or d×9 when zero on the
        entries after the 9th); with a map, on [x_v; y] (the landmarks follow at the next :meth:`flush`).
        P⁺ = P − K(HP), symmetrised: with the optimal gain the Joseph form's K S Kᵀ − (HP)ᵀKᵀ terms
        cancel, and S here is a well-conditioned d ≤ 3 navigation residual. Returns the NIS νᵀ S⁻¹ ν
        (None unless ``nis``)."""
        nv = self.nv
        if self.n == nv:
            P = self._P[:nv, :nv]
        else:
            if self._C is None:
                self._compress()
            P = self._C
        k = H.shape[1]  # H's columns: the first k vehicle entries
        HP = H @ P[:k]  # d × (nv or 2 nv)
        S = HP[:, :k] @ H.T + R
        S_inv = inv_small(S)  # reads the upper triangle: symmetric by construction
        K = HP.T @ S_inv
        dx = K @ innovation
        self._x[:nv] += dx[:nv]
        if len(dx) > nv:
            self._y += dx[nv:]
        Pn = P - K @ HP
        np.add(Pn, Pn.T, out=P)
        P *= 0.5
        return float(innovation @ S_inv @ innovation) if nis else None

    def update(self, innovation: np.ndarray, cols: np.ndarray, H: np.ndarray, R: np.ndarray) -> float:
        """EKF update with ν = z − h(x) and H non-zero only on the state indices ``cols`` (H is d×len(cols)).

        Joseph form P⁺ = (I − KH) P (I − KH)ᵀ + K R Kᵀ, expanded as P − K(HP) − (HP)ᵀKᵀ + K S Kᵀ
        (valid for any gain). Returns the NIS νᵀ S⁻¹ ν.
        """
        cols = np.asarray(cols)
        if len(cols) <= self.nv and np.array_equal(cols, np.arange(len(cols))):
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

        P_ll = G_x P_vv G_xᵀ + G_z R_z G_zᵀ, P_l,· = G_x P_v,·. G_x may cover only the first vehicle
        entries (the rest of its columns zero). Returns the index of the new block.
        """
        self.flush()
        k = len(l)
        n = self.n
        kx = G_x.shape[1]
        self._reserve(n + k)
        P = self._P
        cross = G_x @ P[:kx, :n]  # k×n
        P[n : n + k, :n] = cross
        P[:n, n : n + k] = cross.T
        block = cross[:, :kx] @ G_x.T + G_z @ R_z @ G_z.T
        P[n : n + k, n : n + k] = 0.5 * (block + block.T)
        self._x[n : n + k] = l
        self.n = n + k
        return n

    def remove(self, start: int, size: int) -> None:
        """Drop the block [start, start + size) from the state (marginalise it out)."""
        self.flush()
        n = self.n
        keep = np.r_[np.arange(start), np.arange(start + size, n)]
        self._x[: n - size] = self._x[keep]
        self._P[: n - size, : n - size] = self._P[np.ix_(keep, keep)]
        self.n = n - size

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
