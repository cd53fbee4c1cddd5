"""The shape tests of a pipe lying on the seabed: a straight pipe against a stone's domed top."""

import numpy as np

from frontends.laser.pipe_shape import bow
from frontends.laser.pipes import Pipe


def _segment(dome_m: float, noise_m: float, seed: int = 0) -> tuple[Pipe, np.ndarray]:
    """A 0.2 m segment along x of radius 5 cm (its upper half-shell sampled at ~1 cm) whose surface
    lies ``dome_m`` nearer the axis at both ends than in the middle (a parabola along the axis),
    with Gaussian noise across it."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0.0, 0.2, 400)
    phi = rng.uniform(-np.pi / 2, np.pi / 2, 400)
    u = (x - 0.1) / 0.1
    rho = 0.05 - dome_m * u * u + rng.normal(0.0, noise_m, 400)
    pts = np.column_stack([x, rho * np.sin(phi), -rho * np.cos(phi)])
    pipe = Pipe(np.zeros(3), np.array([0.2, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]), 0.05, np.arange(400), np.eye(6))
    return pipe, pts


def test_bow_is_the_dome_of_the_surface_and_zero_on_a_straight_pipe():
    pipe, pts = _segment(0.0, 0.003)
    b, se = bow(pipe, pts)
    assert abs(b) < 3 * se and se < 0.002  # a straight pipe: no bow beyond its noise
    pipe, pts = _segment(0.010, 0.003)
    b, se = bow(pipe, pts)
    assert abs(b - 0.010) < 3 * se and b > 0.004  # a 1 cm dome (a stone's top) is measured as such
