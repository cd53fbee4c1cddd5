"""Stamp policy on recordings with mixed clocks: zero, constant, backwards and foreign-clock header
stamps, the recorder's clock days off the vehicle's (semslam.mission.stamps)."""

from __future__ import annotations

import numpy as np
import pytest
from real_recordings import FORMATS, Recording, S
from typer.testing import CliRunner

from semslam.cli import app
from semslam.errors import MissionError
from semslam.mission import Attitude, Depth, DvlVelocity, GpsFix, PointCloud
from semslam.mission.bag import read_mission
from semslam.mission.config import ReaderConfig
from semslam.mission.geodesy import Geodetic

T0 = 1_650_000_000 * S  # the vehicle's clock
DAYS = 2 * 86400 * S + 987_654_321  # the recorder's receive clock runs this much ahead
LATENCY = 5_000_000  # every message is received 5 ms after it was stamped


def mixed_clocks(fmt: str, seconds: float = 8.0, late_backwards_at: float | None = None) -> Recording:
    """/pressure: valid header stamps; /ahrs: all zero; /dvl: constant; /gps: running backwards;
    /cloud: stamped by a clock of its own (seconds since the sensor booted)."""
    rec = Recording(fmt)

    def R(t):
        return T0 + int(t * S) + DAYS + LATENCY

    for t in np.arange(0, seconds, 0.1):
        stamp = T0 + int(t * S)
        if late_backwards_at is not None and abs(t - late_backwards_at) < 1e-6:
            stamp -= 10 * S
        rec.add(
            "/pressure", "sensor_msgs/msg/FluidPressure", R(t), rec.pressure(stamp, 101325.0 + 50 * t)
        )  # at the surface
    for t in np.arange(0, seconds, 0.05):
        rec.add("/ahrs", "sensor_msgs/msg/Imu", R(t), rec.imu(0, (0, 0, 0, 1), np.diag([1e-4] * 3)))
    for t in np.arange(0, seconds, 0.2):
        rec.add("/dvl", "geometry_msgs/msg/TwistWithCovarianceStamped", R(t), rec.twist(T0, (0.5 + 0.01 * t, 0, 0)))
    for k, t in enumerate(np.arange(0, seconds, 1.0)):
        stamp = T0 + int((seconds - t) * S)  # backwards from the start
        rec.add("/gps", "sensor_msgs/msg/NavSatFix", R(t), rec.navsatfix(stamp, Geodetic(41.0, 2.0 + 1e-6 * k, 0.0)))
    for t in np.arange(0, seconds, 0.5):
        stamp = 1000 * S + int(t * S)
        rec.add("/cloud", "sensor_msgs/msg/PointCloud2", R(t), rec.pointcloud2(stamp, np.ones((10, 3), np.float32)))
    return rec


def by_sensor(mission):
    out = {}
    for m in mission:
        out.setdefault(m.sensor, []).append(m)
    return out


@pytest.mark.parametrize("fmt", FORMATS)
def test_auto_maps_bad_header_stamps_onto_the_vehicle_clock(tmp_path, fmt):
    m = read_mission(mixed_clocks(fmt).write(tmp_path))
    choice = {s: (c.source, c.reason) for s, c in m.plan.stamps.items()}
    cloud = choice.pop("cloud")
    assert choice == {
        "pressure": ("header", "valid header stamps"),
        "ahrs": ("receive", "header stamps are all zero"),
        "dvl": ("receive", "header stamps are constant"),
        "gps": ("receive", "header stamps run backwards"),
    }
    assert cloud[0] == "receive" and cloud[1].startswith("header clock -16499")  # its own clock, 1.65e9 s away
    # The offset comes from the one topic whose header stamps are the vehicle's: receive - latency.
    assert m.plan.clock.topics == ("/pressure",)
    assert m.plan.clock.offset_ns == -(DAYS + LATENCY)
    got = by_sensor(m)
    assert len(got["ahrs"]) == 160 and all(isinstance(x, Attitude) for x in got["ahrs"])
    # Receive time mapped onto the vehicle clock: the true stamp exactly (all latencies are equal here).
    np.testing.assert_array_equal([x.stamp for x in got["ahrs"]], [T0 + int(t * S) for t in np.arange(0, 8, 0.05)])
    np.testing.assert_array_equal([x.stamp for x in got["dvl"]], [T0 + int(t * S) for t in np.arange(0, 8, 0.2)])
    assert [x.stamp for x in got["gps"]] == [T0 + k * S for k in range(8)]
    assert [x.stamp for x in got["cloud"]] == [T0 + int(t * S) for t in np.arange(0, 8, 0.5)]
    assert isinstance(got["pressure"][0], Depth) and got["pressure"][0].stamp == T0
    assert isinstance(got["dvl"][0], DvlVelocity) and isinstance(got["gps"][0], GpsFix)
    assert isinstance(got["cloud"][0], PointCloud)
    stamps = [x.stamp for x in m]
    assert stamps == sorted(stamps)


def test_info_shows_each_sensors_stamp_and_the_offset(tmp_path):
    r = CliRunner().invoke(app, ["info", str(mixed_clocks("mcap").write(tmp_path))])
    assert r.exit_code == 0, r.output
    out = r.stdout
    assert "ahrs: receive time + offset (auto: header stamps are all zero)" in out
    assert "dvl: receive time + offset (auto: header stamps are constant)" in out
    assert "pressure: header stamp (auto: valid header stamps)" in out
    assert (
        "receive time → header clock: -172800.993 s (-2.00 days), median over 1 topic(s) with both (/pressure)" in out
    )


def test_policy_per_sensor_and_strict_header_stamps(tmp_path):
    path = mixed_clocks("sqlite3").write(tmp_path)
    bound = {
        "pressure": {"topic": "/pressure", "kind": "depth", "stamp": "receive"},
        "dvl": {"topic": "/dvl", "kind": "dvl"},
        "gps": {"topic": "/gps", "kind": "gps", "stamp": "header"},
    }
    # The GPS's stamps run backwards: with the header policy that is an error naming file, topic, stamps.
    with pytest.raises(
        MissionError,
        match=rf"^{path}: topic /gps: header stamps go backwards \(1650000007.000000 s after 1650000008.000000 s\)$",
    ):
        list(read_mission(path, ReaderConfig(sensors=bound)))
    # Constant header stamps taken as they are repeat: also one line with file, topic and stamp.
    bound["gps"]["stamp"] = "auto"
    with pytest.raises(
        MissionError, match=rf"^{path}: topic /dvl: header stamp 1650000000.000000 s repeats the previous message's$"
    ):
        list(read_mission(path, ReaderConfig(sensors=bound, stamp="header")))
    bound["dvl"]["stamp"] = "auto"  # the sensor's own policy wins over reader.stamp
    m = read_mission(path, ReaderConfig(sensors=bound, stamp="header"))
    assert {s: (c.source, c.policy) for s, c in m.plan.stamps.items()} == {
        "pressure": ("receive", "receive"),
        "dvl": ("receive", "auto"),
        "gps": ("receive", "auto"),
    }
    got = by_sensor(m)
    assert [x.stamp for x in got["pressure"]][:3] == [T0, T0 + S // 10, T0 + 2 * S // 10]
    assert [x.stamp for x in got["dvl"]][:2] == [T0, T0 + S // 5]


def test_stamps_running_backwards_after_the_first_messages_are_dropped_not_fatal(tmp_path):
    path = mixed_clocks("ros1", seconds=40.0, late_backwards_at=30.0).write(tmp_path)
    m = read_mission(path, ReaderConfig(sensors={"depth": {"topic": "/pressure", "kind": "depth"}}))
    assert m.plan.stamps["depth"].source == "header"  # its first messages are fine
    assert len(list(m)) == 399 and m.dropped["depth"] == 1
    assert m.dropped_fields["depth"] == {"header stamp runs backwards": 1}


def test_no_valid_header_stamps_anywhere_uses_the_receive_clock(tmp_path):
    rec = Recording("mcap")
    for k in range(20):
        rec.add("/ahrs", "sensor_msgs/msg/Imu", T0 + k * S // 10, rec.imu(0, (0, 0, 0, 1), np.diag([1e-4] * 3)))
    m = read_mission(rec.write(tmp_path))
    assert m.plan.clock.offset_ns == 0 and m.plan.clock.topics == ()
    assert [x.stamp for x in m] == [T0 + k * S // 10 for k in range(20)]
    assert "receive time is the mission clock" in m.plan.clock.format()
