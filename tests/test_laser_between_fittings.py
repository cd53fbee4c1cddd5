"""A pipe shorter than ``min_partial_length`` between two fittings is reported (issue 22, tank world
72: a 0.124 m pipe between two valves was never observed); one as short ending in the open is not."""

import numpy as np

from frontends.laser.config import PipeConfig
from frontends.laser.grid import row_dot
from frontends.laser.pipes import _cut_into_segments

R = 0.0315
AXIS = np.array([1.0, 0.0, 0.0])


def _shell(x0, x1, r, n, rng):
    """Points and outward normals on the upper half (towards the sensor, −z) of a cylinder of
    radius ``r`` about the x axis at z = 2 m, from x0 to x1."""
    th = rng.uniform(-1.3, 1.3, n)
    nrm = np.column_stack([np.zeros(n), np.sin(th), -np.cos(th)])
    pts = np.column_stack([rng.uniform(x0, x1, n), np.zeros(n), np.full(n, 2.0)]) + r * nrm
    return pts + rng.normal(0, 0.001, (n, 3)), nrm


def _segments(parts, cfg):
    pts = np.vstack([p for p, _ in parts])
    nrm = np.vstack([n for _, n in parts])
    c = np.array([0.0, 0.0, 2.0])
    return _cut_into_segments(pts, nrm, row_dot(pts, pts), c, AXIS, R, np.arange(len(pts)), cfg)


def test_a_short_pipe_between_two_fittings_is_reported_and_a_free_one_is_not():
    rng = np.random.default_rng(22)
    cfg = PipeConfig(radius_prior=R)
    # sockets (8 mm wider than the pipe, 6 cm long) at both ends of a 14 cm pipe, pipes beyond them
    parts = [
        _shell(-0.30, -0.06, R, 400, rng),
        _shell(-0.06, 0.00, R + 0.008, 150, rng),
        _shell(0.00, 0.14, R, 240, rng),
        _shell(0.14, 0.20, R + 0.008, 150, rng),
        _shell(0.20, 0.44, R, 400, rng),
    ]
    short = [p for p in _segments(parts, cfg) if p.length < cfg.min_partial_length]
    (middle,) = short
    assert -0.01 < min(middle.p[0], middle.q[0]) < 0.03 and 0.11 < max(middle.p[0], middle.q[0]) < 0.15
    assert middle.reported(cfg) and middle.between_fittings
    assert not middle.reported(cfg.model_copy(update={"report_between_fittings": False}))
    # the same 14 cm of pipe with one socket only, its other end in the open: a partial view, not reported
    free = [p for p in _segments(parts[:3], cfg) if p.length < cfg.min_partial_length]
    (end,) = free
    assert not end.between_fittings and not end.reported(cfg)
