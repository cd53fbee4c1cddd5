"""The odometry's translation covariance calibrated online against the navigation prior (issue 23)."""

import numpy as np
import pytest

from frontends.odometry.calibration import S_MAX, S_MIN, TranslationScale


def _stream(k: float, n: int, seed: int):
    """n pairs (d, M, C): M a registration's stated measured covariance (σ 1–6 mm, anisotropic), C the prior's
    and the held rotation's part (σ 1–3 mm), d drawn with the registration's true error k× its stated σ."""
    rng = np.random.default_rng(seed)
    for _ in range(n):
        Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        M = Q @ np.diag(rng.uniform(1e-3, 6e-3, 3) ** 2) @ Q.T
        C = np.diag(rng.uniform(1e-3, 3e-3, 3) ** 2)
        d = np.linalg.cholesky(k**2 * M) @ rng.normal(size=3) + np.linalg.cholesky(C) @ rng.normal(size=3)
        yield d, M, C


@pytest.mark.parametrize("k", [2.0, 0.5, 1.0])
def test_the_scale_is_k_squared_when_the_true_error_is_k_times_the_stated_sigma(k):
    """Within 30 % of k² after 300 pairs (one mission has ~100–130) on three independent streams each: over
    20 streams s/k² was 1.01 ± 0.04 (k 2), 1.03 ± 0.08 (k 0.5, where the prior's part C is as large as k²·M),
    1.01 ± 0.05 (k 1)."""
    for seed in range(3):
        cal = TranslationScale()
        for d, M, C in _stream(k, 300, seed):
            cal.add(d, M, C)
        assert cal.pairs == 300
        assert cal.scale == pytest.approx(k**2, rel=0.3)


def test_the_scale_starts_at_one_stays_in_its_bounds_and_a_few_outliers_do_not_carry_it():
    cal = TranslationScale()
    assert cal.scale == 1.0
    pairs = list(_stream(1.0, 200, 7))
    for i, (d, M, C) in enumerate(pairs):
        cal.add(d * (30.0 if i % 25 == 0 else 1.0), M, C)  # 4 % of the registrations converged 30 σ off
    assert cal.scale == pytest.approx(1.0, rel=0.3)
    wild = TranslationScale()
    for d, M, C in pairs:
        wild.add(d * 1e3, M, C)  # every pair metres off: outliers all, no information on s
    assert wild.scale == pytest.approx(1.0)
    huge = TranslationScale()
    for d, M, C in _stream(5.0, 200, 8):  # s = 25 is beyond the ceiling
        huge.add(d, M, C)
    assert huge.scale == pytest.approx(S_MAX, rel=1e-6)
    tiny = TranslationScale()
    for _, M, C in pairs:
        tiny.add(np.zeros(3), M, 0.01 * C)
    assert tiny.scale == pytest.approx(S_MIN, rel=1e-6)


def test_non_finite_pairs_are_ignored():
    cal = TranslationScale()
    cal.add(np.array([np.nan, 0, 0]), np.eye(3), np.eye(3))
    cal.add(np.zeros(3), np.full((3, 3), np.inf), np.eye(3))
    assert cal.pairs == 0 and cal.scale == 1.0
