"""An object at the end of a short held-radius run (``objects_only``: a narrow arc at the view's edge
given to the object stage only, ``pipes.held_short_objects``) is placed along the pipe only to within
the body box (issue 22, stop 43: pipeline seed 15's valve, whose views from such runs lay 15 cm apart
along the line with 2.6 cm declared, started two tracks and the valve was never mapped). Elsewhere
the lone end's σ is unchanged, and the position is the same either way."""

import numpy as np

from frontends.laser.config import ObjectConfig, PipeConfig
from frontends.laser.objects import segment_objects
from frontends.laser.pipes import _make_pipe

R = 0.055  # the pipeline's 55 mm line
UP = np.array([0.0, 0.0, -1.0])  # the sensor looks down along +z


def _valve_at_end(objects_only: bool, seed: int):
    """A 0.2 m run along +x (axis at z = 2) ending at x = 0, a valve's body (a box top 8 cm above the
    axis, 12 cm long) beyond it; the run held for the objects only or a pipe as any."""
    rng = np.random.default_rng(seed)
    th = rng.uniform(-1.0, 1.0, 400)
    r = R + rng.normal(0.0, 0.004, 400)
    run = np.column_stack([rng.uniform(-0.2, 0.0, 400), r * np.sin(th), 2.0 - r * np.cos(th)])
    normals = np.column_stack([np.zeros(400), np.sin(th), -np.cos(th)])
    pipe = _make_pipe(run, normals, np.arange(400), np.array([1.0, 0, 0]), PipeConfig(radius_prior=R))
    pipe.objects_only = objects_only
    top = np.column_stack([rng.uniform(0.0, 0.12, 200), rng.uniform(-0.06, 0.06, 200), np.full(200, 1.92)])
    body = top + rng.normal(0.0, 0.004, (200, 3))
    return segment_objects(np.vstack([run, body]), [pipe], UP, ObjectConfig())


def test_an_object_at_a_held_run_end_is_loose_along_the_pipe_only():
    cfg = ObjectConfig()
    for seed in range(5):
        (held,) = _valve_at_end(True, seed)
        (plain,) = _valve_at_end(False, seed)
        assert held.configuration == plain.configuration == 1
        np.testing.assert_allclose(held.position, plain.position)
        along = np.sqrt(np.diag(held.covariance))
        assert np.isclose(along[0], cfg.body_size[0] / np.sqrt(12.0))  # 8.7 cm, not end_sigma's 2.6
        np.testing.assert_allclose(along[1:], cfg.end_sigma[1], atol=1e-9)  # across and up: as any lone end
        np.testing.assert_allclose(np.sqrt(np.diag(plain.covariance)), [cfg.end_sigma[0], *[cfg.end_sigma[1]] * 2])
