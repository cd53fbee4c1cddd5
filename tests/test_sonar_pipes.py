"""Pipe detection on hand-made elevation maps (frontends/sonar/pipes.py): a pipe beside a wide raised
stretch of seabed (where the seabed level lags a slope), and a pipe sampled more sparsely than the
map's cells, are found at the right place and radius."""

import numpy as np

from frontends.sonar.config import PipeDetectionConfig
from frontends.sonar.grid import ElevationMap, GridSpec
from frontends.sonar.pipes import detect_pipes

CELL = 0.04
SEABED = 20.0


def _scene(height_above, rng, shape=(250, 200)):
    """An elevation map (north 0–10 m, east 0–8 m) of a seabed at SEABED with ``height_above(n, e)``
    above it (2 cm of noise), and the seabed level (flat: what the estimate of the level gives)."""
    spec = GridSpec(0.0, 0.0, CELL, shape)
    N, E = spec.centres()
    n, e = np.meshgrid(N, E, indexing="ij")
    h = height_above(n, e) + rng.normal(0.0, 0.02, shape)
    em = ElevationMap(spec, SEABED - h, np.ones(shape, int))
    return em, np.full(shape, SEABED)


def _pipe_height(n, e, a, b, r, lift):
    """Height above the seabed of a pipe of radius r on the axis a → b (north, east), its bottom
    ``lift(s)`` above the seabed at s metres along it (negative: buried); 0 off the pipe."""
    d = (np.asarray(b) - a) / np.linalg.norm(np.asarray(b) - a)
    rel_n, rel_e = n - a[0], e - a[1]
    s = rel_n * d[0] + rel_e * d[1]
    u = -rel_n * d[1] + rel_e * d[0]
    on = (np.abs(u) < r) & (s >= 0) & (s <= np.linalg.norm(np.asarray(b) - a))
    top = lift(s) + r + np.sqrt(np.maximum(r * r - u * u, 0.0))
    return np.where(on, np.maximum(top, 0.0), 0.0)


def _found(segs, a, b, r):
    """The segments on the true axis a → b: within 0.1 m of it, 5° of its direction, radius ±0.05."""
    d = (np.asarray(b) - a) / np.linalg.norm(np.asarray(b) - a)
    nrm = np.array([-d[1], d[0]])
    out = []
    for s in segs:
        v = (s.q - s.p)[:2] / np.linalg.norm((s.q - s.p)[:2])
        lat = max(abs((x[:2] - a) @ nrm) for x in (s.p, s.q))
        if lat < 0.1 and abs(v @ d) > np.cos(np.radians(5)) and abs(s.radius - r) < 0.05:
            out.append(s)
    return out


def test_a_pipe_across_a_raised_stretch_of_seabed_is_found():
    """A 0.1 m pipe runs beside a 5.5 m wide stretch of seabed 0.1 m above the level (as at the edge
    of a window on a slope, the level lagging it). Before, RANSAC's lines ran through the stretch
    (each with more ridge cells than the pipe), and the lines that gave no pipe used up the
    window's ``max_pipes`` before the pipe's."""
    rng = np.random.default_rng(3)
    a, b = np.array([1.0, 0.5]), np.array([9.0, 2.0])
    r = 0.1

    def height(n, e):
        return np.where(e > 2.5, 0.10, 0.0) + _pipe_height(n, e, a, b, r, lambda s: 0.0 * s)

    em, ground = _scene(height, rng)
    segs = detect_pipes(em, ground, PipeDetectionConfig(), rng=np.random.default_rng(0))
    found = _found(segs, a, b, r)
    assert found, [(s.p.round(2), s.q.round(2), round(s.radius, 2)) for s in segs]
    assert max(s.length for s in found) > 3.0


def test_a_pipe_sampled_more_sparsely_than_the_cells_is_found():
    """A 0.1 m pipe across the vehicle's track (field 59's): the pings, 5.5 cm apart along the track
    (0.69 m/s at 12.5 Hz), leave every fourth 4 cm cell across the pipe empty. Before, the speck
    filter's opening broke the pipe's band into pieces too small to be a pipe."""
    rng = np.random.default_rng(5)
    a, b = np.array([1.0, 3.0]), np.array([9.0, 3.1])
    r = 0.1
    em, ground = _scene(lambda n, e: _pipe_height(n, e, a, b, r, lambda s: 0.0 * s), rng)
    _, E = em.spec.centres()
    pings = np.arange(0.0, E[-1] + CELL, 0.055)
    sampled = np.isin(np.arange(len(E)), np.floor(pings / CELL).astype(int))
    em.depth[:, ~sampled] = np.nan
    segs = detect_pipes(em, ground, PipeDetectionConfig(), rng=np.random.default_rng(0))
    found = _found(segs, a, b, r)
    assert found, [(s.p.round(2), s.q.round(2), round(s.radius, 2)) for s in segs]
    assert max(s.length for s in found) > 5.0
