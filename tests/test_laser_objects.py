"""Object segmentation at pipe ends: connectivity configurations, mushroom crop, positions."""

import numpy as np

from frontends.laser import LaserConfig, segment_scan
from frontends.laser.objects import _line_intersection, box_frame, configuration_of
from tests.support.synthetic import SynthScan, cached_scan


def test_configurations():
    x, y = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    assert configuration_of(x[None], 30) == 1
    assert configuration_of(np.array([x, -x]), 30) == 2
    assert configuration_of(np.array([x, -np.array([0.97, 0.24, 0])]), 30) == 2  # 14° off: still collinear
    assert configuration_of(np.array([x, y]), 30) == 3
    assert configuration_of(np.array([x, -x, y]), 30) == 4


def test_line_intersection_and_box_frame():
    p = np.array([[0.0, -1.0, 2.0], [1.0, 0.0, 2.0]])
    d = np.array([[0, 1.0, 0], [-1.0, 0, 0]])
    assert np.allclose(_line_intersection(p, d), [0, 0, 2.0])
    R = box_frame(np.array([1.0, 0, 0.1]), np.array([0, 0, -1.0]))
    assert np.allclose(R.T @ R, np.eye(3))
    assert R[:, 2] @ [0, 0, -1.0] > 0.99 and abs(R[:, 2] @ R[:, 0]) < 1e-12


def test_objects_segmented_once_with_configuration_and_position():
    scan = cached_scan()
    seg = segment_scan(scan.points, LaserConfig())
    truth = scan.scene.objects
    assert len(seg.objects) == len(truth)
    for o in truth:
        d = np.linalg.norm([s.position - o.center for s in seg.objects], axis=1)
        assert (d < 0.15).sum() == 1  # exactly one segment
        found = seg.objects[int(d.argmin())]
        assert d.min() < 0.05
        assert found.configuration == o.configuration
        assert len(found.directions) == len(o.pipes)


def test_mushroom_crop_takes_the_valve_handle_and_no_floor():
    scan = cached_scan()
    seg = segment_scan(scan.points, LaserConfig())
    pts = seg.structure_points
    valve = scan.scene.objects[4]  # one connection, with a handle above the body
    o = min(seg.objects, key=lambda s: np.linalg.norm(s.position - valve.center))
    cloud = pts[o.indices]
    top_of_body = valve.center[2] - valve.size[2] / 2
    handle = cloud[:, 2] < top_of_body - 0.05  # up is −z: the stem and hand wheel above the body
    assert handle.sum() >= 10
    assert (cloud[:, 2] > top_of_body).sum() >= 10  # and the body, apart from the wheel (its stem unseen)
    assert cloud[:, 2].max() < scan.scene.floor_z - 0.01  # nothing of the floor
    # the crop's points are the object's: most voxels of the cloud come from object rays
    raw = seg.raw_indices(o.indices)
    assert (scan.kind[raw] == SynthScan.OBJECT).mean() > 0.9


def test_pipe_ends_join_by_geometry():
    from frontends.laser.config import ObjectConfig
    from frontends.laser.objects import join_ends

    cfg = ObjectConfig()
    x, y = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    # pipe 0 ends at x = −0.06 going out +x; pipe 1 starts at x = +0.06 going out −x: an in-line valve
    # pipe 2 ends 8 cm short of a junction at (1, 0) from −y; pipe 3 leaves it towards +x 8 cm away
    # pipe 4 ends at (0, 0.5) going +x but on another line: nothing to do with the others
    ends = np.array([[-0.06, 0, 0], [0.06, 0, 0], [1.0, -0.08, 0], [1.08, 0, 0], [0.0, 0.5, 0]])
    out = np.array([x, -x, y, -x, x])
    owner = np.arange(5)
    g = join_ends(ends, out, owner, cfg)
    assert g[0] == g[1] and g[2] == g[3]
    assert len({g[0], g[2], g[4]}) == 3
    # two ends of one pipe never join, even when they would face each other
    g = join_ends(ends[:2], out[:2], np.array([0, 0]), cfg)
    assert g[0] != g[1]
    # facing ends farther apart than any in-line object stay apart
    g = join_ends(np.array([[-0.2, 0, 0], [0.2, 0, 0]]), np.array([x, -x]), np.arange(2), cfg)
    assert g[0] != g[1]


def _pipe_with_end(cap: bool, body: bool):
    """A pipe along +x ending at x = 0 (radius 31.5 mm, sensor above at −z), with its end cap
    seen and/or a 12 cm body beyond the end. Returns (points, pipes)."""
    from frontends.laser.config import PipeConfig
    from frontends.laser.pipes import _make_pipe

    rng = np.random.default_rng(7)
    r = 0.0315
    th = rng.uniform(-1.3, 1.3, 600)
    x = rng.uniform(-0.5, 0.0, 600)
    shell = np.column_stack([x, r * np.sin(th), 2.0 - r * np.cos(th)])
    normals = np.column_stack([np.zeros(600), np.sin(th), -np.cos(th)])
    parts = [shell]
    if cap:  # the end disc, facing +x
        rr, ph = r * np.sqrt(rng.uniform(0, 1, 40)), rng.uniform(-np.pi, 0, 40)
        parts.append(np.column_stack([np.zeros(40), rr * np.cos(ph), 2.0 + rr * np.sin(ph)]))
    if body:  # the top of a 12 cm box body, 10 cm wide, its top 6 cm above the axis
        parts.append(np.column_stack([rng.uniform(0.0, 0.12, 150), rng.uniform(-0.05, 0.05, 150), np.full(150, 1.94)]))
    pts = np.vstack(parts)
    pipe = _make_pipe(
        pts,
        np.vstack([normals, np.zeros((len(pts) - 600, 3))]),
        np.arange(600),
        np.array([1.0, 0, 0]),
        PipeConfig(radius_prior=r),
    )
    return pts, [pipe]


def test_a_lone_pipe_end_needs_an_object_of_its_own():
    from frontends.laser.config import ObjectConfig
    from frontends.laser.objects import segment_objects

    up = np.array([0.0, 0.0, -1.0])
    cfg = ObjectConfig()
    pts, pipes = _pipe_with_end(cap=True, body=False)
    assert len(segment_objects(pts, pipes, up, cfg.model_copy(update={"min_own_points": 0, "min_points": 20}))) == 1
    assert segment_objects(pts, pipes, up, cfg.model_copy(update={"min_points": 20})) == []  # an end cap is no object
    pts, pipes = _pipe_with_end(cap=True, body=True)
    (o,) = segment_objects(pts, pipes, up, cfg)
    assert o.configuration == 1 and abs(o.position[0] - 0.06) < 0.02


def test_a_collinear_pipe_stub_beyond_a_lone_end_gives_two_connections():
    """A second pipe in line beyond the object, too short to be detected, still counts (config 2);
    the open bore of a valve's port just beyond the end does not."""
    from frontends.laser.config import ObjectConfig
    from frontends.laser.objects import collinear_stub, segment_objects

    rng = np.random.default_rng(3)
    cfg, r = ObjectConfig(), 0.0315
    end, out = np.array([0.0, 0, 2.0]), np.array([1.0, 0, 0])

    def shell(t0, t1, n):  # the upper half of a pipe's surface seen from above (axis along x at z = 2)
        ph = rng.uniform(-np.pi, 0, n)
        return np.column_stack([rng.uniform(t0, t1, n), r * np.cos(ph), 2.0 + r * np.sin(ph)])

    assert collinear_stub(shell(0.24, 0.34, 40), end, out, r, cfg)
    assert not collinear_stub(shell(0.03, 0.12, 40), end, out, r, cfg)  # a port's bore, not a pipe
    assert not collinear_stub(shell(0.24, 0.26, 40), end, out, r, cfg)  # one bin: a face, not a pipe
    up = np.array([0.0, 0.0, -1.0])
    pts, pipes = _pipe_with_end(cap=True, body=True)
    (o,) = segment_objects(np.vstack([pts, shell(0.22, 0.34, 60)]), pipes, up, cfg)
    assert o.configuration == 2 and len(o.directions) == 2 and o.directions[0] @ o.directions[1] < -0.99


def test_a_fitting_body_fitted_as_a_short_pipe_between_collinear_pipes_is_one_inline_object():
    """A tee seen without its branch: its straight body, fitted as an 8 cm pipe between the two pipes
    in line, adds two ends on their line. Four ends, two directions: two collinear connections,
    centred between the pipes (as a junction its centre would be the crossing of parallel lines)."""
    from frontends.laser.config import ObjectConfig
    from frontends.laser.objects import _site

    cfg = ObjectConfig()
    x = np.array([1.0, 0, 0])
    tilt = np.array([np.cos(0.03), np.sin(0.03), 0.0])  # fits are never exactly parallel
    ends = np.array([[-0.10, 0, 2.0], [-0.04, 0.001, 2.0], [0.04, -0.001, 2.0], [0.10, 0.002, 2.0]])
    out = np.array([x, -tilt, tilt, -x])
    guess = ends + 0.15 * out
    site = _site(np.arange(4), ends, out, guess, np.array([0, 0, -1.0]), cfg)
    assert site.config == 2 and len(site.dirs) == 2 and site.dirs[0] @ site.dirs[1] < -0.99
    assert np.linalg.norm(site.center - [0, 0, 2.0]) < 0.01
    # the centre is the middle of the gap between the pipes, wherever the body piece's axis lies
    off_line = ends + np.array([0, 0.02, 0]) * np.array([[0], [1], [1], [0]])
    site = _site(np.arange(4), off_line, out, guess, np.array([0, 0, -1.0]), cfg)
    assert site.config == 2 and abs(site.center[1]) < 0.003
    # a real junction keeps its crossing: a pipe leaving sideways makes three directions
    y = np.array([0, 1.0, 0])
    site = _site(
        np.arange(3),
        np.array([[-0.1, 0, 2.0], [0.1, 0, 2.0], [0, -0.1, 2.0]]),
        np.array([x, -x, y]),
        guess[:3],
        np.array([0, 0, -1.0]),
        cfg,
    )
    assert site.config == 4 and np.linalg.norm(site.center - [0, 0, 2.0]) < 1e-9


def _pipe_running_on(beyond_radius: float, beyond_to: float, then_pipe_to: float = 0.0, handle: bool = False):
    """A pipe along +x (radius 31.5 mm, seen from above) fitted up to x = 0, with more of a
    cylinder of ``beyond_radius`` from x = 0 to ``beyond_to`` that is not among its inliers, then
    (to ``then_pipe_to``) the pipe's own cylinder again, and optionally a handle above the end."""
    from frontends.laser.config import PipeConfig
    from frontends.laser.pipes import _make_pipe

    rng = np.random.default_rng(5)
    r = 0.0315

    def shell(x0, x1, radius, n):
        th = rng.uniform(-1.3, 1.3, n)
        return np.column_stack([rng.uniform(x0, x1, n), radius * np.sin(th), 2.0 - radius * np.cos(th)]), th

    fitted, th = shell(-0.5, 0.0, r, 600)
    normals = np.column_stack([np.zeros(600), np.sin(th), -np.cos(th)])
    pipe = _make_pipe(fitted, normals, np.arange(600), np.array([1.0, 0, 0]), PipeConfig(radius_prior=r))
    parts = [fitted, shell(0.0, beyond_to, beyond_radius, 120)[0]]
    if then_pipe_to > beyond_to:
        parts.append(shell(beyond_to, then_pipe_to, r, 300)[0])
    if handle:  # a lever 6-8 cm above the axis (up is −z), over the end
        parts.append(
            np.column_stack([rng.uniform(0.0, 0.1, 40), rng.uniform(-0.01, 0.01, 40), rng.uniform(1.92, 1.94, 40)])
        )
    return np.vstack(parts), [pipe]


def test_a_pipe_running_on_past_its_fitted_end_is_no_object_but_a_socket_is():
    from frontends.laser.config import ObjectConfig
    from frontends.laser.objects import segment_objects

    up, cfg = np.array([0.0, 0.0, -1.0]), ObjectConfig()
    pts, pipes = _pipe_running_on(0.0315, 0.15)  # the sparse far part of the same pipe
    assert segment_objects(pts, pipes, up, cfg) == []
    pts, pipes = _pipe_running_on(0.0315 + 0.0045, 0.06)  # a socket: 4.5 mm wider than its pipe
    (o,) = segment_objects(pts, pipes, up, cfg)
    assert o.configuration == 1 and 0.0 < o.position[0] < 0.06
    # the same socket with a pipe running on behind it, too short to have been detected
    pts, pipes = _pipe_running_on(0.0315 + 0.0045, 0.06, then_pipe_to=0.20)
    assert len(segment_objects(pts, pipes, up, cfg)) == 1
    # points nearer the axis than the pipe's surface beyond the end (its end cap, the inside of an
    # open end: the tank's free pipe ends) are no fitting (issue 21: false objects at lone ends)
    pts, pipes = _pipe_running_on(0.0315 - 0.006, 0.06)
    assert segment_objects(pts, pipes, up, cfg) == []
    # points at the pipe's level beyond the end, but a handle above it: an object
    pts, pipes = _pipe_running_on(0.0315, 0.15, handle=True)
    assert len(segment_objects(pts, pipes, up, cfg)) == 1


def test_one_object_per_cluster_the_best_supported():
    """Objects sharing at least half of the smaller cloud are one: the one on the longest pipes stays
    (a valve's lever fitted as a 10 cm pipe puts a second object on the valve's points)."""
    from frontends.laser.objects import SegmentedObject, one_per_cluster
    from frontends.laser.pipes import Pipe

    def pipe(length):
        return Pipe(np.zeros(3), np.array([length, 0, 0]), np.array([1.0, 0, 0]), 0.03, np.arange(0), np.eye(6))

    def obj(indices, pipe_ids):
        return SegmentedObject(np.zeros(3), np.eye(3), np.asarray(indices), np.zeros((1, 3)), 1, pipe_ids)

    pipes = [pipe(0.10), pipe(0.80), pipe(0.50), pipe(0.40), pipe(0.40), pipe(1.50)]
    lever = obj(np.arange(30, 130), (0,))  # listed first, on the short piece, the larger cloud
    valve = obj(np.arange(0, 70), (1,))  # shares 40 of its 70 points with the lever
    other = obj(np.arange(200, 260), (0,))  # its own points
    near = obj(np.arange(120, 190), (2,))  # shares 10 of 70 with the lever, none with the valve
    assert one_per_cluster([lever, valve, other, near], pipes, 300) == [valve, other, near]
    # where two pipes meet (a junction) beats a lone end, even of a longer pipe
    junction = obj(np.arange(0, 60), (3, 4))
    lone = obj(np.arange(20, 100), (5,))
    assert one_per_cluster([lone, junction], pipes, 300) == [junction]
