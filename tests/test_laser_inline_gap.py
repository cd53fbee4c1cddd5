"""An object between two collinear pipe ends needs a part in the gap: one pipe cut in two (at a short
bump of its surface, or where it runs on through a stretch not fitted) is no object; a socket or a
valve body between them is one."""

import numpy as np

from frontends.laser.config import ObjectConfig, PipeConfig
from frontends.laser.objects import segment_objects
from frontends.laser.pipes import _make_pipe

R = 0.0315  # the tank's pipe radius
UP = np.array([0.0, 0.0, -1.0])  # the sensor looks down along +z


def _shell(rng, x0: float, x1: float, radius: float, n: int):
    th = rng.uniform(-1.3, 1.3, n)  # the side facing the sensor
    return np.column_stack([rng.uniform(x0, x1, n), radius * np.sin(th), 2.0 - radius * np.cos(th)]), th


def _two_pipes_and_gap(gap: float, gap_radius: float, body: bool = False):
    """Points of two pipes along +x from x = -0.5 to 0 and from ``gap`` to ``gap`` + 0.5 (their inlier
    indices), with a cylinder of ``gap_radius`` between them (among no pipe's inliers), and optionally
    a valve's body (points 5-7 cm above the axis) over the gap."""
    rng = np.random.default_rng(3)
    parts, inliers, n = [], [], 0
    for x0 in (-0.5, gap):
        parts.append(_shell(rng, x0, x0 + 0.5, R, 600)[0])
        inliers.append(np.arange(n, n + 600))
        n += 600
    parts.append(_shell(rng, 0.0, gap, gap_radius, int(1500 * gap))[0])
    if body:
        parts.append(
            np.column_stack([rng.uniform(0.0, gap, 60), rng.uniform(-0.02, 0.02, 60), rng.uniform(1.93, 1.95, 60)])
        )
    return np.vstack(parts), inliers


def _pipes(points, inliers):
    cfg = PipeConfig(radius_prior=R)
    th = np.arctan2(points[:, 1], 2.0 - points[:, 2])
    normals = np.column_stack([np.zeros(len(points)), np.sin(th), -np.cos(th)])
    return [_make_pipe(points, normals, idx, np.array([1.0, 0, 0]), cfg) for idx in inliers]


def _objects(gap: float, gap_radius: float, body: bool = False):
    points, inliers = _two_pipes_and_gap(gap, gap_radius, body)
    return segment_objects(points, _pipes(points, inliers), UP, ObjectConfig())


def test_one_pipe_cut_at_a_short_bump_is_no_inline_object():
    # the pipe stage cuts a pipe where 4 cm of its surface stand 4 mm out (noise): one pipe, no part
    assert _objects(0.045, R + 0.004) == []


def test_one_pipe_running_on_through_the_gap_is_no_inline_object():
    assert _objects(0.10, R) == []


def test_a_socket_between_two_pipes_is_one_inline_object():
    (o,) = _objects(0.09, R + 0.0045)  # the tank's R-Socket: 4.5 mm wider, 8.8 cm between its ports
    assert o.configuration == 2 and abs(o.position[0] - 0.045) < 0.01


def test_a_valve_body_in_a_short_gap_is_one_inline_object():
    (o,) = _objects(0.045, R, body=True)
    assert o.configuration == 2
