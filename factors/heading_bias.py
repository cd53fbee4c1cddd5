"""The AHRS heading bias's drift model, numpy only (shared by the graph's factor and the EKF).

The bias b (rad) is a random walk of intensity σ_b plus a drift rate r that is itself a random walk
of intensity σ_r (an integrated random walk): a learned drift carries the bias on where nothing
observes it. The rate is held as ρ = r τ, in rad per τ = :data:`RATE_UNIT_S` seconds.
"""

from __future__ import annotations

import numpy as np

# The rate state is in rad per RATE_UNIT_S seconds: of the bias's own size in the solvers (a rate in
# rad/s is ~10⁻⁵, its information ~10¹⁰ beside a position's ~10⁴).
RATE_UNIT_S = 100.0


def heading_bias_drift_covariance(dt: float, walk_sigma: float, rate_walk_sigma: float) -> np.ndarray:
    """Covariance of (b_j − b_i − ρ_i Δt/τ, ρ_j − ρ_i) over Δt = ``dt``: the integrated random walk's
    [[σ_b² Δt + σ_r² Δt³/3, σ_r² Δt² τ/2], [σ_r² Δt² τ/2, σ_r² Δt τ²]] with τ = RATE_UNIT_S."""
    dt = max(dt, 1e-6)
    qb, qr, tau = walk_sigma**2, rate_walk_sigma**2, RATE_UNIT_S
    return np.array([[qb * dt + qr * dt**3 / 3.0, qr * dt**2 / 2.0 * tau], [qr * dt**2 / 2.0 * tau, qr * dt * tau**2]])
