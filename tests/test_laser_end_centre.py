"""Where an object at a lone pipe end is placed along the pipe (issue 21: lone-end objects were placed
3-4 cm short of elbows and tees, by the middle of their whole visible extent)."""

import numpy as np

from frontends.laser.config import ObjectConfig
from frontends.laser.objects import lone_end_depth

R_PIPE = 0.0315
OUT = np.array([1.0, 0.0, 0.0])  # the pipe (along −x) ends at the origin; the object lies along +x


def _shell(rng, axis_point, axis, radius, t0, t1, n):
    """``n`` points on the upper half of a cylinder (radius, unit axis through axis_point) from t0 to t1."""
    a = axis / np.linalg.norm(axis)
    e1 = np.cross(a, [0.0, 0.0, 1.0]) if abs(a[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    th = rng.uniform(0, np.pi, n)
    t = rng.uniform(t0, t1, n)
    return axis_point + np.outer(t, a) + radius * (np.outer(np.cos(th), e1) + np.outer(np.sin(th), e2))


def test_an_elbow_seen_from_one_port_is_centred_where_its_ports_cross():
    rng = np.random.default_rng(0)
    centre = 0.07  # where the elbow's ports' axes cross, beyond the pipe's end
    wall = R_PIPE + 0.006
    port_in = _shell(rng, np.zeros(3), OUT, wall, 0.0, centre + wall, 600)  # its first port, round the pipe
    port_out = _shell(rng, np.array([centre, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), wall, 0.0, 0.09, 600)
    depth = lone_end_depth(np.vstack([port_in, port_out]), np.zeros(3), OUT, R_PIPE, ObjectConfig())
    assert abs(depth - centre) < 0.008
    whole = lone_end_depth(np.vstack([port_in, port_out]), np.zeros(3), OUT, R_PIPE, ObjectConfig(centre_margin=10.0))
    assert whole < centre - 0.01  # the middle of the whole extent: short of the centre


def test_a_symmetric_body_and_a_plain_socket_are_centred_on_their_middle():
    rng = np.random.default_rng(1)
    body = _shell(rng, np.zeros(3), OUT, 0.075, 0.03, 0.17, 1500)  # a valve body 0.14 m long, wider than its pipe
    sleeve = _shell(rng, np.zeros(3), OUT, R_PIPE + 0.006, 0.0, 0.03, 200)
    assert abs(lone_end_depth(np.vstack([sleeve, body]), np.zeros(3), OUT, R_PIPE, ObjectConfig()) - 0.10) < 0.006
    socket = _shell(rng, np.zeros(3), OUT, R_PIPE + 0.005, 0.0, 0.06, 500)  # nothing 25 mm off: its whole extent
    assert abs(lone_end_depth(socket, np.zeros(3), OUT, R_PIPE, ObjectConfig()) - 0.03) < 0.004
