"""A pipe segment's axis when the visible arc of its shell changes along it (a camera looking
forward and down at a pipe lying on the seabed): the principal direction of the points turns, the
least-squares cylinder does not."""

import numpy as np

from frontends.laser.config import PipeConfig
from frontends.laser.pipes import fit_cylinder, refine_cylinder


def _turning_arc(rng, r=0.045, length=0.4, n=1500, noise=0.003):
    """Points and normals of a cylinder along x (axis through the origin) whose visible arc runs
    from -40°..+80° about "up" (-z) at x = 0 to -80°..+40° at x = length: the arc's middle swings
    across, as the sensor's view of the shell does along a pipe partly hidden by the seabed."""
    t = rng.uniform(0.0, length, n)
    s = t / length
    lo, hi = np.radians(-40 - 40 * s), np.radians(80 - 40 * s)
    th = lo + rng.uniform(0, 1, n) * (hi - lo)
    nrm = np.column_stack([np.zeros(n), np.sin(th), -np.cos(th)])
    pts = np.column_stack([t, np.zeros(n), np.zeros(n)]) + r * nrm + rng.normal(0, noise, (n, 3))
    return pts, nrm + rng.normal(0, 0.05, (n, 3))


def _angle_deg(a, b):
    return float(np.degrees(np.arccos(min(1.0, abs(a @ b) / np.linalg.norm(a) / np.linalg.norm(b)))))


def test_refit_axis_does_not_follow_the_visible_arc():
    rng = np.random.default_rng(3)
    r = 0.045
    cfg = PipeConfig()
    pts, nrm = _turning_arc(rng, r)
    truth = np.array([1.0, 0.0, 0.0])
    c, a, rr = fit_cylinder(pts, nrm, truth, cfg)
    assert _angle_deg(a, truth) > 1.0  # the principal direction swings with the arc
    c2, a2, r2 = refine_cylinder(pts, c, a, rr, cfg)
    assert _angle_deg(a2, truth) < 0.2
    off = c2 - (c2 @ truth) * truth  # the refitted axis passes through the true one
    assert np.linalg.norm(off) < 0.002
    assert abs(r2 - r) < 0.002


def test_refit_keeps_the_first_fit_when_the_points_are_no_cylinder():
    rng = np.random.default_rng(4)
    # a flat patch: the least-squares "cylinder" grows its radius past the range; the first fit stays
    pts = np.column_stack([rng.uniform(0, 0.3, 300), rng.uniform(-0.02, 0.02, 300), rng.normal(0, 0.002, 300)])
    c, a, r = np.array([0.15, 0.0, 0.03]), np.array([1.0, 0.0, 0.0]), 0.03
    c2, a2, r2 = refine_cylinder(pts, c, a, r, PipeConfig())
    assert r2 == r and np.array_equal(c2, c) and np.array_equal(a2, a)


def test_with_a_known_radius_the_first_fit_stays():
    """The tank's path (radius_prior) is not refitted (see refine_cylinder)."""
    rng = np.random.default_rng(5)
    cfg = PipeConfig(radius_prior=0.045)
    pts, nrm = _turning_arc(rng, 0.045 - cfg.surface_offset)
    c, a, r = fit_cylinder(pts, nrm, np.array([1.0, 0.0, 0.0]), cfg)
    c2, a2, r2 = refine_cylinder(pts, c, a, r, cfg)
    assert r2 == r and np.array_equal(c2, c) and np.array_equal(a2, a)
