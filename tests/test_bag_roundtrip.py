"""Mission → bag → Mission for every measurement type, in ROS 1, ROS 2 sqlite3 and ROS 2 mcap."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.errors import MissionError
from semslam.mission import Depth, Mission, MissionMetadata, SensorInfo, SonarSwath
from semslam.mission.bag import read_mission, sidecar_path, write_mission
from semslam.mission.config import ReaderConfig, TopicBinding

FORMATS = ["mission.bag", "mission_ros2", "mission.mcap"]

# Where a bag cannot be bit-exact: depth goes through Pa (float64 rounding), LaserScan stores
# angle_min/increment as float32, a quaternion is re-normalised.
# (rtol, atol) per field; everything else must be bit-exact.
TOL = {
    ("Depth", "depth"): (1e-12, 1e-9),
    ("Depth", "variance"): (1e-12, 0.0),
    ("SonarSwath", "angles"): (0.0, 1e-6),
    ("Attitude", "orientation"): (0.0, 1e-12),
}
# Attitude re-normalises its quaternion on construction, which is not idempotent to the last bit.
EXACT_AFTER_READ = {("SonarSwath", "angles")}


def assert_same(a, b, exact: bool = False):
    assert type(a) is type(b), (a, b)
    assert (a.stamp, a.sensor) == (b.stamp, b.sensor)
    for name, va in vars(a).items():
        vb = getattr(b, name)
        if va is None or vb is None:
            assert va is None and vb is None, f"{type(a).__name__}.{name}: {va!r} vs {vb!r}"
        elif isinstance(va, (bool, str, int, tuple)):
            assert va == vb, f"{type(a).__name__}.{name}"
        else:
            key = (type(a).__name__, name)
            rtol, atol = (0.0, 0.0) if exact and key in EXACT_AFTER_READ else TOL.get(key, (0.0, 0.0))
            np.testing.assert_allclose(
                np.asarray(vb, dtype=float),
                np.asarray(va, dtype=float),
                rtol=rtol,
                atol=atol,
                equal_nan=True,
                err_msg=f"{type(a).__name__}.{name} at {a.stamp}",
            )


@pytest.mark.parametrize("name", FORMATS)
def test_round_trip_every_type(tmp_path, sample_mission, name):
    original = sample_mission()
    path = write_mission(original, tmp_path / name)
    first = read_mission(path)
    a, b = list(original), list(first)
    assert len(a) == len(b) == 10 + 40 + 16 + 4 + 8 + 20
    for x, y in zip(a, b):
        assert_same(x, y)
    assert {type(m).__name__ for m in b} == {
        "DvlVelocity",
        "Attitude",
        "Depth",
        "PointCloud",
        "SonarSwath",
        "GroundTruthPose",
    }
    assert sum(not m.valid for m in b if m.sensor == "dvl") == 2

    # metadata: names, kinds, topics, extrinsics, ground truth, extras
    assert list(first.metadata.sensors) == list(original.metadata.sensors)
    for s, t in zip(original.metadata.sensors.values(), first.metadata.sensors.values()):
        assert (s.name, s.kind, s.topic) == (t.name, t.kind, t.topic)
        np.testing.assert_array_equal(s.T_BS, t.T_BS)
    assert first.metadata.sensors["dvl"].msgtype == "cola2_msgs/msg/DVL"
    assert first.metadata.ground_truth == original.metadata.ground_truth
    assert first.metadata.extras == original.metadata.extras
    assert first.metadata.name == "sample"

    # read → write → read is exact (up to the depth ↔ pressure conversion)
    second = read_mission(write_mission(first, tmp_path / ("again_" + name)))
    for x, y in zip(b, second):
        assert_same(x, y, exact=True)
    assert len(list(second)) == len(b)


def test_formats_and_sidecar_locations(tmp_path, sample_mission):
    m = sample_mission(seconds=0.5)
    ros1 = write_mission(m, tmp_path / "a.bag")
    assert ros1.is_file() and ros1.read_bytes().startswith(b"#ROSBAG V2.0")
    assert sidecar_path(ros1) == tmp_path / "a.bag.semslam.json" and sidecar_path(ros1).is_file()
    ros2 = write_mission(m, tmp_path / "b")
    assert (ros2 / "metadata.yaml").is_file() and any(ros2.glob("*.db3"))
    assert sidecar_path(ros2) == ros2 / "semslam.json" and sidecar_path(ros2).is_file()
    mcap = write_mission(m, tmp_path / "c.mcap")
    assert mcap.is_file() and mcap.read_bytes()[:8] == b"\x89MCAP0\r\n"
    # nothing else left behind (no temporary directories)
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "a.bag",
        "a.bag.semslam.json",
        "b",
        "c.mcap",
        "c.mcap.semslam.json",
    ]


def test_sensor_without_measurements_keeps_its_topic(tmp_path, sample_mission):
    m = sample_mission(seconds=0.5)
    m.metadata.sensors["spare_dvl"] = SensorInfo("spare_dvl", "dvl", topic="/spare/dvl")
    back = read_mission(write_mission(m, tmp_path / "x.bag"))
    assert back.metadata.sensors["spare_dvl"].topic == "/spare/dvl"
    assert back.message_counts["/spare/dvl"] == 0


def test_refuses_to_overwrite_unless_asked(tmp_path, sample_mission):
    m = sample_mission(seconds=0.5)
    for name in ("x.bag", "y"):
        p = write_mission(m, tmp_path / name)
        with pytest.raises(MissionError, match="exists already"):
            write_mission(m, p)
        write_mission(m, p, overwrite=True)
        assert len(list(read_mission(p))) == len(list(m))


def test_failed_write_leaves_nothing(tmp_path):
    # A swath whose beams are not on a uniform grid cannot be a LaserScan: the write fails cleanly.
    bad = SonarSwath(5, "sonar", angles=np.array([0.0, 0.1, 0.1 * np.pi]), ranges=np.ones(3))
    m = Mission.from_measurements(MissionMetadata(), [Depth(1, "depth", depth=1.0, variance=0.1), bad])
    for name in ("x.bag", "y", "z.mcap"):
        with pytest.raises(
            MissionError, match="sensor 'sonar' at t=0.000000 s: swath beam angles are not on a uniform grid"
        ):
            write_mission(m, tmp_path / name)
    assert list(tmp_path.iterdir()) == []


def test_configuration_overrides_sidecar(tmp_path, sample_mission):
    p = write_mission(sample_mission(seconds=0.5), tmp_path / "x.bag")
    T = np.eye(4)
    T[:3, 3] = (1.0, 2.0, 3.0)
    cfg = ReaderConfig(
        sensors={
            "dvl": TopicBinding(topic="/nav/dvl", kind="dvl", T_BS=T.tolist()),
            "imu": TopicBinding(topic="/nav/imu", kind="ahrs"),
        }
    )
    m = read_mission(p, cfg)
    assert list(m.metadata.sensors) == ["dvl", "imu"]  # only the configured sensors are read
    np.testing.assert_array_equal(m.metadata.sensors["dvl"].T_BS, T)
    np.testing.assert_array_equal(m.metadata.sensors["imu"].T_BS, np.eye(4))
    assert {x.sensor for x in m} == {"dvl", "imu"}


def test_stream_is_in_stamp_order_across_topics(tmp_path, sample_mission):
    stamps = [m.stamp for m in read_mission(write_mission(sample_mission(), tmp_path / "x"))]
    assert stamps == sorted(stamps)
