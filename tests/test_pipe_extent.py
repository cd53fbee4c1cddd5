"""A pipe's ends from many noisy, partly clipped views (the graph's and the EKF's shared rule)."""

import numpy as np

from semslam.backend.landmarks import robust_ends


def test_ends_of_many_noisy_views_are_not_biased_outwards():
    rng = np.random.default_rng(3)
    sigma, n = 0.05, 300  # the oracle's along-axis endpoint noise; a pipe seen all mission long
    lo = rng.normal(0.0, sigma, n)
    hi = rng.normal(0.4, sigma, n)
    clipped = rng.random(n) < 0.3  # views clipped by the field of view end further in
    hi[clipped] -= rng.uniform(0.05, 0.3, clipped.sum())
    a, b = robust_ends(lo, hi, 6 * sigma)
    assert abs(a) < 0.015 and abs(b - 0.4) < 0.015
    # the extreme views alone would be about 3σ out at each end
    assert lo.min() < -0.1 and hi.max() > 0.5


def test_a_few_views_give_their_median_ends():
    a, b = robust_ends(np.array([0.01, -0.01, 0.0]), np.array([0.39, 0.41, 0.4]), 0.06)
    assert (a, b) == (0.0, 0.4)
