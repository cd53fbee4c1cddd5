"""On the seabed, a fitting at a lying pipe's end that is only a sleeve a few millimetres proud of the
pipe (a socket, a tee's run) is an object (issue 22, stop 43: pipeline seeds 15, 23, 19, 25, 34 map the
pipe straight through sockets and tees that got no object view, their bodies not rising over the pipe
by ``own_margin``); stones beside the end, or sand over a buried end (no constant distance from the
axis), are not."""

import numpy as np

from frontends.laser.config import ObjectConfig, PipeConfig
from frontends.laser.objects import segment_objects
from frontends.laser.pipes import _make_pipe

R = 0.055  # the pipeline's 55 mm line
UP = np.array([0.0, 0.0, -1.0])  # the sensor looks down along +z; the pipe's axis at z = 2


def _arc(rng, x0, x1, radius, n):
    """Points of the upper half of a cylinder of ``radius`` along x (the part a sensor above sees)."""
    th = rng.uniform(-1.2, 1.2, n)
    r = radius + rng.normal(0.0, 0.001, n)
    return np.column_stack([rng.uniform(x0, x1, n), r * np.sin(th), 2.0 - r * np.cos(th)]), th


def _scene(beyond: str, seed: int):
    """A 0.3 m pipe lying along +x ending at x = 0, and beyond or beside its end: a sleeve 5 mm proud
    of it ("sleeve", 0-10 cm, then the pipe on, not detected), stones on the seabed beside the end
    ("stones"), the pipe buried under flat sand 5 mm above its top ("sand"), a few points a little off
    it on one flank, then the pipe on ("flank"), or nothing but the pipe running on ("pipe")."""
    rng = np.random.default_rng(seed)
    run, th = _arc(rng, -0.3, 0.0, R, 600)
    normals = np.column_stack([np.zeros(len(th)), np.sin(th), -np.cos(th)])
    pipe = _make_pipe(run, normals, np.arange(len(run)), np.array([1.0, 0, 0]), PipeConfig(radius_prior=R))
    if beyond == "sleeve":
        rest = np.vstack([_arc(rng, 0.0, 0.10, R + 0.005, 300)[0], _arc(rng, 0.10, 0.16, R, 150)[0]])
    elif beyond == "flank":  # a few points 8 mm off the pipe, on one flank only (seen at a free end)
        th = rng.uniform(-1.1, -0.7, 12)
        r = R + 0.008 + rng.normal(0.0, 0.001, 12)
        flank = np.column_stack([rng.uniform(0.03, 0.07, 12), r * np.sin(th), 2.0 - r * np.cos(th)])
        rest = np.vstack([flank, _arc(rng, 0.09, 0.16, R, 100)[0]])  # and the pipe on, 2 cm on
    elif beyond == "sand":  # the seabed rising over the pipe where it is buried: sand at its top's level
        n = 500
        rest = np.column_stack([rng.uniform(0.0, 0.16, n), rng.uniform(-0.12, 0.12, n), np.full(n, 2.0 - R - 0.005)])
        rest[:, 2] += rng.normal(0.0, 0.001, n)
    elif beyond == "stones":  # two stones on the floor (z = 2 + R) beside the end, 4-5 cm high
        c = np.array([[0.05, 0.12, 2.0 + R], [0.02, -0.13, 2.0 + R]])
        u = rng.normal(size=(300, 3))
        u[:, 2] = -np.abs(u[:, 2])
        rest = np.repeat(c, 150, axis=0) + 0.045 * u / np.linalg.norm(u, axis=1)[:, None]
    else:
        rest = _arc(rng, 0.0, 0.16, R, 450)[0]
    points = np.vstack([run, rest])
    return segment_objects(points, [pipe], UP, ObjectConfig(), lying=np.array([True]))


def test_a_sleeve_at_a_lying_pipe_end_is_an_object():
    for seed in range(5):
        objects = _scene("sleeve", seed)
        assert len(objects) == 1, seed
        assert abs(objects[0].position[0] - 0.05) < 0.04  # the sleeve's middle, on the axis
        np.testing.assert_allclose(objects[0].position[1:], [0.0, 2.0], atol=0.01)


def test_stones_beside_sand_over_a_flank_or_the_pipe_running_on_are_not():
    for seed in range(5):
        assert _scene("stones", seed) == [], seed
        assert _scene("sand", seed) == [], seed
        assert _scene("flank", seed) == [], seed
        assert _scene("pipe", seed) == [], seed
