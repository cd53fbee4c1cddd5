"""Pipe extents of the EKF: saved view endpoints, robust ends, gaps and collinear pipes split by an object."""

import numpy as np

from semslam.ekf import geometry as g
from semslam.ekf.estimator import _Extent

D = np.array([1.0, 0.0, 0.0])
M = g.cross3(np.array([0.0, 2.0, 4.0]), D)  # the line y = 2, z = 4 along x


def seg(a, b, rng=None, sigma=0.0):
    e = np.array([[a, 2.0, 4.0], [b, 2.0, 4.0]])
    if rng is not None:
        e[:, 0] += rng.normal(scale=sigma, size=2)
        e[:, 1:] += rng.normal(scale=0.02, size=(2, 2))  # off-line noise: re-projection removes it
    return e


def test_robust_ends_are_not_biased_outwards_by_noise():
    rng = np.random.default_rng(0)
    ext = _Extent()
    for _ in range(200):  # views that all reach the true ends 0 and 3, noisy along the axis
        ext.add(seg(0.0, 3.0, rng, 0.05), 0.05)
    lo, hi = ext.interval(M, D)
    assert abs(lo) < 0.03 and abs(hi - 3.0) < 0.03  # the extremes alone would be ~±0.14 out
    p, q = ext.ends(M, D)
    np.testing.assert_allclose(p[1:], [2.0, 4.0], atol=1e-12)  # on the line


def test_gap_and_separation_by_an_in_line_object():
    ext = _Extent()
    ext.add(seg(0.0, 2.0), 0.05)
    span = ext.interval(M, D)
    assert ext.gap(seg(1.0, 2.5), M, D, span) == 0.0
    assert abs(ext.gap(seg(2.4, 3.5), M, D, span) - 0.4) < 1e-9
    valve = np.array([[2.2, 2.0, 4.0]])
    off_line = np.array([[2.2, 2.5, 4.0]])
    assert ext.separated(seg(2.3, 3.5), M, D, valve, 0.15, span)  # pipe B beyond the valve
    assert not ext.separated(seg(2.3, 3.5), M, D, off_line, 0.15, span)
    assert not ext.separated(seg(0.5, 1.8), M, D, valve, 0.15, span)  # a view inside pipe A
    elbow_at_end = np.array([[2.08, 2.0, 4.0]])
    assert not ext.separated(seg(1.0, 1.9), M, D, elbow_at_end, 0.15, span)
