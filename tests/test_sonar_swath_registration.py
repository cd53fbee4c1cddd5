"""Sonar front-end: swath registration (signed median depth, then the north/east shift minimising
the median unsigned depth difference), its texture checks and covariance."""

import numpy as np
import pytest

from frontends.sonar.config import SwathRegistrationConfig
from frontends.sonar.grid import ElevationMap, GridSpec
from frontends.sonar.swath_registration import register


def _seabed(n, e, pipes=((0.3, 1.0),), box=True):
    """Depth of a gently tilted seabed with pipes (lateral offset, direction angle) and a boulder
    (lower than ``max_height_m``: taller things are structures, which registration leaves out)."""
    z = 20.0 + 0.02 * n + 0.01 * e
    for off, ang in pipes:
        d = np.abs(-np.sin(ang) * n + np.cos(ang) * e - off)
        r = 0.25
        z = z - np.where(d < r, np.sqrt(np.maximum(r * r - d * d, 0.0)) + r * 0.6, 0.0)
    if box:
        z = z - np.where((np.abs(n - 1.2) < 0.4) & (np.abs(e + 0.8) < 0.3), 0.4, 0.0)  # a boulder
    return z


def _cloud(rng, n_pts, lo, hi, fn, sigma=0.015):
    p = rng.uniform(lo, hi, (n_pts, 2))
    return np.column_stack([p, fn(p[:, 0], p[:, 1]) + rng.normal(0, sigma, n_pts)])


def _ref_map(rng, fn, cfg, lo=(-3, -3), hi=(3, 3)):
    pts = _cloud(rng, 60000, lo, hi, fn)
    spec = GridSpec.around(np.array(lo) + 0.3, np.array(hi) - 0.3, cfg.cell_m, pad=0.2)
    return ElevationMap.from_points(pts, spec=spec)


@pytest.mark.parametrize("true", [(0.17, -0.11, 0.03), (-0.23, 0.05, -0.02), (0.0, 0.0, 0.0)])
def test_recovers_a_known_shift(true):
    cfg = SwathRegistrationConfig()
    rng = np.random.default_rng(7)
    fn = lambda n, e: _seabed(n, e, pipes=((0.3, 1.0), (-0.5, 2.3)))  # noqa: E731
    ref = _ref_map(rng, fn, cfg)
    new = _cloud(rng, 20000, (-1.9, -1.9), (1.9, 1.9), fn)
    new -= np.array(true)  # the new swaths are misplaced by −true: the correction is +true
    res = register(new, ref, cfg, rng)
    assert res is not None and res.informative == 2
    assert np.hypot(*(res.shift - true[:2])) < 0.02
    assert res.depth == pytest.approx(true[2], abs=0.005)
    # the covariance is honest: the error is within 3 σ in every direction
    e = np.r_[res.shift, res.depth] - np.array(true)
    assert e @ np.linalg.solve(res.cov, e) < 3.0**2 * 3
    assert res.cost_after <= res.cost_before + 1e-12


def test_flat_seabed_gives_no_north_east_information():
    cfg = SwathRegistrationConfig()
    rng = np.random.default_rng(8)
    fn = lambda n, e: 20.0 + 0.03 * n - 0.02 * e + 0.01 * np.sin(n / 3.0)  # noqa: E731
    ref = _ref_map(rng, fn, cfg)
    new = _cloud(rng, 20000, (-1.9, -1.9), (1.9, 1.9), fn) - np.array([0.1, 0.1, 0.0])
    assert register(new, ref, cfg, rng) is None


def test_a_single_ridge_constrains_only_across_it():
    cfg = SwathRegistrationConfig()
    rng = np.random.default_rng(9)
    ang = 0.4  # the ridge runs along (cos 0.4, sin 0.4)
    fn = lambda n, e: _seabed(n, e, pipes=((0.0, ang),), box=False)  # noqa: E731
    ref = _ref_map(rng, fn, cfg)
    true = np.array([0.3, 0.0, 0.0])  # 0.28 m along the ridge, −0.12 m across
    new = _cloud(rng, 20000, (-1.9, -1.9), (1.9, 1.9), fn) - true
    res = register(new, ref, cfg, rng)
    assert res is not None and res.informative == 1
    along = np.array([np.cos(ang), np.sin(ang)])
    across = np.array([-np.sin(ang), np.cos(ang)])
    assert res.shift @ across == pytest.approx(true[:2] @ across, abs=0.02)
    assert abs(res.shift @ along) < 0.05  # the 0.28 m along the ridge cannot be seen: none is kept ...
    w, V = np.linalg.eigh(res.cov[:2, :2])
    assert w[1] > 1.0  # no information claimed along it ...
    assert np.sqrt(w[0]) < 0.05 and abs(V[:, 0] @ across) > np.cos(np.radians(3))  # ... only across


def test_too_little_overlap_is_rejected():
    cfg = SwathRegistrationConfig()
    rng = np.random.default_rng(10)
    ref = _ref_map(rng, _seabed, cfg, lo=(-3, -3), hi=(0, 3))
    new = _cloud(rng, 20000, (1.5, -1.9), (3.0, 1.9), _seabed)  # beyond the reference
    assert register(new, ref, cfg, rng) is None
