"""The laser front-end behind the registry: configuration, observations, recognition hook."""

import numpy as np
import pytest

from frontends.laser import LaserFrontend
from semslam.errors import ConfigError
from semslam.mission.measurements import PointCloud
from semslam.mission.mission import MissionMetadata, SensorInfo
from semslam.observations import Connectivity, LineObservation, PointObservation
from semslam.registry import Frontend, load_frontend_class
from tests.support.synthetic import cached_scan


class _View:
    def __init__(self, T_WB=None):
        self.T_WB = T_WB

    def pose_at(self, stamp):
        return self.T_WB

    def landmarks(self):
        return []


def _metadata():
    # laser looking down: sensor axes = body axes (x forward, y right, z down)
    return MissionMetadata(sensors={"laser": SensorInfo("laser", "laser", "/scan", T_BS=np.eye(4))})


def test_registered_as_laser():
    cls = load_frontend_class("laser")
    assert cls is LaserFrontend
    fe = cls(_metadata(), {})
    assert isinstance(fe, Frontend) and fe.name == "laser" and PointCloud in fe.consumes


def test_config_errors_name_the_key():
    with pytest.raises(ConfigError, match="frontends.laser.pipes.max_radius"):
        LaserFrontend(_metadata(), {"pipes": {"max_radius": -1}})
    with pytest.raises(ConfigError, match="frontends.laser.planes.bogus"):
        LaserFrontend(_metadata(), {"planes": {"bogus": 1}})


def test_process_gives_lines_and_points():
    scan = cached_scan()
    fe = LaserFrontend(_metadata(), {"recognition": {"enabled": False}})  # geometry only
    obs = fe.process(PointCloud(stamp=123, sensor="laser", points=scan.points), _View(np.eye(4)))
    lines = [o for o in obs if isinstance(o, LineObservation)]
    points = [o for o in obs if isinstance(o, PointObservation)]
    assert len(lines) == 6 and len(points) == 5
    assert all(o.stamp == 123 and o.sensor == "laser" for o in obs)
    for ln in lines:
        assert np.linalg.eigvalsh(ln.covariance).min() > 0
        assert 0.03 < ln.radius < 0.064
    for pt in points:
        assert pt.class_likelihood is None
        assert np.linalg.eigvalsh(pt.covariance).min() > 0
        assert pt.cloud.dtype == np.float32 and pt.cloud.shape[1] == 3
        assert isinstance(pt.connectivity, Connectivity) and pt.connectivity.configuration in (1, 2, 3, 4)
        assert len(pt.connectivity.directions) == pt.connectivity.n_pipes
    # full-resolution clouds: the raw points of the object's voxels, more than the voxels
    seg = fe.last
    biggest = max(points, key=lambda p: len(p.cloud))
    assert len(biggest.cloud) > max(len(o.indices) for o in seg.objects)
    # "up" came from the pose and extrinsic: the sensor's −z
    assert np.allclose(seg.up, [0, 0, -1.0])


def test_recognizer_hook_fills_likelihoods():
    seen = []

    class Recognizer:
        def classify(self, cloud, connectivity):
            seen.append((cloud.shape, connectivity.configuration))
            return {"valve": 0.7, "elbow": 0.3}

    scan = cached_scan()
    fe = LaserFrontend(_metadata(), {}, recognizer=Recognizer())
    obs = fe.process(PointCloud(stamp=1, sensor="laser", points=scan.points), _View())
    points = [o for o in obs if isinstance(o, PointObservation)]
    assert len(seen) == len(points) == 5
    assert all(dict(p.class_likelihood) == {"valve": 0.7, "elbow": 0.3} for p in points)


def test_up_follows_the_ahrs_attitude():
    from scipy.spatial.transform import Rotation

    from semslam.mission.measurements import Attitude

    meta = _metadata()
    T_BA = np.eye(4)
    T_BA[:3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()  # the AHRS mounted turned
    meta.sensors["ahrs"] = SensorInfo("ahrs", "ahrs", "/imu", T_BS=T_BA)
    fe = LaserFrontend(meta, {})
    assert fe.uses_view is False and Attitude in fe.consumes
    assert np.allclose(fe._up("laser"), [0, 0, -1.0])  # before any AHRS reading: level vehicle assumed
    R_WB = Rotation.from_euler("ZYX", [1.2, np.radians(20), np.radians(-5)]).as_matrix()
    R_WA = R_WB @ T_BA[:3, :3]
    assert fe.process(Attitude(stamp=1, sensor="ahrs", orientation=Rotation.from_matrix(R_WA).as_quat()), None) == []
    assert np.allclose(fe._up("laser"), R_WB.T @ [0, 0, -1.0])
    assert fe._up("unknown") is None


def test_empty_and_tiny_scans():
    fe = LaserFrontend(_metadata(), {})
    assert fe.process(PointCloud(stamp=1, sensor="laser", points=np.zeros((0, 3))), _View()) == []
    few = np.random.default_rng(0).normal(size=(30, 3)).astype(np.float32) + [0, 0, 2]
    assert fe.process(PointCloud(stamp=1, sensor="laser", points=few), _View()) == []


def test_finish_hands_over_the_measured_syn_confusion_only():
    class Recognizer:
        classes = ["elbow", "valve"]
        confusion = np.array([[9.0, 1.0], [2.0, 8.0]])
        confusion_measured = True

        def classify(self, cloud, connectivity):
            return {"elbow": 0.5, "valve": 0.5}

    rec = Recognizer()
    summary = LaserFrontend(_metadata(), {}, recognizer=rec).finish(_View())
    assert summary.section == "recognition"
    syn = summary.metrics["SYN"]
    assert syn["accuracy"] == pytest.approx(17 / 20)
    assert syn["confusion"] == [[9, 1], [2, 8]] and syn["classes"] == ["elbow", "valve"]
    rec.confusion_measured = False  # the generic assumption is no SYN measurement
    assert LaserFrontend(_metadata(), {}, recognizer=rec).finish(_View()).section is None
    # no recogniser built during the mission (no object seen): nothing, and none built now
    fe = LaserFrontend(_metadata(), {"recognition": {"enabled": True}})
    assert fe.finish(_View()).section is None and fe._recognizer is None


def test_replicas_in_two_processes_give_the_inline_observations():
    """The laser declares its scans independent (parallel_consumes): its RANSAC and descriptor
    generators are seeded per scan, so two worker processes sharing the scans (each seeing every
    AHRS reading) give exactly the observations of one front-end inline."""
    from scipy.spatial.transform import Rotation

    from semslam.config import SemslamConfig
    from semslam.ekf import DeadReckoning
    from semslam.mission.measurements import Attitude
    from semslam.mission.mission import Mission
    from semslam.pipeline import run_pipeline

    meta = _metadata()
    meta.sensors["ahrs"] = SensorInfo("ahrs", "ahrs", "/imu", T_BS=np.eye(4))
    scan = cached_scan()
    rng = np.random.default_rng(3)
    ms = []
    for k in range(6):  # each scan jittered, with a different attitude before it
        q = Rotation.from_euler("ZYX", [0.3 * k, 0.02 * k, -0.01 * k]).as_quat()
        ms.append(Attitude(stamp=k * 10**9, sensor="ahrs", orientation=q))
        pts = scan.points + rng.normal(scale=0.002, size=scan.points.shape)
        ms.append(PointCloud(stamp=k * 10**9 + 5, sensor="laser", points=pts.astype(np.float32)))
    mission = Mission.from_measurements(meta, ms)
    cfg = {"recognition": {"enabled": False}}

    def stream(**kw):
        res = run_pipeline(mission, [DeadReckoning(meta, SemslamConfig())], [LaserFrontend(meta, cfg)], **kw)
        return [
            (
                r.stamp,
                type(r.observation).__name__,
                getattr(r.observation, "position", None),
                getattr(r.observation, "p", None),
            )
            for r in res.observations
        ]

    inline, apart = stream(frontend_process=False), stream(frontend_workers=2)
    assert len(inline) > 20 and len(apart) == len(inline)
    for a, b in zip(inline, apart):
        assert a[:2] == b[:2]
        for x, y in zip(a[2:], b[2:]):
            assert (x is None and y is None) or np.array_equal(x, y)
