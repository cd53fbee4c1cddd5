"""A fitting's part standing over a pipe line on the seabed (a valve's lever fitted as a short pipe
across the line) is no pipe; a branch meeting the line at a tee, and pipes crossing on a rack, are."""

import numpy as np

from frontends.laser.config import PipeConfig
from frontends.laser.pipes import Pipe, over_a_line

UP = np.array([0.0, 0.0, 1.0])
R = 0.055


def _pipe(p, q, r=R) -> Pipe:
    p, q = np.asarray(p, float), np.asarray(q, float)
    return Pipe(p, q, (q - p) / np.linalg.norm(q - p), r, np.arange(10), np.eye(6))


def _line() -> Pipe:
    """A 0.6 m line along x, its axis at height 0."""
    return _pipe([0.0, 0.0, 0.0], [0.6, 0.0, 0.0])


def _lever(height: float, x: float = 0.7, length: float = 0.25, r: float = R) -> Pipe:
    """A segment along y crossing over x, its axis ``height`` above the line's."""
    return _pipe([x, -0.1, height], [x, -0.1 + length, height], r)


def test_a_lever_over_the_line_past_its_end_is_dropped_and_the_line_kept():
    cfg = PipeConfig()
    pipes = [_line(), _lever(0.33)]
    assert over_a_line(pipes, np.array([True, False]), UP, cfg).tolist() == [False, True]
    # found first, the lever is dropped all the same (order does not matter)
    assert over_a_line(pipes[::-1], np.array([False, True]), UP, cfg).tolist() == [True, False]


def test_a_branch_at_a_tee_meets_the_line_axis_to_axis_and_is_kept():
    cfg = PipeConfig()
    branch = _pipe([0.65, 0.0, 0.0], [0.65, 0.25, 0.0])  # from the line's axis, on the seabed
    assert not over_a_line([_line(), branch], np.array([True, True]), UP, cfg).any()
    low = _lever(0.09)  # its axis less than the two radii above the line's: it can meet it
    assert not over_a_line([_line(), low], np.array([True, False]), UP, cfg).any()


def test_only_over_a_line_lying_on_the_ground_short_across_and_near():
    cfg = PipeConfig()
    lever = _lever(0.33)
    # a rack's pipes cross over each other clear of the ground (the tank)
    assert not over_a_line([_line(), lever], np.array([False, False]), UP, cfg).any()
    # under the line (along up) is no fitting's part over it
    assert not over_a_line([_line(), _lever(-0.33)], np.array([True, False]), UP, cfg).any()
    # as long as 8 line radii (0.44 m) or more: a pipe of its own crossing over
    assert not over_a_line(
        [_pipe([0, 0, 0], [0.9, 0, 0]), _lever(0.33, length=0.45)], np.array([True, False]), UP, cfg
    ).any()
    # along the line, not across it
    along = _pipe([0.7, 0.0, 0.33], [0.95, 0.0, 0.33])
    assert not over_a_line([_line(), along], np.array([True, False]), UP, cfg).any()
    # farther past the line's end than that length
    assert not over_a_line([_line(), _lever(0.33, x=1.1)], np.array([True, False]), UP, cfg).any()
    # switched off
    off = cfg.model_copy(update={"over_line_max_radii": 0.0})
    assert not over_a_line([_line(), lever], np.array([True, False]), UP, off).any()


def _gap_runs(open_gap):
    """The runs of a 0.40 m pipe's inliers followed, after a 0.15 m gap, by 6 cm of a stone's."""
    from frontends.laser.pipes import split_at_fittings

    t = np.concatenate([np.linspace(0.0, 0.40, 200), np.linspace(0.55, 0.61, 30)])
    return split_at_fittings(t, np.zeros(len(t)), np.zeros(0), PipeConfig(), None, None, None, open_gap)


def test_a_gap_where_the_pipe_is_absent_is_not_bridged():
    assert [len(r) for r in _gap_runs(None)] == [230]  # bridged (up to max_gap: an occlusion)
    assert [len(r) for r in _gap_runs(lambda t0, t1: False)] == [230]
    assert [len(r) for r in _gap_runs(lambda t0, t1: True)] == [200, 30]


def test_rays_end_inside_a_missing_pipe_and_on_a_present_one():
    from frontends.laser.pipes import Rays

    # looking down (+z) at a pipe along x, axis 1 m away, radius 5 cm, present over x 0-0.2 m and
    # absent over 0.3-0.5 m, where the rays end on the seabed 3 cm under its axis
    y = np.linspace(-0.03, 0.03, 7)
    on = [(x, v, 1.0 - np.sqrt(0.05**2 - v * v)) for x in np.linspace(0.0, 0.2, 21) for v in y]
    bare = [(x, v, 1.03) for x in np.linspace(0.3, 0.5, 21) for v in y]
    rays = Rays(np.array(on + bare))
    c, a, cfg = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]), PipeConfig()
    deep, crossing = rays.hollow(c, a, 0.05, 0.3, 0.5, cfg)
    assert crossing >= 50 and deep == crossing
    deep, crossing = rays.hollow(c, a, 0.05, 0.0, 0.2, cfg)
    assert crossing >= 50 and deep == 0
    # the see-through test (rays past the cylinder's far side) sees neither: the seabed is under it
    assert rays.see_through(c, a, 0.05, 0.3, 0.5, cfg)[0] == 0
