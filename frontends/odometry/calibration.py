"""The registration's translation covariance calibrated online against the navigation prior (issue 23).

While the DVL is valid, the prior knows the translation between two scans to a few millimetres. The
registration's translation minus the prior's, d, then has covariance s·M + C: M the registration's
measured translation covariance (its part given the rotation), C what the shared held rotation and the
prior's own errors add, and s the world's scale of M (1 if the registration's covariance is right).
:class:`TranslationScale` estimates s by maximum a posteriori on a grid of log s from every such pair seen
so far: d's likelihood a mixture of the Gaussian N(0, s·M + C) and a small fraction of broad outliers (a
registration that converged wrong, which the gate's bounds still let through: it carries no information on
s and must not pull it up), and a log-normal prior on s centred on 1.
"""

from __future__ import annotations

import numpy as np

#: s is searched in [S_MIN, S_MAX]: the translation's NEES given the rotation ranged 1.05–6.31 of 3 over ten
#: tank worlds (experiments/odometry/README.md, stop 45 §5), i.e. s ≈ 0.35–2.1; the bounds leave a factor
#: of ~3.5–5 beyond that, so a real world is not clipped, and keep a σ within √10 of the registration's own.
S_MIN, S_MAX = 0.1, 10.0
#: σ of ln s in the prior toward 1 (a factor 3 at one σ): worth about two pairs, so the first few pairs
#: cannot swing s far, and a hundred pairs (one mission's) decide it
PRIOR_SIGMA_LN = np.log(3.0)
#: the outliers' share and σ per axis (m): the gate lets corrections of up to 0.35 m through (a wrong minimum
#: is seldom farther than a third of it), and a good pair's d is a few mm, so a good pair's likelihood is
#: ~10⁵ times the outliers' and their share barely moves s (measured with and without: the tests)
OUTLIER_SHARE, OUTLIER_SIGMA_M = 0.02, 0.1
_GRID = np.exp(np.linspace(np.log(S_MIN), np.log(S_MAX), 201))


class TranslationScale:
    """A running MAP estimate of the scale s of the registration's measured translation covariance."""

    def __init__(self) -> None:
        self._log_post = -0.5 * (np.log(_GRID) / PRIOR_SIGMA_LN) ** 2
        self.pairs = 0
        self.scale = 1.0

    def add(self, d: np.ndarray, measured: np.ndarray, other: np.ndarray) -> None:
        """One pair: d (3,) the registration's translation minus the prior's, ``measured`` (3×3) the
        registration's measured covariance (as stated, unscaled), ``other`` (3×3) what else d carries
        (the held rotation's part and the prior's). Non-finite inputs are ignored."""
        if not (np.isfinite(d).all() and np.isfinite(measured).all() and np.isfinite(other).all()):
            return
        S = _GRID[:, None, None] * measured[None] + other[None]
        sign, logdet = np.linalg.slogdet(S)
        if (sign <= 0).any():
            return
        q = np.einsum("i,kij,j->k", d, np.linalg.inv(S), d)
        good = np.log1p(-OUTLIER_SHARE) - 0.5 * (logdet + q)
        wide = np.log(OUTLIER_SHARE) - 0.5 * (6 * np.log(OUTLIER_SIGMA_M) + d @ d / OUTLIER_SIGMA_M**2)
        self._log_post += np.logaddexp(good, wide)  # (2π)^-3/2 is common to both
        self.pairs += 1
        self.scale = _argmax(self._log_post)


def _argmax(log_post: np.ndarray) -> float:
    """s at the maximum of ``log_post`` on the grid, refined by a parabola through its neighbours (in ln s)."""
    k = int(np.argmax(log_post))
    x = np.log(_GRID)
    if 0 < k < len(x) - 1:
        a, b, c = log_post[k - 1 : k + 2]
        den = a - 2 * b + c
        if den < 0:
            return float(np.exp(x[k] + 0.5 * (a - c) / den * (x[1] - x[0])))
    return float(_GRID[k])
