"""The simulated tank mission: determinism, physical sanity of every sensor, declared noise, metadata."""

import hashlib
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.mission import Attitude, Depth, DvlVelocity, GroundTruthPose, PointCloud
from semslam.models import cad
from semslam.sim import sensors as S
from semslam.sim.config import TankSimConfig
from semslam.sim.simulate import simulate_tank
from semslam.sim.tank import TankScene, make_layout
from semslam.sim.trajectory import Trajectory


def short_config(**kw) -> TankSimConfig:
    base = {
        "trajectory": {"duration_s": 60.0, "rest_s": 2.0, "ramp_s": 15.0, "loops": 0.4},
        "laser": {"resolution": [90, 70]},
    }
    for k, v in kw.items():
        base.setdefault(k, {}).update(v) if isinstance(v, dict) else base.__setitem__(k, v)
    return TankSimConfig.model_validate(base)


@pytest.fixture(scope="module")
def short_mission():
    return simulate_tank(short_config())


def _world(cfg: TankSimConfig):
    layout = make_layout(cfg.structure, cfg.tank, cfg.seed)
    scene = TankScene(cfg.tank, layout)
    lo, hi = layout.bounds()
    traj = Trajectory(cfg.trajectory, np.array([*cfg.structure.center_xy_m, (lo[2] + hi[2]) / 2]))
    return layout, scene, traj


def _digest(mission) -> str:
    h = hashlib.sha256()
    for m in mission:
        h.update(f"{type(m).__name__}|{m.stamp}|{m.sensor}|".encode())
        for v in vars(m).values():
            h.update(v.tobytes() if isinstance(v, np.ndarray) else repr(v).encode())
    return h.hexdigest()


def test_same_seed_same_bytes(short_mission):
    assert _digest(simulate_tank(short_config())) == _digest(short_mission)
    assert _digest(simulate_tank(short_config(seed=1))) != _digest(short_mission)


def test_streams_rates_and_metadata(short_mission):
    ms = list(short_mission)
    assert all(type(m.stamp) is int for m in ms)
    assert [m.stamp for m in ms] == sorted(m.stamp for m in ms)
    count = {c: sum(isinstance(m, c) for m in ms) for c in (DvlVelocity, Attitude, Depth, PointCloud, GroundTruthPose)}
    assert count == {DvlVelocity: 300, Attitude: 1200, Depth: 480, PointCloud: 30, GroundTruthPose: 3001}
    # the sensors are not synchronised: no two streams share a stamp, except laser scans and ground truth
    by_sensor = {s: {m.stamp for m in ms if m.sensor == s} for s in ("dvl", "ahrs", "depth", "laser")}
    assert not (by_sensor["dvl"] & by_sensor["ahrs"]) and not (by_sensor["dvl"] & by_sensor["depth"])
    assert not (by_sensor["ahrs"] & by_sensor["depth"])
    assert by_sensor["laser"] <= {m.stamp for m in ms if m.sensor == "ground_truth"}
    t0 = int(round(short_config().start_time_s * 1e9))
    assert min(by_sensor["dvl"]) - t0 == 11_000_000 and max(by_sensor["dvl"]) - t0 <= 60 * 10**9
    meta = short_mission.metadata
    expected = {
        "dvl": ("dvl", "cola2_msgs/msg/DVL"),
        "ahrs": ("ahrs", "sensor_msgs/msg/Imu"),
        "depth": ("depth", "sensor_msgs/msg/FluidPressure"),
        "laser": ("laser", "sensor_msgs/msg/PointCloud2"),
        "ground_truth": ("ground_truth", "nav_msgs/msg/Odometry"),
    }
    assert {n: (s.kind, s.msgtype) for n, s in meta.sensors.items()} == expected
    assert len({s.topic for s in meta.sensors.values()}) == 5
    cfg = short_config()
    np.testing.assert_allclose(meta.sensors["laser"].T_BS, cfg.laser.mount.matrix())
    np.testing.assert_allclose(meta.sensors["dvl"].T_BS[:3, 3], cfg.dvl.mount.xyz)
    extras = json.loads(json.dumps(meta.extras))  # the sidecar must be plain JSON
    assert extras["noise"]["dvl"]["velocity_sigma_m_s"] == 0.01
    assert extras["noise"]["ahrs"]["heading_sigma_rad"] == pytest.approx(np.deg2rad(0.5))
    assert extras["noise"]["depth"]["sigma_m"] == 0.02
    assert extras["noise"]["laser"]["range_sigma_m"] == 0.005
    assert len(extras["scene"]["layout"]["objects"]) == len(meta.ground_truth.objects)


def test_ground_truth_covers_all_classes_and_sees_the_structure(short_mission):
    gt = short_mission.metadata.ground_truth
    assert {o.cls for o in gt.objects} == set(cad.CLASSES)
    assert len(gt.objects) >= 20 and len(gt.pipes) >= 12
    assert set(gt.seen_objects) <= {o.id for o in gt.objects} and len(gt.seen_objects) >= 10
    assert set(gt.seen_pipes) <= {p.id for p in gt.pipes} and len(gt.seen_pipes) >= 8


def test_declared_noise_is_the_noise(short_mission):
    """Measurement − truth has the standard deviation written in the message covariances."""
    cfg = short_config()
    _, _, traj = _world(cfg)
    t0 = int(round(cfg.start_time_s * 1e9))
    sec = lambda ms: np.array([(m.stamp - t0) * 1e-9 for m in ms])  # noqa: E731

    att = list(short_mission.of_type(Attitude))
    t = sec(att)
    R_WS = traj.rotation(t) * Rotation.from_matrix(cfg.ahrs.mount.matrix()[:3, :3])
    err = (R_WS.inv() * Rotation.from_quat([a.orientation for a in att])).as_euler("ZYX")  # small: ≈ (yaw, pitch, roll)
    bias = np.deg2rad(2.0) * t / cfg.trajectory.duration_s
    yaw_err = err[:, 0] - np.sign(err[:, 0].mean()) * bias
    cov = att[0].covariance
    assert np.std(yaw_err) == pytest.approx(np.sqrt(cov[2, 2]), rel=0.1)
    assert np.std(err[:, 2]) == pytest.approx(np.sqrt(cov[0, 0]), rel=0.1)
    assert np.std(err[:, 1]) == pytest.approx(np.sqrt(cov[1, 1]), rel=0.1)
    assert np.sqrt(cov[0, 0]) == pytest.approx(np.deg2rad(0.1)) and np.sqrt(cov[2, 2]) == pytest.approx(np.deg2rad(0.5))
    w_err = np.array([a.angular_rate for a in att]) - traj.angular_rate(t) @ cfg.ahrs.mount.matrix()[:3, :3]
    assert np.std(w_err, axis=0) == pytest.approx([cfg.ahrs.angular_rate_sigma_rad_s] * 3, rel=0.1)
    assert np.abs(w_err.mean(0)).max() < 4 * cfg.ahrs.angular_rate_sigma_rad_s / np.sqrt(len(att))
    # the heading bias drifts by 2° per mission: here, over 60 s, the mean yaw error grows by 2° · 60/60
    late = t > 50
    assert abs(err[late, 0].mean()) == pytest.approx(np.deg2rad(2.0) * t[late].mean() / 60, abs=np.deg2rad(0.1))

    dep = list(short_mission.of_type(Depth))
    t = sec(dep)
    p, _ = traj.position_velocity(t)
    z = (p + traj.rotation(t).as_matrix() @ np.array(cfg.depth.mount.xyz))[:, 2]
    assert np.std([d.depth for d in dep] - z) == pytest.approx(np.sqrt(dep[0].variance), rel=0.12)
    assert dep[0].variance == pytest.approx(0.02**2)

    dvl = [d for d in short_mission.of_type(DvlVelocity) if d.valid]
    assert len(dvl) > 100
    t = sec(dvl)
    p, v = traj.position_velocity(t)
    R = traj.rotation(t).as_matrix()
    T_BS = cfg.dvl.mount.matrix()
    v_S = (np.einsum("nji,nj->ni", R, v) + np.cross(traj.angular_rate(t), T_BS[:3, 3])) @ T_BS[:3, :3]
    e = np.array([d.velocity for d in dvl]) - v_S
    assert np.std(e, axis=0) == pytest.approx([0.01] * 3, rel=0.15)
    np.testing.assert_allclose(dvl[0].covariance, np.eye(3) * 1e-4)


def test_noise_free_dvl_integrates_to_the_true_trajectory():
    """Dead reckoning with noise-free DVL and the true attitude reproduces the true path (mm over
    two minutes), and only if the lever-arm term ω × t_BS is accounted for."""
    cfg = short_config(
        tank={"floor_half_x_m": 30.0, "floor_half_y_m": 30.0},
        dvl={"sigma_m_s": 1e-12, "random_dropout_rate": 0.0},
        trajectory={"duration_s": 120.0},
    )
    _, scene, traj = _world(cfg)
    st, t = S.sample_times(0, cfg.dvl.rate_hz, 120.0)
    res = S.simulate_dvl(cfg.dvl, traj, scene, st, t, np.random.default_rng(0), np.random.default_rng(1))
    assert res.valid.all()
    v_S = np.array([m.velocity for m in res.measurements])
    T_BS = cfg.dvl.mount.matrix()
    R_WB = traj.rotation(t).as_matrix()
    w_B = traj.angular_rate(t)

    def integrate(lever: bool):
        v_B = v_S @ T_BS[:3, :3].T - (np.cross(w_B, T_BS[:3, 3]) if lever else 0.0)  # body-origin velocity
        v_W = np.einsum("nij,nj->ni", R_WB, v_B)
        steps = 0.5 * (v_W[1:] + v_W[:-1]) * np.diff(t)[:, None]
        return traj.position_velocity(t[:1])[0][0] + np.vstack([np.zeros(3), np.cumsum(steps, 0)])

    truth = traj.position_velocity(t)[0]
    assert np.abs(integrate(True) - truth).max() < 2e-3
    assert np.abs(integrate(False) - truth).max() > 0.1


def test_dvl_dropouts_where_configured():
    cfg = TankSimConfig(dvl={"random_dropout_rate": 0.0})
    _, scene, traj = _world(cfg)
    st, t = S.sample_times(0, cfg.dvl.rate_hz, cfg.trajectory.duration_s)
    res = S.simulate_dvl(cfg.dvl, traj, scene, st, t, np.random.default_rng(0), np.random.default_rng(1))
    lost = res.beam_valid.sum(1) < cfg.dvl.min_valid_beams
    assert lost.any() and not res.valid[lost].any()  # wall hits always drop the reading
    assert {c for _, _, c in res.intervals} == {"walls"}
    # each burst lasts 2–10 s; outside bursts every reading is valid and finite
    for s, e, _ in res.intervals:
        assert 2.0 - 1e-9 <= e - s <= 10.0
    ms = res.measurements
    assert all(np.isnan(m.velocity).all() and not m.valid for m, ok in zip(ms, res.valid) if not ok)
    assert all(np.isfinite(m.velocity).all() for m, ok in zip(ms, res.valid) if ok)
    # wall dropouts happen at the ends of the long axis, where the rear beams reach past the floor
    x = traj.position_velocity(t)[0][:, 0]
    assert np.abs(x[lost]).min() > 3.0
    # the default adds random bursts; together they cover 10–20 % of the mission
    default = TankSimConfig()
    res_d = S.simulate_dvl(default.dvl, traj, scene, st, t, np.random.default_rng(0), np.random.default_rng(1))
    assert 0.10 <= res_d.invalid_fraction <= 0.20
    assert {c for _, _, c in res_d.intervals} == {"walls", "random"}  # never merged into longer bursts
    assert all(2.0 - 1e-9 <= e - s <= 10.0 for s, e, _ in res_d.intervals)
    random_time = sum(e - s for s, e, c in res_d.intervals if c == "random")
    assert random_time == pytest.approx(default.dvl.random_dropout_rate * t[-1], abs=1e-6)
    clean = TankSimConfig(dvl={"random_dropout_rate": 0.0, "wall_beams_lost": False})
    res_c = S.simulate_dvl(clean.dvl, traj, scene, st, t, np.random.default_rng(0), np.random.default_rng(1))
    assert res_c.valid.all() and res_c.intervals == []
    heavy = TankSimConfig(dvl={"random_dropout_rate": 0.4})
    res_h = S.simulate_dvl(heavy.dvl, traj, scene, st, t, np.random.default_rng(0), np.random.default_rng(1))
    assert res_h.invalid_fraction > 0.35


def test_laser_points_lie_on_the_scene_surfaces():
    """Full-resolution scans at working depth: ~100k points in the sensor frame; moved to {W} with
    the true pose they lie on the tank/structure surfaces within the 5 mm range noise."""
    cfg = TankSimConfig()
    _, scene, traj = _world(cfg)
    t = np.array([100.0, 230.0])
    res = S.simulate_laser(cfg.laser, traj, scene, np.array([1, 2]), t, np.random.default_rng(3))
    T_BS = cfg.laser.mount.matrix()
    for pc, T_WB in zip(res.measurements, traj.poses(t)):
        assert pc.points.dtype == np.float32 and 85_000 <= len(pc.points) <= 101_000
        T_WS = T_WB @ T_BS
        pw = pc.points.astype(float) @ T_WS[:3, :3].T + T_WS[:3, 3]
        d = scene.distance(pw)
        assert np.quantile(d, 0.999) < 4 * cfg.laser.range_sigma_m
        assert np.sqrt(np.mean(d**2)) < cfg.laser.range_sigma_m
        assert np.sqrt(np.mean(d**2)) > 0.3 * cfg.laser.range_sigma_m  # the noise is really there
        r = np.linalg.norm(pc.points, axis=1)
        assert r.min() >= cfg.laser.min_range_m and r.max() <= cfg.laser.max_range_m
        assert (pc.points[:, 2] > 0).all()  # in front of the sensor: {S} z is the view axis
    assert len(res.seen_objects) >= 5 and len(res.seen_pipes) >= 5
    exact = TankSimConfig(laser={"range_sigma_m": 1e-9})
    res0 = S.simulate_laser(exact.laser, traj, scene, np.array([1]), t[:1], np.random.default_rng(3))
    pc = res0.measurements[0]
    T_WS = traj.poses(t[:1])[0] @ T_BS
    assert scene.distance(pc.points.astype(float) @ T_WS[:3, :3].T + T_WS[:3, 3]).max() < 1e-3


def test_default_mission_dimensions():
    """Without running it: the default mission has ~245 scans of ~100k rays over ~8 minutes,
    3 loops at 2–3.5 m from the structure, starting at rest on the surface."""
    cfg = TankSimConfig()
    n_scans = len(S.sample_times(0, cfg.laser.rate_hz, cfg.trajectory.duration_s, first=1)[0])
    assert n_scans == 245
    assert 95_000 <= np.prod(cfg.laser.resolution) <= 105_000
    assert 7.5 * 60 <= cfg.trajectory.duration_s <= 8.5 * 60 and cfg.trajectory.loops == 3
    _, _, traj = _world(cfg)
    t = np.linspace(0, cfg.trajectory.duration_s, 5000)
    p, v = traj.position_velocity(t)
    assert p[0, 2] == pytest.approx(0.0) and np.linalg.norm(v[0]) == pytest.approx(0.0)
    r = np.linalg.norm(p[:, :2] - traj.center[:2], axis=1)
    assert r.min() >= 2.0 and r.max() <= 3.5
    # always facing the structure centre
    fwd = traj.rotation(t).as_matrix()[:, :2, 0]
    to_c = (traj.center[:2] - p[:, :2]) / r[:, None]
    assert np.degrees(np.arccos(np.clip((fwd * to_c).sum(1) / np.linalg.norm(fwd, axis=1), -1, 1))).max() < 0.5
    # the last pose has gone round `loops` times
    ang = np.unwrap(np.arctan2(p[:, 1] - traj.center[1], p[:, 0] - traj.center[0]))
    assert abs(ang[-1] - ang[0]) == pytest.approx(2 * np.pi * 3, rel=1e-6)


def test_preview_png(tmp_path, short_mission):
    from semslam.sim.preview import render_preview

    out = tmp_path / "preview.png"
    render_preview(short_mission, out)
    import matplotlib.image as mpimg

    img = mpimg.imread(out)
    assert img.shape[0] > 800 and img.shape[1] > 1200
    assert img[..., :3].std() > 0.05  # something was drawn


def test_written_bag_reads_back_identically(tmp_path, short_mission):
    """Through the ordinary bag writer and reader (ROS 1), the mission comes back with the same
    streams, stamps, DVL validity and ground truth, and the preview can be drawn from the bag."""
    from semslam.mission.bag import read_mission, write_mission
    from semslam.sim import render_preview

    path = write_mission(short_mission, tmp_path / "tank.bag")
    back = read_mission(path)
    a, b = list(short_mission), list(back)
    assert [(type(m), m.sensor, m.stamp) for m in a] == [(type(m), m.sensor, m.stamp) for m in b]
    va = [m.valid for m in a if isinstance(m, DvlVelocity)]
    assert va == [m.valid for m in b if isinstance(m, DvlVelocity)] and not all(va)
    pa = [m for m in a if isinstance(m, PointCloud)]
    pb = [m for m in b if isinstance(m, PointCloud)]
    assert all(np.array_equal(x.points, y.points) for x, y in zip(pa, pb))
    assert back.metadata.ground_truth == short_mission.metadata.ground_truth
    assert back.metadata.extras["noise"] == short_mission.metadata.extras["noise"]
    for name, s in short_mission.metadata.sensors.items():
        np.testing.assert_allclose(back.metadata.sensors[name].T_BS, s.T_BS)
    render_preview(back, tmp_path / "p.png")


def test_simulate_to_bag_with_options(tmp_path):
    """The CLI's path: YAML config ← options; the options land in the resolved config of the bag."""
    from semslam.errors import ConfigError
    from semslam.mission.bag import read_mission
    from semslam.sim.simulate import simulate_tank_to_bag

    cfg = tmp_path / "sim.yaml"
    cfg.write_text("trajectory: {rest_s: 1.0, ramp_s: 5.0, loop_period_s: 20.0}\nlaser: {resolution: [40, 30]}\n")
    simulate_tank_to_bag(
        tmp_path / "m.bag", seed=4, dvl_dropout_rate=0.3, loops=0.5, config=cfg, preview=tmp_path / "m.png"
    )
    back = read_mission(tmp_path / "m.bag")
    resolved = back.metadata.extras["simulator"]["config"]
    assert resolved["seed"] == 4 and resolved["dvl"]["random_dropout_rate"] == 0.3
    assert resolved["trajectory"]["loops"] == 0.5 and resolved["trajectory"]["duration_s"] == pytest.approx(13.5)
    assert (tmp_path / "m.png").stat().st_size > 10_000
    cfg.write_text("dvl: {random_dropout_rate: 2}\n")
    with pytest.raises(ConfigError, match="dvl.random_dropout_rate"):
        simulate_tank_to_bag(tmp_path / "n.bag", config=cfg)


def test_preview_without_ground_truth(tmp_path, short_mission):
    """A real mission has no ground truth and no scene: the preview still draws the trajectory."""
    from semslam.mission import Mission, MissionMetadata
    from semslam.sim.preview import render_preview

    bare = Mission.from_measurements(MissionMetadata(name="real"), list(short_mission))
    render_preview(bare, tmp_path / "bare.png")
    assert (tmp_path / "bare.png").stat().st_size > 10_000


def test_a_long_dvl_outage_where_configured():
    """``dvl.outage_s``: every reading in [start, start + length) is invalid, the interval is
    labelled, and the random bursts are the same as without it (same seed)."""
    base = TankSimConfig()
    _, scene, traj = _world(base)
    st, t = S.sample_times(0, base.dvl.rate_hz, base.trajectory.duration_s)
    with_outage = TankSimConfig(dvl={"outage_s": (100.0, 90.0)})

    def dvl(cfg):
        return S.simulate_dvl(cfg.dvl, traj, scene, st, t, np.random.default_rng(0), np.random.default_rng(1))

    plain, out = dvl(base), dvl(with_outage)
    inside = (t >= 100.0) & (t < 190.0 - 1e-9)
    assert inside.sum() > 400 and not out.valid[inside].any()
    assert (out.valid[~inside] == plain.valid[~inside]).all()
    assert any("outage" in c and s <= 100.0 and e >= 190.0 - 1e-9 for s, e, c in out.intervals)
    assert out.invalid_fraction > plain.invalid_fraction + 90.0 / t[-1] * 0.5
