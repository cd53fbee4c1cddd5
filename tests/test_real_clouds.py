"""Point clouds as cameras and scanners record them: PCL's packed colour, organised clouds with
invalid points, and clouds whose scale does not fit a sensor (warned about, never silently read)."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from real_recordings import Recording, S
from typer.testing import CliRunner

from semslam.cli import app
from semslam.mission import Mission, MissionMetadata, PointCloud, SensorInfo
from semslam.mission.bag import read_mission, write_mission

T0 = 1_600_000_000 * S


def colours(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (n, 3)).astype(np.uint8)


@pytest.mark.parametrize(("packed", "datatype"), [("rgb", 7), ("rgba", 6)])
@pytest.mark.parametrize("fmt", ["mcap", "ros1"])
def test_pcl_packed_colour_and_an_organised_cloud_with_invalid_points(tmp_path, fmt, packed, datatype):
    rng = np.random.default_rng(1)
    h, w = 4, 6
    pts = rng.uniform(0.5, 3.0, (h * w, 3)).astype(np.float32)
    pts[[3, 10, 11]] = np.nan  # no return at three pixels of an organised (stereo) cloud
    rgb = colours(h * w)
    rec = Recording(fmt)
    msg = rec.pointcloud2(T0, pts, rgb, height=h, packed=packed, rgb_datatype=datatype)
    rec.add("/stereo/points", "sensor_msgs/msg/PointCloud2", T0, msg)
    (cloud,) = list(read_mission(rec.write(tmp_path)))
    keep = np.isfinite(pts).all(axis=1)
    assert isinstance(cloud, PointCloud) and len(cloud.points) == h * w - 3
    np.testing.assert_array_equal(cloud.points, pts[keep])
    np.testing.assert_array_equal(cloud.rgb, rgb[keep])  # colours stay with their points
    assert cloud.intensity is None


@pytest.mark.parametrize("name", ["c.bag", "c_ros2", "c.mcap"])
def test_colour_and_intensity_round_trip(tmp_path, name):
    rng = np.random.default_rng(2)
    clouds = [
        PointCloud(T0, "cam", points=rng.normal(size=(50, 3)).astype(np.float32), rgb=colours(50, 1)),
        PointCloud(
            T0 + S,
            "cam",
            points=rng.normal(size=(40, 3)).astype(np.float32),
            intensity=rng.random(40).astype(np.float32),
            rgb=colours(40, 2),
        ),
        PointCloud(T0 + 2 * S, "cam", points=rng.normal(size=(30, 3)).astype(np.float32)),
    ]
    meta = MissionMetadata(name="cam", sensors={"cam": SensorInfo("cam", "laser", topic="/cam/points")})
    back = list(read_mission(write_mission(Mission.from_measurements(meta, clouds), tmp_path / name)))
    for a, b in zip(clouds, back):
        np.testing.assert_array_equal(b.points, a.points)
        for field in ("intensity", "rgb"):
            va, vb = getattr(a, field), getattr(b, field)
            assert (va is None) == (vb is None)
            if va is not None:
                np.testing.assert_array_equal(vb, va)
                assert vb.dtype == va.dtype


@pytest.mark.parametrize(
    ("scale", "offset", "what"),
    [
        (1000.0, 0.0, "median point distance beyond 300 m from the sensor (millimetres? a world-frame cloud?)"),
        (1.0, 4.6e6, "median point distance beyond 300 m from the sensor (millimetres? a world-frame cloud?)"),
        (1e-3, 0.0, "median point distance below 0.01 m from the sensor (kilometres?)"),
    ],
)
def test_a_cloud_that_does_not_fit_the_sensor_is_warned_about(tmp_path, caplog, scale, offset, what):
    rng = np.random.default_rng(3)
    rec = Recording("mcap")
    for k in range(4):
        pts = (rng.uniform(1.0, 4.0, (200, 3)) * scale + offset).astype(np.float32)
        rec.add("/laser/points", "sensor_msgs/msg/PointCloud2", T0 + k * S, rec.pointcloud2(T0 + k * S, pts))
    path = rec.write(tmp_path)
    with caplog.at_level(logging.WARNING, logger="semslam.mission"):
        m = read_mission(path)
        assert len(list(m)) == 4  # read, not refused
    (record,) = caplog.records  # once per sensor, one line naming file, topic and stamp
    assert f"{path}: topic /laser/points: point cloud at t=1600000000.000000 s: median point distance" in record.message
    assert "\n" not in record.message
    assert m.warnings == {"laser/points": {what: 4}}
    r = CliRunner().invoke(app, ["info", str(path), "--allow-missing", "dvl,ahrs"])
    assert r.exit_code == 0 and f"warnings:\n  laser/points: {what} ×4" in r.stdout


def test_a_cloud_in_metres_near_the_sensor_is_not_warned_about(tmp_path, caplog):
    rec = Recording("ros1")
    pts = np.random.default_rng(4).uniform(0.3, 5.0, (500, 3)).astype(np.float32)
    rec.add("/laser/points", "sensor_msgs/msg/PointCloud2", T0, rec.pointcloud2(T0, pts))
    with caplog.at_level(logging.WARNING, logger="semslam.mission"):
        m = read_mission(rec.write(tmp_path))
        assert len(list(m)) == 1
    assert not caplog.records and m.warnings == {}


def test_a_run_warns_about_a_cloud_in_millimetres(tmp_path, caplog):
    """On the ``semslam.mission`` logger (stderr, one line, when nothing configured logging)."""
    rng = np.random.default_rng(5)
    rec = Recording("sqlite3")
    for k in range(30):
        t = T0 + k * S // 10
        rec.add("/ahrs", "sensor_msgs/msg/Imu", t, rec.imu(t, (0, 0, 0, 1), np.diag([1e-4] * 3)))
        if k % 2 == 0:  # a velocity source: the mission check refuses a run without one
            rec.add("/dvl", "geometry_msgs/msg/TwistWithCovarianceStamped", t, rec.twist(t, (0.2 + 0.01 * k, 0, 0)))
        if k % 10 == 0:
            pts = (rng.uniform(1.0, 3.0, (300, 3)) * 1000).astype(np.float32)
            rec.add("/laser/points", "sensor_msgs/msg/PointCloud2", t, rec.pointcloud2(t, pts))
    path = rec.write(tmp_path)
    with caplog.at_level(logging.WARNING, logger="semslam.mission"):
        r = CliRunner().invoke(app, ["run", str(path), "--estimator", "dr", "--out", str(tmp_path / "out")])
    assert r.exit_code == 0, r.output
    (line,) = [x.message for x in caplog.records if "point cloud" in x.message]
    assert line.startswith(f"{path}: topic /laser/points: point cloud at t=1600000000.000000 s: median point distance")
    assert "millimetres? a world-frame cloud?" in line
