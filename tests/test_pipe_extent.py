"""A pipe's ends from many noisy, partly clipped views (the graph's and the EKF's shared rule)."""

import numpy as np
import pytest

from semslam.mapping.pipes import robust_ends


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


def test_association_extent_stays_short_of_the_next_valve():
    from semslam.backend.landmarks import Landmark
    from semslam.mapping.pipes import object_between

    # pipe 18 of the tank: 0.40 m long, a 3-way valve 0.12 m beyond its end, then pipe 16
    rng = np.random.default_rng(5)
    lm = Landmark(1, "pipe", 0)
    for _ in range(220):  # views along the axis (line frame: s), endpoint σ 5 cm
        lo, hi = rng.normal(0.0, 0.05), rng.normal(0.40, 0.05)
        lm.seen_ends.append((lo, hi, 0.05))
    lm.extent = (min(e[0] for e in lm.seen_ends), max(e[1] for e in lm.seen_ends))
    c, d = np.zeros(3), np.array([1.0, 0.0, 0.0])
    valve = np.array([[0.52, 0.0, 0.0]])
    next_pipe = np.array([[0.53, 0.0, 0.0], [1.05, 0.0, 0.0]])  # a view of pipe 16 (from 0.64), its near end 2σ long
    # every view's extreme reaches into the valve: the next pipe's view overlaps it, nothing between
    assert lm.extent[1] > 0.52
    assert not object_between(lm.extent, next_pipe, c, d, valve, 0.15)
    lo, hi = lm.robust_extent()
    assert abs(hi - 0.40) < 0.02
    assert object_between((lo, hi), next_pipe, c, d, valve, 0.15)


def test_a_pipe_seen_through_a_mapped_tee_is_cut_at_it_on_the_side_of_its_views():
    from factors.landmarks import LineAnchor
    from semslam.backend.landmarks import Landmark

    # a landmark started by laser fits through an in-line tee at s = 0.5: most views then see the
    # part before it, a few the whole 1 m
    lm = Landmark(
        1, "pipe", 0, anchor=LineAnchor.from_points(np.zeros(3), np.array([1.0, 0.0, 0.0])), estimate=np.zeros(4)
    )
    lm.seen_ends = [(0.0, 0.45, 0.01)] * 30 + [(0.0, 1.0, 0.01)] * 5
    lm.extent = (0.0, 1.0)
    d = lm.anchor.direction(lm.estimate)
    c0 = lm.anchor.c0
    tee = c0 + 0.5 * d + np.array([0.0, 0.02, 0.0])  # 2 cm off the axis, as estimated
    elbow = c0 + 1.05 * d  # at the end: not inside
    assert lm.stretch(np.zeros((0, 3)), 0.15) == lm.robust_extent()
    lo, hi = lm.stretch(np.array([tee, elbow]), 0.15)
    assert lo == pytest.approx(lm.robust_extent()[0]) and hi == pytest.approx(0.5, abs=1e-9)
    # the views mostly beyond the tee keep that side instead
    other = Landmark(2, "pipe", 0, anchor=lm.anchor, estimate=lm.estimate, extent=(0.0, 1.0))
    other.seen_ends = [(0.55, 1.0, 0.01)] * 30 + [(0.0, 1.0, 0.01)] * 5
    lo, hi = other.stretch(np.array([tee]), 0.15)
    assert lo == pytest.approx(0.5, abs=1e-9) and hi == pytest.approx(1.0, abs=1e-9)


def test_the_ekf_extent_is_cut_at_a_mapped_tee_like_the_graphs():
    from semslam.ekf.estimator import _Extent

    ext = _Extent()
    for _ in range(30):
        ext.add(np.array([[0.0, 1.0, 4.0], [0.45, 1.0, 4.0]]), 0.01)  # the part before the tee
    for _ in range(5):
        ext.add(np.array([[0.0, 1.0, 4.0], [1.0, 1.0, 4.0]]), 0.01)  # fits through the tee
    d = np.array([1.0, 0.0, 0.0])
    m = np.cross(np.array([0.0, 1.0, 4.0]), d)
    c = np.cross(d, m)  # the line's closest point to the origin: positions are along d from it
    a, b = ext.interval(m, d)
    assert b - a == pytest.approx(1.0, abs=1e-9)
    a, b = ext.interval(m, d, np.array([[0.5, 1.02, 4.0]]), 0.15)
    np.testing.assert_allclose(c + b * d, [0.5, 1.0, 4.0], atol=1e-9)
    np.testing.assert_allclose(c + a * d, [0.0, 1.0, 4.0], atol=1e-9)
