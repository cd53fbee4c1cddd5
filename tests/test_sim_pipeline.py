"""The simulated pipeline on a natural seabed: scene, stereo camera, mission, ground truth."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from semslam.cli import app
from semslam.errors import ConfigError
from semslam.mission import Attitude, Depth, DvlVelocity, GroundTruthPose, PointCloud
from semslam.mission.bag import read_mission
from semslam.models import cad
from semslam.sim.pipeline_config import PipelineSimConfig, StereoConfig, load_pipeline_config
from semslam.sim.pipeline_mission import simulate_pipeline
from semslam.sim.stereo import depth_sigma, focal_px, pixel_rays

SECONDS = 15.0


def short_config(seed: int = 0, seconds: float = SECONDS) -> PipelineSimConfig:
    """The first ``seconds`` of the default mission (two clouds a second)."""
    return PipelineSimConfig.model_validate({"seed": seed, "trajectory": {"duration_s": seconds}})


@pytest.fixture(scope="module")
def mission():
    return simulate_pipeline(short_config())


@pytest.mark.slow
def test_simulate_pipeline_from_the_cli_same_seed_same_clouds_other_seed_other_world(tmp_path):
    """`semslam simulate pipeline` writes the bag the in-memory simulation gives (read back: the same
    valid points, the reader dropping the NaN pixels, colours and ground truth), with its preview;
    another seed is another world."""
    (tmp_path / "short.yaml").write_text("trajectory: {duration_s: 3.0}\n")
    bag, png = tmp_path / "p.mcap", tmp_path / "p.png"
    args = ["simulate", "pipeline", "--seed", "3", "--out", str(bag), "--sim-config", str(tmp_path / "short.yaml")]
    res = CliRunner().invoke(app, [*args, "--preview", str(png)])
    assert res.exit_code == 0, res.output
    assert "fittings" in res.output and png.stat().st_size > 10_000
    a = read_mission(bag)
    b = simulate_pipeline(short_config(seed=3, seconds=3.0))
    c = simulate_pipeline(short_config(seed=4, seconds=3.0))
    ca, cb = list(a.of_type(PointCloud)), list(b.of_type(PointCloud))
    assert len(ca) == len(cb) == 6
    for x, y in zip(ca, cb, strict=True):
        valid = np.isfinite(y.points).all(axis=1)
        assert np.array_equal(x.points, y.points[valid]) and np.array_equal(x.rgb, y.rgb[valid])
    assert a.metadata.ground_truth == b.metadata.ground_truth
    assert b.metadata.ground_truth.pipes != c.metadata.ground_truth.pipes


def test_clouds_are_organised_stereo_with_nans_and_colour(mission):
    w, h = StereoConfig().resolution
    clouds = list(mission.of_type(PointCloud))
    assert len(clouds) == int(SECONDS * StereoConfig().rate_hz)
    for c in clouds:
        assert c.sensor == "stereo" and c.points.shape == (w * h, 3) and c.rgb.shape == (w * h, 3)
        valid = np.isfinite(c.points).all(axis=1)
        assert 0.6 < valid.mean() < 0.98  # holes, occlusions and dropouts, but most pixels valid
        assert np.isnan(c.points[~valid]).all()  # a failed pixel is NaN in all three coordinates
        # each valid point lies on its pixel's ray (depth noise moves it along the ray only)
        d = pixel_rays(StereoConfig())[valid]
        p = c.points[valid].astype(float)
        assert np.allclose(np.cross(p / np.linalg.norm(p, axis=1)[:, None], d), 0.0, atol=1e-5)
    sensor = mission.metadata.sensors["stereo"]
    assert sensor.kind == "laser" and sensor.msgtype == "sensor_msgs/msg/PointCloud2"


def test_depth_noise_grows_with_the_square_of_depth():
    cfg = StereoConfig()
    assert focal_px(cfg) == pytest.approx(120 / np.tan(np.radians(10)))
    s1, s2 = depth_sigma(cfg, 1.0), depth_sigma(cfg, 2.0)
    assert s2 == pytest.approx(4 * s1)
    assert s1 == pytest.approx(cfg.disparity_sigma_px / (focal_px(cfg) * cfg.baseline_m))


def test_the_front_end_measures_the_declared_noise(mission):
    """The laser front-end's own noise measurement on the simulated clouds finds the depth noise the
    simulator declares, within 35 % (the seabed's roughness adds a little)."""
    from frontends.laser import LaserConfig
    from frontends.laser.noise import measure_noise
    from frontends.laser.preprocess import preprocess

    cfg = LaserConfig()
    declared = mission.metadata.extras["noise"]["stereo"]
    ratios = []
    for c in list(mission.of_type(PointCloud))[::5]:
        raw = c.points[np.isfinite(c.points).all(axis=1)].astype(float)
        model = measure_noise(raw, preprocess(raw, cfg.preprocess, cfg.planes))
        z = model.range_ref * 0.97  # depth ≈ range near the optical axis
        ratios.append(model.at(model.range_ref) / (declared["depth_sigma_at_1m_m"] * z**2))
    assert 0.8 < np.median(ratios) < 1.35


def test_ground_truth_of_the_scene(mission):
    gt = mission.metadata.ground_truth
    assert gt.pipes and gt.objects
    radii = {p.radius for p in gt.pipes}
    assert all(0.02 <= r <= 0.06 for r in radii)
    assert {o.cls for o in gt.objects} <= set(cad.CLASSES)
    # every fitting sits on its pipes: each listed pipe has an end at one of the (scaled) model's ports
    layout = mission.metadata.extras["scene"]["layout"]
    for o in layout["objects"]:
        R = Rotation.from_quat(o["orientation"]).as_matrix()
        ports = np.array([R @ (o["scale"] * p) + o["position"] for p, _ in cad.library()[o["model"]].ports])
        assert o["pipes"]
        for pid in o["pipes"]:
            ends = np.array([gt.pipes[pid].p, gt.pipes[pid].q])
            assert np.linalg.norm(ends[:, None] - ports[None], axis=2).min() < 1e-6
    scans = mission.metadata.extras["scans"]
    assert len(scans) == int(SECONDS * StereoConfig().rate_hz)
    seen = {int(k) for s in scans for k in s["pipe_visible_m"]}
    assert seen <= set(gt.seen_pipes) and set(gt.seen_pipes) <= {p.id for p in gt.pipes}
    assert all(0.0 <= v <= 1.5 for s in scans for v in s["pipe_visible_m"].values())


def test_navigation_sensors_like_the_tank(mission):
    counts = {t: sum(1 for _ in mission.of_type(t)) for t in (DvlVelocity, Attitude, Depth, GroundTruthPose)}
    assert counts[DvlVelocity] == pytest.approx(5 * SECONDS, abs=2)
    assert counts[Attitude] == pytest.approx(20 * SECONDS, abs=2)
    assert counts[Depth] == pytest.approx(8 * SECONDS, abs=2)
    assert counts[GroundTruthPose] == pytest.approx(20 * SECONDS, abs=2)
    # the vehicle flies ~1.4 m above the line, ~15 m down
    z = np.array([g.position[2] for g in mission.of_type(GroundTruthPose)])
    assert 12.5 < z.min() and z.max() < 15.0


def test_config_errors_name_the_key():
    with pytest.raises(ConfigError, match="layout.radius_m"):
        load_pipeline_config(None, layout__radius_m=[0.06, 0.02])
    with pytest.raises(ConfigError, match="stereo.bogus"):
        load_pipeline_config(None, stereo__bogus=1)


def test_the_study_resolves_pipeline_missions_by_seed_alone():
    from semslam.sim.scenarios import resolve_config
    from semslam.sim.vary import ASPECTS

    cfg = resolve_config("pipeline", 5, ASPECTS, {"trajectory": {"duration_s": 4.0}}, "mine.yaml")
    assert isinstance(cfg, PipelineSimConfig) and cfg.seed == 5 and cfg.trajectory.duration_s == 4.0
    assert cfg.model_dump(exclude={"seed", "trajectory"}) == PipelineSimConfig().model_dump(
        exclude={"seed", "trajectory"}
    )
