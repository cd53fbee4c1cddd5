"""The simulated sonar field: structure library, layout, seabed, lawnmower, multibeam, bag, CLI, preview."""

import hashlib
import json

import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from semslam.errors import ConfigError
from semslam.mission import Attitude, Depth, DvlVelocity, GroundTruthPose, SonarSwath
from semslam.models import structures as st
from semslam.sim import sensors as S
from semslam.sim.field import PIPE, STRUCTURE, FieldScene, make_field
from semslam.sim.field_config import FieldSimConfig, load_field_config
from semslam.sim.field_mission import REFLECTIVITY, simulate_field
from semslam.sim.lawnmower import Lawnmower
from semslam.sim.sonar import simulate_sonar


def short_config(seed: int = 0, **sections) -> FieldSimConfig:
    """Two 12 m lines over structure B (the manifold) with 64 beams: ~70 s of mission."""
    base = {
        "seed": seed,
        "trajectory": {"lines": 2, "line_length_m": 12.0},
        "sonar": {"n_beams": 64},
    }
    for k, v in sections.items():
        base.setdefault(k, {}).update(v)
    cfg = FieldSimConfig.model_validate(base)
    b = make_field(cfg).structures[1].position
    base["trajectory"]["center_m"] = (float(b[0]) - 3.0, float(b[1]))  # B under the first line
    return FieldSimConfig.model_validate(base)


@pytest.fixture(scope="module")
def short_mission():
    return simulate_field(short_config())


def _digest(mission) -> str:
    h = hashlib.sha256()
    for m in mission:
        h.update(f"{type(m).__name__}|{m.stamp}|{m.sensor}|".encode())
        for v in vars(m).values():
            h.update(v.tobytes() if isinstance(v, np.ndarray) else repr(v).encode())
    return h.hexdigest()


def _world_points(mission):
    """Every sonar return in {W} with the true pose of its swath, and the swath's index."""
    T_BS = mission.metadata.sensors["sonar"].T_BS
    poses = {m.stamp: m.matrix() for m in mission.of_type(GroundTruthPose)}
    pts, idx = [], []
    for k, m in enumerate(mission.of_type(SonarSwath)):
        T_WS = poses[m.stamp] @ T_BS  # every swath stamp is a ground-truth stamp
        pts.append(m.points() @ T_WS[:3, :3].T + T_WS[:3, 3])
        idx.append(np.full(len(m.ranges), k))
    return np.vstack(pts), np.concatenate(idx)


# ----------------------------------------------------------------------------------------------
# structure library


def test_structure_library_models():
    lib = st.structure_library()
    assert set(st.STRUCTURES) <= set(lib) and st.STRUCTURES == ("manifold", "plet", "wellhead")
    sizes = {}
    for name in st.STRUCTURES:
        m = lib[name]
        assert m.name == name and m.source is None
        assert 100 < len(m.triangles) <= 3000
        v = m.vertices
        # {M}: z down, the base on the seabed (only the hub clamps sink a few cm), the top at −height
        assert v[:, 2].max() <= 0.031 and -v[:, 2].min() == pytest.approx(m.height)
        assert np.linalg.norm(v[:, :2], axis=1).max() == pytest.approx(m.footprint_radius)
        sizes[name] = (m.size[0], m.size[1], m.height)
        assert m.yaw_period == pytest.approx(2 * np.pi / m.symmetry)
        for h in m.hubs:
            np.testing.assert_allclose(np.linalg.norm(h.direction), 1.0)
            assert h.direction[2] == 0.0  # horizontal
            assert h.pipe_radius in (0.25, 0.10)
            assert -h.position[2] == pytest.approx(h.pipe_radius + 0.01)  # the pipe rests 1 cm above the seabed
    expected = {"manifold": (6.4, 3.8, 2.5), "plet": (3.0, 2.0, 1.5), "wellhead": (1.95, 1.7, 2.5)}
    for name, size in expected.items():
        np.testing.assert_allclose(sizes[name], size, atol=1e-9)
    assert {m.symmetry for m in lib.values() if m.name in st.STRUCTURES} == {1, 2}
    assert [len(lib[n].hubs) for n in st.STRUCTURES] == [4, 1, 1]


def test_structure_meshes_are_deterministic_and_tell_apart_from_above():
    a = st._build("manifold")
    b = st._build("manifold")
    assert np.asarray(a.mesh.vertices).tobytes() == np.asarray(b.mesh.vertices).tobytes()
    assert np.asarray(a.mesh.triangles).tobytes() == np.asarray(b.mesh.triangles).tobytes()
    # top-down height maps (ray cast from above on a 10 cm grid) differ in area and in profile
    lib = st.structure_library()
    profiles = {}
    for name in st.STRUCTURES:
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(lib[name].mesh))
        g = np.arange(-3.5, 3.5, 0.1)
        X, Y = np.meshgrid(g, g, indexing="ij")
        rays = np.zeros((X.size, 6), np.float32)
        rays[:, 0], rays[:, 1], rays[:, 2], rays[:, 5] = X.ravel(), Y.ravel(), -5.0, 1.0
        t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        h = np.where(np.isfinite(t), 5.0 - t, 0.0)
        profiles[name] = (float((h > 0.05).mean()), float(np.quantile(h[h > 0.05], 0.9)))
    areas = sorted(p[0] for p in profiles.values())
    assert areas[1] > 1.5 * areas[0] and areas[2] > 1.5 * areas[1]  # clearly different footprints
    assert profiles["manifold"][1] > 2.0 > profiles["plet"][1]  # a high roof vs a low PLET


def test_hubs_are_clamp_mouths():
    """A ray shot back along a hub's direction from just outside hits the clamp at the hub, and a
    ray leaving the hub outward never re-enters the structure."""
    for name, m in st.structure_library().items():
        if name not in st.STRUCTURES:
            continue
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(m.mesh))
        P = np.array([h.position for h in m.hubs])
        D = np.array([h.direction for h in m.hubs])
        back = scene.cast_rays(o3d.core.Tensor(np.hstack([P + 0.05 * D, -D]).astype(np.float32)))["t_hit"].numpy()
        np.testing.assert_allclose(back, 0.05, atol=1e-4)
        out = scene.cast_rays(o3d.core.Tensor(np.hstack([P + 1e-3 * D, D]).astype(np.float32)))["t_hit"].numpy()
        assert np.isinf(out).all()


def _chamfer_turned(model, angle):
    """Symmetric Chamfer distance (m) between a mesh and its copy turned by ``angle`` about z."""
    V = model.vertices
    samples = np.vstack([V, V[model.triangles].mean(1)])
    R = st.pose_matrix((0, 0, 0), angle)[:3, :3]
    turned = model.transformed(st.pose_matrix((0, 0, 0), angle))
    d = []
    for mesh, pts in ((model.mesh, samples @ R.T), (turned, samples)):
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
        d.append(scene.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy().mean())
    return float(np.mean(d))


def test_declared_symmetry_is_true_of_the_mesh():
    lib = st.structure_library()
    assert lib["manifold"].symmetry == 2
    assert _chamfer_turned(lib["manifold"], np.pi) < 0.01
    assert _chamfer_turned(lib["manifold"], np.pi / 2) > 0.1  # 2, not 4
    for name in ("plet", "wellhead"):
        assert lib[name].symmetry == 1
        assert _chamfer_turned(lib[name], np.pi) > 0.05
    assert st.symmetry_error(lib["manifold"].mesh, 2) < 0.01 and st.symmetry_error(lib["plet"].mesh, 2) > 0.05


def test_register_user_structure(tmp_path):
    box = o3d.geometry.TriangleMesh.create_box(4.0, 2.0, 1.0)
    box.translate((-2.0, -1.0, 0.0))  # z up from the base, as CAD files have it
    path = tmp_path / "skid.ply"
    o3d.io.write_triangle_mesh(str(path), box)
    try:
        m = st.register_structure(path, symmetry=2, z_up=True, hubs=[((2.0, 0.0, -0.11), (1.0, 0.0, 0.0), 0.1)])
        assert m.name == "skid" and st.structure_library()["skid"] is m and m.source == str(path)
        assert m.height == pytest.approx(1.0) and m.vertices[:, 2].max() == pytest.approx(0.0)
        assert m.footprint_radius == pytest.approx(np.hypot(2.0, 1.0)) and m.hubs[0].pipe_radius == 0.1
        with pytest.raises(st.StructureError, match="not symmetric of order 4"):
            st.register_structure(path, "skid4", symmetry=4, z_up=True)
        with pytest.raises(st.StructureError, match="not found"):
            st.register_structure(tmp_path / "none.stl")
        with pytest.raises(st.StructureError, match="built-in"):
            st.register_structure(path, "manifold")
    finally:
        st.unregister_structure("skid")
    assert "skid" not in st.structure_library()


# ----------------------------------------------------------------------------------------------
# the field: layout, seabed, pipelines


@pytest.mark.parametrize("seed", range(6))
def test_layout_structures_and_pipelines(seed):
    cfg = FieldSimConfig(seed=seed)
    field = make_field(cfg)
    gt = field.ground_truth()
    lib = st.structure_library()
    assert [s.model for s in gt.structures] == ["plet", "manifold", "wellhead"] and [s.id for s in gt.structures] == [
        0,
        1,
        2,
    ]
    assert [p.radius for p in gt.pipes] == [0.25, 0.10]
    assert gt.extras["pipeline_connections"] == {"0": [0, 1], "1": [1, 2]}
    half = np.array(cfg.seabed.area_m) / 2
    for s in gt.structures:
        m = lib[s.model]
        c = np.array(s.position)
        # inside the surveyed area with its whole footprint, upright, on the seabed (its pad)
        assert (np.abs(c[:2]) + m.footprint_radius <= half - cfg.layout.edge_margin_m + 1e-9).all()
        R = Rotation.from_quat(s.orientation).as_matrix()
        np.testing.assert_allclose(R[:, 2], [0, 0, 1], atol=1e-12)
        assert c[2] == pytest.approx(float(field.seabed.depth(c[0], c[1])), abs=1e-9)
        ring = c[:2] + m.footprint_radius * np.stack(
            [np.cos(np.arange(0, 6.3, 0.3)), np.sin(np.arange(0, 6.3, 0.3))], 1
        )
        np.testing.assert_allclose(field.seabed.depth(ring[:, 0], ring[:, 1]), c[2], atol=1e-9)  # level ground
    for i in range(3):
        for j in range(i + 1, 3):
            a, b = gt.structures[i], gt.structures[j]
            gap = np.linalg.norm(np.subtract(a.position, b.position)[:2])
            assert gap > lib[a.model].footprint_radius + lib[b.model].footprint_radius  # no overlap
    for p in gt.pipes:
        for end, sid in zip((p.p, p.q), gt.extras["pipeline_connections"][str(p.id)]):
            s = gt.structures[sid]
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = Rotation.from_quat(s.orientation).as_matrix(), s.position
            hubs = [
                (h, d)
                for (h, d), spec in zip(lib[s.model].hubs_in(T), lib[s.model].hubs)
                if spec.pipe_radius == p.radius
            ]
            dist = min(np.linalg.norm(np.asarray(end) - h) for h, _ in hubs)
            assert dist < 0.01
            # the pipeline leaves the hub roughly along the hub's direction
            h, d = min(hubs, key=lambda hd: np.linalg.norm(np.asarray(end) - hd[0]))
            other = np.asarray(p.q if end is p.p else p.p)
            away = (other - h)[:2] / np.linalg.norm((other - h)[:2])
            assert away @ d[:2] > np.cos(np.deg2rad(2 * cfg.layout.max_hub_angle_deg))
    for p in field.pipes:  # resting on the seabed: at most half buried, never spanning high
        assert p.max_burial_m <= p.radius + 1e-9 and p.max_span_gap_m <= cfg.layout.max_span_gap_m


def test_different_seeds_give_different_fields():
    a, b = make_field(FieldSimConfig(seed=0)), make_field(FieldSimConfig(seed=1))
    assert not np.allclose(a.structures[1].position, b.structures[1].position)
    assert not np.allclose(a.seabed.bumps, b.seabed.bumps)
    assert np.array_equal(make_field(FieldSimConfig(seed=0)).seabed.bumps, a.seabed.bumps)


def test_seabed_relief_and_description():
    cfg = FieldSimConfig(seed=2)
    field = make_field(cfg)
    sb = field.seabed
    n = np.linspace(-17, 17, 69)
    e = np.linspace(-25, 25, 101)
    base = sb.base_depth(*np.meshgrid(n, e, indexing="ij"))
    assert base.mean() == pytest.approx(20.0, abs=1e-6)
    assert np.abs(base - 20.0).max() == pytest.approx(0.8, abs=1e-6)
    # the description in the metadata evaluates to the same seabed, and the mesh follows it
    from semslam.sim.seabed import seabed_depth

    d = json.loads(json.dumps(sb.to_dict()))
    P = np.random.default_rng(0).uniform([-20, -30], [20, 30], (500, 2))
    np.testing.assert_allclose(seabed_depth(d, P[:, 0], P[:, 1]), sb.depth(P[:, 0], P[:, 1]), atol=1e-12)
    mesh = sb.mesh()
    V = np.asarray(mesh.vertices)
    np.testing.assert_allclose(V[:, 2], sb.depth(V[:, 0], V[:, 1]))
    assert (np.asarray(mesh.triangle_normals)[:, 2] < 0).all()  # facing up (−z in NED)


# ----------------------------------------------------------------------------------------------
# the mission


def test_same_seed_same_bytes(short_mission):
    assert _digest(simulate_field(short_config())) == _digest(short_mission)
    other = simulate_field(short_config(seed=1))
    assert _digest(other) != _digest(short_mission)
    assert other.metadata.ground_truth.structures != short_mission.metadata.ground_truth.structures


def test_streams_rates_and_metadata(short_mission):
    ms = list(short_mission)
    assert [m.stamp for m in ms] == sorted(m.stamp for m in ms)
    T = short_mission.metadata.extras["trajectory"]["duration_s"]
    count = {c: sum(isinstance(m, c) for m in ms) for c in (DvlVelocity, Attitude, Depth, SonarSwath, GroundTruthPose)}
    assert count[SonarSwath] == int(T * 12.5) and count[GroundTruthPose] == int(T * 25) + 1
    assert count[DvlVelocity] == pytest.approx(T * 5, abs=1) and count[Attitude] == pytest.approx(T * 20, abs=1)
    meta = short_mission.metadata
    assert {n: (s.kind, s.topic, s.msgtype) for n, s in meta.sensors.items()} == {
        "dvl": ("dvl", "/sim/dvl", "cola2_msgs/msg/DVL"),
        "ahrs": ("ahrs", "/sim/imu", "sensor_msgs/msg/Imu"),
        "depth": ("depth", "/sim/pressure", "sensor_msgs/msg/FluidPressure"),
        "sonar": ("sonar", "/sim/sonar/scan", "sensor_msgs/msg/LaserScan"),
        "ground_truth": ("ground_truth", "/sim/ground_truth/odom", "nav_msgs/msg/Odometry"),
    }
    np.testing.assert_allclose(meta.sensors["sonar"].T_BS, short_config().sonar.mount.matrix())
    extras = json.loads(json.dumps(meta.extras))  # the sidecar must be plain JSON
    noise = extras["noise"]
    assert noise["sonar"]["range_sigma_m"] == 0.015 and noise["sonar"]["rate_hz"] == 12.5
    assert noise["dvl"]["velocity_sigma_m_s"] == 0.01 and noise["depth"]["sigma_m"] == 0.02
    assert noise["ahrs"]["heading_bias_drift_rad"] == pytest.approx(np.deg2rad(1.5))
    assert extras["scene"]["kind"] == "field" and len(extras["scene"]["layout"]["structures"]) == 3
    gt = meta.ground_truth
    assert gt.seen_structures == (1,)  # B under the first line; A and C out of reach of these short lines
    assert set(gt.seen_pipes) <= {0, 1} and gt.seen_pipes
    sw = next(short_mission.of_type(SonarSwath))
    assert len(sw.ranges) == 64 and sw.angles[0] == pytest.approx(-np.deg2rad(40), abs=1e-6)
    assert np.diff(sw.angles) == pytest.approx(np.deg2rad(80) / 63, abs=1e-7)


def test_sonar_points_lie_on_the_scene(short_mission):
    """Moved to {W} with the true pose, every return lies on the seabed, a structure or a pipe within
    the configured range noise; without noise, within float32 precision."""
    cfg = short_config()
    scene = FieldScene(make_field(cfg))
    pts, _ = _world_points(short_mission)
    d = scene.distance(pts)
    sigma = cfg.sonar.range_sigma_m
    assert np.sqrt(np.mean(d**2)) < 1.05 * sigma and np.sqrt(np.mean(d**2)) > 0.5 * sigma
    assert np.quantile(d, 0.999) < 4 * sigma
    # returns on each kind of surface, at full resolution over the structure
    traj = Lawnmower(cfg.trajectory, cfg.seabed)
    full = short_config(sonar={"n_beams": 512, "range_sigma_m": 1e-9})
    t = np.arange(0.5, traj.duration, 1.0)
    res = simulate_sonar(full.sonar, traj, scene, np.arange(len(t)), t, np.random.default_rng(0), REFLECTIVITY)
    assert res.seen[STRUCTURE] == {1} and res.seen[PIPE]
    T_BS = full.sonar.mount.matrix()
    for m, T_WB in zip(res.measurements, traj.poses(t)):
        T_WS = T_WB @ T_BS
        assert len(m.ranges) == 512
        assert scene.distance(m.points() @ T_WS[:3, :3].T + T_WS[:3, 3]).max() < 2e-3  # float32 at 20 m depth


def test_swaths_of_neighbouring_lines_overlap():
    """On a flat seabed at 5 m altitude the 80° fans of lines 5.5 m apart overlap by ≥ 20 %."""
    cfg = short_config(seabed={"relief_m": 0.0})
    m = simulate_field(cfg)
    pts, idx = _world_points(m)
    lines = m.metadata.extras["trajectory"]["lines"]
    t0 = cfg.start_time_s
    t_sw = np.array([(s.stamp * 1e-9 - t0) for s in m.of_type(SonarSwath)])[idx]
    on_seabed = np.abs(pts[:, 2] - 20.0) < 0.05
    spans = []
    for ln in lines:
        sel = on_seabed & (t_sw >= ln["t_start_s"]) & (t_sw <= ln["t_end_s"])
        spans.append((np.quantile(pts[sel, 0], 0.001), np.quantile(pts[sel, 0], 0.999)))
    (a0, a1), (b0, b1) = spans
    width = ((a1 - a0) + (b1 - b0)) / 2
    assert width == pytest.approx(2 * 4.7 * np.tan(np.deg2rad(40)), rel=0.03)  # the sonar head is 4.7 m up
    assert (min(a1, b1) - max(a0, b0)) / width >= 0.2


def test_noise_free_dvl_integrates_to_the_true_trajectory():
    """Dead reckoning with noise-free DVL and the true attitude reproduces the lawnmower, turns and
    all (mm over a line, a turn and a line), and only with the lever-arm term ω × t_BS."""
    cfg = short_config(dvl={"sigma_m_s": 1e-12, "random_dropout_rate": 0.0})
    scene = FieldScene(make_field(cfg))
    traj = Lawnmower(cfg.trajectory, cfg.seabed)
    st_, t = S.sample_times(0, cfg.dvl.rate_hz, traj.duration)
    res = S.simulate_dvl(
        cfg.dvl, traj, scene, st_, t, np.random.default_rng(0), np.random.default_rng(1), lost_kinds=()
    )
    assert res.valid.all()
    v_S = np.array([m.velocity for m in res.measurements])
    T_BS = cfg.dvl.mount.matrix()
    R_WB = traj.rotation(t).as_matrix()
    w_B = traj.angular_rate(t)

    def integrate(lever: bool):
        v_B = v_S @ T_BS[:3, :3].T - (np.cross(w_B, T_BS[:3, 3]) if lever else 0.0)
        v_W = np.einsum("nij,nj->ni", R_WB, v_B)
        steps = 0.5 * (v_W[1:] + v_W[:-1]) * np.diff(t)[:, None]
        return traj.position_velocity(t[:1])[0][0] + np.vstack([np.zeros(3), np.cumsum(steps, 0)])

    truth = traj.position_velocity(t)[0]
    assert np.abs(integrate(True) - truth).max() < 3e-3
    assert np.abs(integrate(False) - truth).max() > 0.01


def test_lawnmower_geometry():
    cfg = FieldSimConfig()
    traj = Lawnmower(cfg.trajectory, cfg.seabed)
    assert 10 * 60 <= traj.duration <= 12 * 60
    t = np.arange(0.0, traj.duration, 0.05)
    p, v = traj.position_velocity(t)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 0.5)
    assert np.abs(np.diff(p, axis=0)).max() < 0.5 * 0.05 + 1e-9  # continuous
    lines = traj.lines()
    assert [ln["north_m"] for ln in lines] == [-13.75, -8.25, -2.75, 2.75, 8.25, 13.75]
    assert lines[0]["east_from_m"] == -25.0 and lines[0]["heading_deg"] == 90.0 and lines[1]["heading_deg"] == -90.0
    np.testing.assert_allclose(p[0], [-13.75, -25.0, 15.0])  # starts on the first line, at working depth
    # smooth turns: the yaw rate stays small and continuous
    w = traj.angular_rate(t)
    assert np.abs(w[:, 2]).max() < np.deg2rad(12) and np.abs(np.diff(w[:, 2])).max() < 0.01  # ≤ 0.2 rad/s²
    # 4–6 m over the seabed away from the structures
    field = make_field(cfg)
    alt = field.seabed.base_depth(p[:, 0], p[:, 1]) - p[:, 2]
    assert alt.min() >= 4.0 and alt.max() <= 6.0


def test_dead_reckoning_drifts_between_lines():
    """Three 50 m lines: the navigation noise misplaces neighbouring lines by centimetres to decimetres."""
    cfg = FieldSimConfig.model_validate({"trajectory": {"lines": 3}, "sonar": {"n_beams": 16}})
    drift = simulate_field(cfg).metadata.extras["navigation_drift"]
    assert 0.02 < drift["between_lines_median_m"] < 0.5
    assert drift["between_lines_max_m"] < 1.5 and len(drift["between_lines_max_per_pair_m"]) == 2


def test_world_model_budget():
    """The three meshes (float32 vertices, int32 triangles) are < 1 % of the default raw sonar cloud."""
    cfg = FieldSimConfig()
    traj = Lawnmower(cfg.trajectory, cfg.seabed)
    n_swaths = len(S.sample_times(0, cfg.sonar.rate_hz, traj.duration, first=1)[0])
    raw_bytes = 0.95 * n_swaths * cfg.sonar.n_beams * 12
    lib = st.structure_library()
    mesh_bytes = sum(12 * (len(lib[n].vertices) + len(lib[n].triangles)) for n in st.STRUCTURES)
    assert mesh_bytes < 0.01 * raw_bytes
    assert 8000 < n_swaths < 10000


def test_config_errors(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("sonar: {n_beams: 1}\n")
    with pytest.raises(ConfigError, match="sonar.n_beams"):
        load_field_config(bad)
    bad.write_text("layout: {chain: [plet, pond, wellhead]}\n")
    with pytest.raises(ConfigError, match="unknown structure model 'pond'"):
        simulate_field(load_field_config(bad))
    bad.write_text("trajectory: [1, 2\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_field_config(bad)


# ----------------------------------------------------------------------------------------------
# bag, preview, command line


def test_written_bag_reads_back(tmp_path, short_mission):
    from semslam.mission.bag import read_mission, write_mission

    back = read_mission(write_mission(short_mission, tmp_path / "field.bag"))
    a, b = list(short_mission), list(back)
    assert [(type(m), m.sensor, m.stamp) for m in a] == [(type(m), m.sensor, m.stamp) for m in b]
    for x, y in zip((m for m in a if isinstance(m, SonarSwath)), (m for m in b if isinstance(m, SonarSwath))):
        assert np.array_equal(x.ranges, y.ranges) and np.array_equal(x.intensities, y.intensities)
        np.testing.assert_allclose(x.angles, y.angles, atol=1e-6)
    assert back.metadata.ground_truth == short_mission.metadata.ground_truth
    assert back.metadata.extras["noise"] == short_mission.metadata.extras["noise"]
    assert back.metadata.extras["scene"] == json.loads(json.dumps(short_mission.metadata.extras["scene"]))


def test_preview_png(tmp_path, short_mission):
    import matplotlib.image as mpimg

    from semslam.sim.field_preview import render_field_preview

    out = tmp_path / "field.png"
    render_field_preview(short_mission, out)
    img = mpimg.imread(out)
    assert img.shape[0] > 1000 and img.shape[1] > 1000 and img[..., :3].std() > 0.05


def test_cli_simulate_field_and_info(tmp_path):
    from semslam.cli import app

    runner = CliRunner()
    sim = tmp_path / "sim.yaml"
    sim.write_text("trajectory: {lines: 2, line_length_m: 8.0}\nsonar: {n_beams: 32}\n")
    out, png = tmp_path / "f.bag", tmp_path / "f.png"
    res = runner.invoke(
        app, ["simulate", "field", "--seed", "3", "--out", str(out), "--sim-config", str(sim), "--preview", str(png)]
    )
    assert res.exit_code == 0, res.output
    assert "3 structures, 2 pipelines" in res.output and png.stat().st_size > 50_000
    info = runner.invoke(app, ["info", str(out)])
    assert info.exit_code == 0, info.output
    rows = {line.split()[0]: line.split() for line in info.output.splitlines() if line.split()}
    assert rows["sonar"][1:4] == ["sonar", "/sim/sonar/scan", "sensor_msgs/LaserScan"]
    assert float(rows["sonar"][5]) == pytest.approx(12.5) and float(rows["ground_truth"][5]) == pytest.approx(25.0)
    assert int(rows["sonar"][4]) == int(
        json.loads((tmp_path / "f.bag.semslam.json").read_text())["extras"]["sonar"]["swaths"]
    )
    again = runner.invoke(app, ["simulate", "field", "--out", str(out)])
    assert again.exit_code == 1 and "already exists" in again.output
    assert len([line for line in again.output.splitlines() if line.strip()]) == 1
    tank_only = runner.invoke(app, ["simulate", "field", "--out", str(tmp_path / "g.bag"), "--loops", "2"])
    assert tank_only.exit_code == 1 and "tank" in tank_only.output and not (tmp_path / "g.bag").exists()
