"""A pipe seen over a narrow arc at stereo noise (issue 22, pipeline seed 15's valve): its free fit
reads a radius above the range, so without a known radius it is never found; with the pipeline's
nominal radii (``pipes.nominal_radii``) it is, with the nominal radius held."""

import numpy as np
import pytest

from frontends.laser.config import LaserConfig, PipeConfig
from frontends.laser.evaluation import matching_pipe
from frontends.laser.frontend import segment_scan
from frontends.laser.pipes import free_radius


def _seed15_cloud(t_s: float):
    """One stereo cloud of pipeline scene 15 at ``t_s`` s into its track, rendered by the simulator's
    stereo model (its own noise draw), with the sensor's true pose, the truth pipes and radii."""
    import semslam.sim.pipeline_mission as pm
    from semslam.sim.pipeline_config import PipelineSimConfig

    cfg = PipelineSimConfig(seed=15)
    lay_rng = pm._stream(cfg.seed, "pipeline_layout")
    heading = float(lay_rng.uniform(0, 2 * np.pi))
    length = float(lay_rng.uniform(*cfg.layout.length_m))
    seabed = pm.make_seabed(cfg.seabed, heading, 0.5 * length + cfg.seabed.margin_m, pm._stream(15, "pipeline_seabed"))
    layout = pm.make_pipeline(cfg.layout, seabed, heading, length, lay_rng)
    rocks = pm.make_rocks(cfg.seabed, seabed, layout, pm._stream(15, "pipeline_rocks"))
    scene = pm.PipelineScene(seabed, rocks, layout, cfg.seabed.roughness_m, pm._stream(15, "scene"))
    track = pm.InspectionTrack(cfg.trajectory, layout.lines[0])
    t = np.array([t_s])
    stamps = np.array([int(cfg.start_time_s * 1e9) + int(t_s * 1e9)])
    cloud = pm.simulate_stereo(cfg.stereo, track, scene, stamps, t, np.random.default_rng(0)).measurements[0]
    T_WS = track.poses(t)[0] @ cfg.stereo.mount.matrix()
    return cloud, T_WS, layout.ground_truth().pipes


@pytest.fixture(scope="module")
def beyond_the_valve():
    """Seed 15, 53.5 s: the 55 mm pipe beyond its butterfly valve, 0.36 m of it seen over ~80°."""
    return _seed15_cloud(53.5)


def _found(cloud, T_WS, cfg: LaserConfig):
    seg = segment_scan(cloud.points, cfg, up=T_WS[:3, :3].T @ np.array([0.0, 0.0, -1.0]), rgb=cloud.rgb)
    return seg, [p for p in seg.pipes if p.reported(seg.pipe_config)]


def test_a_narrow_arc_pipe_is_found_with_its_nominal_radius_held(beyond_the_valve):
    cloud, T_WS, truth = beyond_the_valve
    seg, pipes = _found(cloud, T_WS, LaserConfig())
    assert not pipes  # its free fit leaves the radius range
    radii = sorted({g.radius for g in truth})
    seg, pipes = _found(cloud, T_WS, LaserConfig.model_validate({"pipes": {"nominal_radii": radii}}))
    assert len(pipes) == 1
    (pipe,) = pipes
    P = np.stack([pipe.p, pipe.q]) @ T_WS[:3, :3].T + T_WS[:3, 3]
    g = matching_pipe(P[0], P[1], truth)
    assert g is not None and pipe.radius_held and pipe.radius == pytest.approx(g.radius, abs=1e-9)
    assert pipe.length > 0.3
    r, se = free_radius(np.take(seg.structure_points, pipe.inliers, axis=0), pipe.p, pipe.axis)
    assert r > PipeConfig().max_radius  # (what the free fit reads there)


def test_nominal_radii_must_be_positive():
    with pytest.raises(ValueError, match="nominal_radii"):
        PipeConfig(nominal_radii=[0.05, 0.0])


def test_a_short_cylinder_with_the_radius_held_is_not_a_pipe(beyond_the_valve):
    """The same narrow-arc pipe cut to 0.25 m (its points beyond left out): with the radius held a
    short cylinder on the seabed is no more a pipe than a stone's domed top of that size (which
    a narrow arc fits as well), so it is not kept; only a straight run of ``color_max_length``."""
    cloud, T_WS, truth = beyond_the_valve
    radii = sorted({g.radius for g in truth})
    cfg = LaserConfig.model_validate({"pipes": {"nominal_radii": radii}})
    _, (pipe,) = _found(cloud, T_WS, cfg)
    P = cloud.points.astype(float)
    v = P - pipe.p
    t = v @ pipe.axis
    near = np.sqrt(np.maximum((v * v).sum(axis=1) - t * t, 0.0)) < pipe.radius + 0.03
    cut = cloud.__class__(**{**cloud.__dict__, "points": np.where((near & (t > 0.25))[:, None], np.nan, cloud.points)})
    _, pipes = _found(cut, T_WS, cfg)
    assert not [p for p in pipes if p.radius_held]
    short = LaserConfig.model_validate({"pipes": {"nominal_radii": radii, "color_max_length": 0.15}})
    _, pipes = _found(cut, T_WS, short)
    assert [p for p in pipes if p.radius_held]  # (what the floor keeps out)


def test_a_nominal_radius_far_below_the_range_changes_nothing(beyond_the_valve):
    """A free fit above max_radius is never more than twice a 25 mm pipe's radius: with such a
    nominal radius alone the segmentation is the default one, pipe for pipe."""
    cloud, T_WS, _ = beyond_the_valve
    seg, _ = _found(cloud, T_WS, LaserConfig())
    small, _ = _found(cloud, T_WS, LaserConfig.model_validate({"pipes": {"nominal_radii": [0.025]}}))
    assert len(seg.pipes) == len(small.pipes)
    for a, b in zip(seg.pipes, small.pipes):
        assert np.array_equal(a.inliers, b.inliers) and np.allclose(a.p, b.p) and not b.radius_held


def test_a_valve_at_the_end_of_a_short_held_run_is_found_and_the_run_not_reported():
    """Seed 15, 54.0 s: its butterfly valve at the frame's edge, the pipe beyond it seen over a narrow
    arc for less than ``color_max_length`` (the held floor keeps it from being a pipe). With
    ``held_short_objects`` the run serves the object stage alone: the valve is found at its end,
    and no line observation comes of the run."""
    cloud, T_WS, truth = _seed15_cloud(54.0)
    radii = sorted({g.radius for g in truth})
    valve = np.array([-1.179921572, 0.082017213, 14.868301202])  # the scene's valve 1 (W)
    x = T_WS[:3, :3].T @ (valve - T_WS[:3, 3])
    found = {}
    for on in (False, True):
        cfg = LaserConfig.model_validate({"pipes": {"nominal_radii": radii, "held_short_objects": on}})
        seg, reported = _found(cloud, T_WS, cfg)
        found[on] = [np.linalg.norm(o.position - x) for o in seg.objects if np.linalg.norm(o.position - x) < 0.3]
        assert not [p for p in reported if p.radius_held]
        assert all(p.objects_only == (p.radius_held and p.length < cfg.pipes.color_max_length) for p in seg.pipes)
    assert not found[False]
    assert len(found[True]) == 1 and found[True][0] < 0.08


def test_a_short_held_run_whose_points_a_pipe_took_again_is_left_out():
    """Object-stage runs take no points from the search, so a later cylinder may fit theirs again:
    one sharing more than half of its inliers with a pipe, or with such a run kept before it, goes."""
    from frontends.laser.pipes import Pipe, _apart

    def pipe(idx):
        z = np.zeros(3)
        return Pipe(z, z, np.array([1.0, 0, 0]), 0.05, np.asarray(idx), np.eye(6), objects_only=True)

    kept = [pipe(range(0, 100))]
    a, b, c, d = pipe(range(60, 140)), pipe(range(30, 130)), pipe(range(200, 260)), pipe(range(220, 300))
    assert _apart([a, b, c, d], kept) == [a, c, d]  # b: all taken (by the pipe and a); a, d: half
