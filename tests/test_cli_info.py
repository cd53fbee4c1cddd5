"""`semslam info` on bags written by the tests, and every bad input as one line + exit code 1."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from semslam.cli import app
from semslam.mission import Depth, DvlVelocity, Mission, MissionMetadata
from semslam.mission.bag import write_mission

runner = CliRunner()

RATES = {"dvl": 5.0, "ahrs": 20.0, "depth": 8.0, "laser": 2.0, "sonar": 4.0, "gt": 10.0}


def info(*args):
    return runner.invoke(app, ["info", *map(str, args)])


def row(output: str, sensor: str) -> list[str]:
    return next(line.split() for line in output.splitlines() if line.split()[:1] == [sensor])


def assert_one_line_error(result, *fragments):
    assert result.exit_code == 1, result.output
    assert "Traceback" not in result.output
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("semslam: error: ")
    for f in fragments:
        assert f in lines[0], (f, lines[0])


@pytest.mark.parametrize("name", ["m.bag", "m_ros2", "m.mcap"])
def test_info_counts_and_rates(tmp_path, sample_mission, name):
    path = write_mission(sample_mission(seconds=4.0), tmp_path / name)
    r = info(path)
    assert r.exit_code == 0, r.output
    assert "mission sample" in r.stdout and "duration 3.950 s" in r.stdout
    for sensor, rate in RATES.items():
        cols = row(r.stdout, sensor)
        assert int(cols[4]) == round(4.0 * rate), cols
        assert float(cols[5]) == pytest.approx(rate), cols
    dvl = row(r.stdout, "dvl")
    assert dvl[2:4] == ["/nav/dvl", "cola2_msgs/DVL"] and dvl[9] == "2"  # two invalid readings
    assert row(r.stdout, "laser")[3] == "sensor_msgs/PointCloud2"


def _dvl_mission(stamps_valid, extra=()):
    ms = [
        DvlVelocity(
            t,
            "dvl",
            velocity=(0.1, 0.0, 0.0) if v else (np.nan,) * 3,
            covariance=np.eye(3) * 1e-4,
            valid=v,
            beam_valid=(v,) * 4,
        )
        for t, v in stamps_valid
    ]
    return Mission.from_measurements(MissionMetadata(name="dropouts"), [*ms, *extra])


def test_info_reports_dvl_dropouts_and_stream_gaps(tmp_path):
    # DVL at 5 Hz for 10 s; bottom lock lost from 3.0 s to 5.0 s, and silent from 7.0 s to 8.0 s
    dvl = [(10**9 + k * 200_000_000, not 15 <= k < 25) for k in range(50) if not 35 < k < 40]
    depth = [Depth(10**9 + k * 125_000_000, "depth", depth=1.0, variance=0.01) for k in range(80) if not 40 <= k < 60]
    r = info(write_mission(_dvl_mission(dvl, depth), tmp_path / "d.bag"), "--allow-missing", "ahrs")
    assert r.exit_code == 0, r.output
    assert row(r.stdout, "dvl")[9] == "10"  # invalid readings
    assert "dvl: DVL dropout at 2.800 s for 2.200 s (period 0.200 s)" in r.stdout
    assert "dvl: DVL dropout at 7.000 s for 1.000 s" in r.stdout
    assert "depth: gap at 4.875 s for 2.625 s (period 0.125 s)" in r.stdout


def test_info_drops_and_reports_nonfinite_messages(tmp_path):
    ms = [Depth(10**9 + k * 10**8, "depth", depth=np.nan if k in (3, 7) else 1.0, variance=0.01) for k in range(10)]
    ms.append(DvlVelocity(10**9, "dvl", velocity=(np.inf, 0, 0), valid=True))
    ms.append(DvlVelocity(2 * 10**9, "dvl", velocity=(np.nan,) * 3, valid=False))  # a dropout, not a bad message
    path = write_mission(Mission.from_measurements(MissionMetadata(name="nan"), ms), tmp_path / "nan")
    r = info(path, "--allow-missing", "ahrs")
    assert r.exit_code == 0, r.output
    assert row(r.stdout, "depth")[4] == "8" and row(r.stdout, "depth")[10] == "2"
    assert row(r.stdout, "dvl")[4] == "1" and row(r.stdout, "dvl")[10] == "1"
    assert "depth: 2 message(s) dropped (non-finite or unusable field: depth ×2)" in r.stdout
    assert "dvl: 1 message(s) dropped (non-finite or unusable field: velocity ×1)" in r.stdout

    # strict reading turns the first one into an error naming file, topic and field
    cfg = tmp_path / "strict.yaml"
    cfg.write_text("reader:\n  on_nonfinite: error\n")
    r = info(path, "--config", cfg, "--allow-missing", "ahrs")
    assert_one_line_error(r, str(path), "topic /dvl", "field velocity is not finite", "t=1.000000 s")


def test_missing_file(tmp_path):
    assert_one_line_error(info(tmp_path / "nope.bag"), f"{tmp_path / 'nope.bag'}: no such file or directory")


def test_directory_that_is_not_a_bag(tmp_path):
    (tmp_path / "notabag").mkdir()
    assert_one_line_error(info(tmp_path / "notabag"), "notabag: directory is not a ROS 2 bag (no metadata.yaml)")


def test_file_that_is_not_a_bag(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    assert_one_line_error(info(tmp_path / "notes.txt"), "notes.txt: not a bag")
    (tmp_path / "fake.bag").write_text("hello")
    assert_one_line_error(info(tmp_path / "fake.bag"), "fake.bag: cannot open bag")


@pytest.mark.parametrize("name", ["t.bag", "t_ros2", "t.mcap"])
def test_truncated_bag(tmp_path, sample_mission, name):
    path = write_mission(sample_mission(seconds=2.0), tmp_path / name)
    f = next(path.glob("*.db3")) if path.is_dir() else path
    data = f.read_bytes()
    f.write_bytes(data[: len(data) * 2 // 3])
    assert_one_line_error(info(path), str(path), "cannot open bag, corrupt or truncated?")


def test_configured_topic_missing(tmp_path, sample_mission):
    path = write_mission(sample_mission(seconds=0.5), tmp_path / "m.bag")
    cfg = tmp_path / "c.yaml"
    cfg.write_text("reader:\n  sensors:\n    dvl:\n      topic: /girona500/dvl\n      kind: dvl\n")
    assert_one_line_error(
        info(path, "--config", cfg),
        str(path),
        "topic /girona500/dvl (configured sensor 'dvl') is not in the bag",
        "/nav/dvl",
    )


def test_configured_topic_of_unsupported_type(tmp_path, sample_mission):
    path = write_mission(sample_mission(seconds=0.5), tmp_path / "m.bag")
    cfg = tmp_path / "c.yaml"
    cfg.write_text("reader:\n  sensors:\n    odd:\n      topic: /nav/dvl\n      kind: banana\n")
    assert_one_line_error(info(path, "--config", cfg), "sensor 'odd': unknown kind 'banana'")


def test_stamps_going_backwards(tmp_path):
    """Strict header stamps: an error naming file, topic and stamps. By default (auto) the topic is
    read by receive time instead, and info says so."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    path = tmp_path / "back.bag"
    with Writer(path) as w:
        conn = w.add_connection("/depth", "sensor_msgs/msg/FluidPressure", typestore=store)
        for k, stamp in enumerate([1.0, 1.1, 1.2, 0.9, 1.4]):
            ns = int(stamp * 1e9)
            hdr = T["std_msgs/msg/Header"](
                seq=k, stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9), frame_id="p"
            )
            msg = T["sensor_msgs/msg/FluidPressure"](header=hdr, fluid_pressure=101325.0, variance=1.0)
            w.write(conn, 10**9 + k * 10**8, store.serialize_ros1(msg, "sensor_msgs/msg/FluidPressure"))
    cfg = tmp_path / "strict.yaml"
    cfg.write_text("reader:\n  stamp: header\n")
    assert_one_line_error(
        info(path, "--config", cfg), str(path), "topic /depth: header stamps go backwards (0.900000 s after 1.200000 s)"
    )
    r = info(path, "--allow-missing", "dvl,ahrs")
    assert r.exit_code == 0, r.output
    assert int(row(r.stdout, "depth")[4]) == 5
    assert "depth: receive time + offset (auto: header stamps run backwards)" in r.stdout


def test_malformed_sidecar(tmp_path, sample_mission):
    path = write_mission(sample_mission(seconds=0.5), tmp_path / "m.bag")
    Path(str(path) + ".semslam.json").write_text(
        '{"format": "semslam-mission", "version": 1, "sensors": {"x": {"kind": "rocket"}}}'
    )
    assert_one_line_error(info(path), "m.bag.semslam.json: sensors.x.kind")


def test_sidecar_is_optional(tmp_path, sample_mission):
    path = write_mission(sample_mission(seconds=1.0), tmp_path / "m_ros2")
    (path / "semslam.json").unlink()
    r = info(path)
    assert r.exit_code == 0, r.output
    assert int(row(r.stdout, "nav/dvl")[4]) == 5  # sensors named after their topics
    shutil.rmtree(path)


def test_configured_kind_must_match_message_type(tmp_path, sample_mission):
    path = write_mission(sample_mission(seconds=0.5), tmp_path / "m.bag")
    cfg = tmp_path / "c.yaml"
    cfg.write_text("reader:\n  sensors:\n    imu:\n      topic: /nav/dvl\n      kind: ahrs\n")
    assert_one_line_error(
        info(path, "--config", cfg),
        "topic /nav/dvl: cola2_msgs/DVL feeds a dvl sensor, but configured sensor 'imu' is of kind ahrs",
    )
