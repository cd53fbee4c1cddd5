"""The oracle front-end: visibility, noise statistics, misses, false positives, classification."""

import numpy as np
import pytest

from frontends.oracle import OracleFrontend
from semslam.errors import ConfigError
from semslam.mission.ground_truth import GroundTruthMap, GtObject, GtPipe
from semslam.mission.measurements import GroundTruthPose, PointCloud
from semslam.mission.mission import MissionMetadata, SensorInfo
from semslam.observations import LineObservation
from semslam.registry import load_frontend_class

CLASSES = ("valve", "elbow", "tee")


def metadata(objects=(), pipes=(), T_BS=np.eye(4)):
    gt = GroundTruthMap(classes=CLASSES, objects=tuple(objects), pipes=tuple(pipes))
    return MissionMetadata(sensors={"laser": SensorInfo("laser", "laser", T_BS=T_BS)}, ground_truth=gt)


def scan(fe, stamp=10, position=(0.0, 0.0, 0.0)):
    fe.process(GroundTruthPose(stamp, "gt", position=np.array(position), orientation=np.array([0, 0, 0, 1.0])), None)
    return fe.process(PointCloud(stamp, "laser"), None)


def test_registered_through_entry_point():
    assert load_frontend_class("oracle") is OracleFrontend


def test_visibility_cone_and_range():
    objs = [
        GtObject(1, "valve", (0.0, 0.0, 3.0)),  # straight below: visible
        GtObject(2, "valve", (0.0, 0.0, 8.0)),  # beyond max range
        GtObject(3, "valve", (3.0, 0.0, 1.0)),  # 72° off the axis
        GtObject(4, "valve", (0.0, 0.0, -3.0)),  # behind
    ]
    fe = OracleFrontend(metadata(objs), {"point_sigma_m": 0.0, "point_sigma_per_m": 0.0})
    obs = scan(fe)
    assert [o.truth_id for o in obs] == [1]
    np.testing.assert_allclose(obs[0].position, [0, 0, 3.0], atol=1e-9)


def test_observations_in_sensor_frame_with_stated_noise():
    R = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])  # laser yawed 90° on the body
    T_BS = np.eye(4)
    T_BS[:3, :3], T_BS[:3, 3] = R, [0.5, 0.0, 0.2]
    fe = OracleFrontend(metadata([GtObject(7, "tee", (1.5, 1.0, 4.0))], T_BS=T_BS), {"seed": 3})
    expected = R.T @ (np.array([1.5, 1.0, 4.0]) - [1.0, 0.0, 0.0] - [0.5, 0.0, 0.2])
    errs = np.array([scan(fe, 10 + i, (1.0, 0.0, 0.0))[0].position - expected for i in range(2000)])
    sigma = 0.02 + 0.002 * np.linalg.norm(expected)
    assert np.all(np.abs(errs.mean(axis=0)) < 4 * sigma / np.sqrt(2000))
    np.testing.assert_allclose(errs.std(axis=0), sigma, rtol=0.08)
    o = scan(fe, 99999, (1.0, 0.0, 0.0))[0]
    np.testing.assert_allclose(o.covariance, np.eye(3) * sigma**2)


def test_pipe_clipped_to_view():
    pipe = GtPipe(5, (-10.0, 0.0, 3.0), (10.0, 0.0, 3.0), 0.05)
    fe = OracleFrontend(
        metadata(pipes=[pipe]), {"line_sigma_m": 0.0, "line_along_sigma_m": 0.0, "fov_half_angle_deg": 45}
    )
    (obs,) = scan(fe)
    assert isinstance(obs, LineObservation) and obs.truth_id == 5
    # Cone of 45° at 3 m depth: the visible stretch is |x| ≤ 3 (within sampling).
    xs = sorted([obs.p[0], obs.q[0]])
    assert xs[0] == pytest.approx(-3.0, abs=0.05) and xs[1] == pytest.approx(3.0, abs=0.05)
    np.testing.assert_allclose([obs.p[1:], obs.q[1:]], [[0, 3], [0, 3]], atol=1e-3)


def test_miss_and_false_positive_rates():
    objs = [GtObject(i, CLASSES[i % 3], (0.3 * (i % 5) - 0.6, 0.3 * (i // 5) - 0.6, 3.0)) for i in range(25)]
    fe = OracleFrontend(metadata(objs), {"seed": 4, "miss_rate": 0.1, "false_positive_rate": 0.1})
    n_true = n_fp = 0
    for i in range(200):
        obs = scan(fe, 10 + i)
        n_true += sum(o.truth_id is not None for o in obs)
        n_fp += sum(o.truth_id is None for o in obs)
    assert n_true / (200 * 25) == pytest.approx(0.9, abs=0.015)
    assert n_fp / n_true == pytest.approx(0.1, rel=0.15)  # Poisson(0.1 × n_reported)


def test_class_likelihood_is_a_confusion_column():
    fe = OracleFrontend(metadata([GtObject(1, "elbow", (0.0, 0.0, 3.0))]), {"seed": 5, "classification_accuracy": 0.7})
    right = 0
    for i in range(1000):
        lk = scan(fe, 10 + i)[0].class_likelihood
        assert set(lk) == set(CLASSES) and np.isclose(sum(lk.values()), 1.0)
        detected = max(lk, key=lk.get)
        assert lk[detected] == pytest.approx(0.7) and all(
            v == pytest.approx(0.15) for c, v in lk.items() if c != detected
        )
        right += detected == "elbow"
    assert right / 1000 == pytest.approx(0.7, abs=0.05)


def test_pose_interpolated_between_ground_truth_samples():
    fe = OracleFrontend(
        metadata([GtObject(1, "valve", (1.0, 0.0, 3.0))]), {"point_sigma_m": 0.0, "point_sigma_per_m": 0.0}
    )
    fe.process(GroundTruthPose(0, "gt", position=np.zeros(3), orientation=np.array([0, 0, 0, 1.0])), None)
    fe.process(GroundTruthPose(100, "gt", position=np.array([1.0, 0, 0]), orientation=np.array([0, 0, 0, 1.0])), None)
    (obs,) = fe.process(PointCloud(150, "laser"), None)  # extrapolated to x = 1.5
    np.testing.assert_allclose(obs.position, [-0.5, 0.0, 3.0], atol=1e-9)


def test_invalid_config_is_a_one_line_config_error():
    with pytest.raises(ConfigError, match="frontends.oracle.miss_rate"):
        OracleFrontend(metadata(), {"miss_rate": 2.0})
    with pytest.raises(ConfigError, match="frontends.oracle.bogus"):
        OracleFrontend(metadata(), {"bogus": 1})
    with pytest.raises(ConfigError, match="ground truth"):
        OracleFrontend(MissionMetadata(), {})
