"""The mission check on recordings without a velocity source, an attitude source, a depth sensor or a
sidecar: refused with one line naming the bag and what is missing, unless the user accepts it."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from real_recordings import Recording

from faults.bags import T0, Faults, recording
from faults.cli import assert_accepted, assert_refused, check_section, info
from semslam.errors import ConfigError, MissionError
from semslam.mission import Mission
from semslam.mission.bag import read_mission, write_mission
from semslam.mission.check import check_mission, parse_allow_missing
from semslam.mission.config import ReaderConfig


@pytest.mark.parametrize("fmt", ["mcap", "ros1"])
def test_no_dvl_is_refused_unless_accepted(tmp_path, fmt):
    path = recording(fmt, 20.0, Faults(without=("/dvl",))).write(tmp_path)
    m = read_mission(path)
    check = check_mission(m)
    assert check.refusals == [
        "no velocity source (no DVL topic and no odometry front-end): no estimator gives a meaningful trajectory "
        "without one (bind a topic in reader.sensors with kind dvl, or accept it with --allow-missing dvl)"
    ]
    with pytest.raises(MissionError, match=rf"^{path}: no velocity source \(no DVL topic"):
        check.raise_if_refused()
    r = info(path)
    assert_refused(r, str(path), "no velocity source (no DVL topic", "--allow-missing dvl")
    assert "refused: no velocity source" in check_section(r.stdout)[0]  # the report is printed all the same

    accepted = check_mission(m, allow_missing={"dvl"})
    assert accepted.refusals == []
    assert f"{path}: no velocity source (no DVL topic): accepted (--allow-missing dvl)" in accepted.warnings[0]
    out = assert_accepted(info(path, "--allow-missing", "dvl"))
    assert check_section(out)[0].startswith("warning: no velocity source (no DVL topic): accepted")
    # The odometry front-end is a velocity source of its own.
    assert check_mission(m, frontends=["laser", "odometry"]).refusals == []
    assert_accepted(info(path, "--frontends", "laser,odometry"))


def test_no_ahrs_is_refused_and_a_raw_imu_is_named(tmp_path):
    rec = recording("mcap", 20.0, Faults(without=("/ahrs",)))
    for k in range(200):  # an IMU without orientation (REP 145): no attitude source
        t = T0 + k * 100_000_000
        rec.add("/imu/raw", "sensor_msgs/msg/Imu", t, rec.imu(t, (0, 0, 0, 1), no_orientation=True))
    path = rec.write(tmp_path)
    r = info(path)
    line = assert_refused(r, str(path), "no attitude source (no usable AHRS topic: /imu/raw: Imu without orientation")
    assert line.endswith("accept it with --allow-missing ahrs)")
    assert_accepted(info(path, "--allow-missing", "ahrs"))
    with pytest.raises(MissionError, match="no attitude source"):
        check_mission(read_mission(path), allow_missing="dvl").raise_if_refused()


def test_nothing_to_navigate_with_is_two_refusals_in_one_line(tmp_path):
    rec = Recording("sqlite3")
    for k in range(10):
        rec.add("/pressure", "sensor_msgs/msg/FluidPressure", T0 + k * 10**8, rec.pressure(T0 + k * 10**8, 101325.0))
    path = rec.write(tmp_path)
    r = info(path)
    assert_refused(r, "no velocity source", "(and 1 more, listed by semslam info)")
    section = check_section(r.stdout)
    assert [x.split(":")[0] for x in section[:2]] == ["refused", "refused"]
    assert "no attitude source (no AHRS topic)" in section[1]
    assert_accepted(info(path, "--allow-missing", "dvl,ahrs"))


def test_an_unknown_name_to_allow_is_a_one_line_error(tmp_path):
    with pytest.raises(ConfigError, match=r"^--allow-missing: unknown sensor kind 'gps' \(expected dvl, ahrs\)$"):
        parse_allow_missing("dvl, gps")
    assert parse_allow_missing(" dvl , ahrs ") == {"dvl", "ahrs"}
    path = recording("mcap", 5.0).write(tmp_path)
    assert_refused(info(path, "--allow-missing", "sonar"), "--allow-missing: unknown sensor kind 'sonar'")


def _without_dvl(mission: Mission) -> Mission:
    meta = mission.metadata
    sensors = {k: v for k, v in meta.sensors.items() if v.kind != "dvl"}
    stripped = type(meta)(meta.name, sensors, meta.ground_truth, meta.extras, meta.datum)
    return Mission.from_measurements(stripped, [x for x in mission if x.sensor != "dvl"])


def test_the_sidecars_dvl_not_in_the_bag(tmp_path, sample_mission):
    full = write_mission(sample_mission(seconds=3.0), tmp_path / "full.bag")
    cut = write_mission(_without_dvl(sample_mission(seconds=3.0)), tmp_path / "cut.bag")
    shutil.copy(f"{full}.semslam.json", f"{cut}.semslam.json")  # the sidecar still declares the DVL
    r = info(cut)
    assert_refused(r, str(cut), "no velocity source (the sidecar's DVL 'dvl' on /nav/dvl is not in the bag")
    out = assert_accepted(info(cut, "--allow-missing", "dvl"))
    assert "mission sample" in out and " dvl " not in out  # read without it

    # A sidecar sensor whose topic is missing and that is no navigation source: a warning, not read.
    side = json.loads((tmp_path / "full.bag.semslam.json").read_text())
    side["sensors"]["sonar"]["topic"] = "/sonar/old"
    (tmp_path / "full.bag.semslam.json").write_text(json.dumps(side))
    out = assert_accepted(info(full))
    assert "warning: the sidecar's sensor(s) sonar (/sonar/old) not in the bag: not read" in check_section(out)


def test_a_dvl_topic_without_messages(tmp_path, sample_mission):
    m = sample_mission(seconds=2.0)
    empty = Mission.from_measurements(m.metadata, [x for x in m if x.sensor != "dvl"])  # declared, never heard
    path = write_mission(empty, tmp_path / "m.mcap")
    assert_refused(info(path), "no velocity source (the DVL topic /nav/dvl holds no message")


def test_no_sidecar_warns_of_the_identity_mounts_assumed(tmp_path, sample_mission):
    path = write_mission(sample_mission(seconds=2.0), tmp_path / "m_ros2")
    with_sidecar = check_mission(read_mission(path))
    assert with_sidecar.findings == []
    (path / "semslam.json").unlink()
    m = read_mission(path)
    (warning,) = check_mission(m).warnings
    assert warning == (
        f"{path}: no extrinsics for laser/points, nav/dvl, nav/imu, nav/pressure, sonar/swath (no sidecar): "
        "identity mounts assumed (each sensor at the body origin, axes along the body's); give them as "
        "reader.sensors.<name>.T_BS (semslam info --write-config F writes the binding to fill in)"
    )
    out = assert_accepted(info(path))
    assert check_section(out) == [f"warning: {warning.removeprefix(f'{path}: ')}"]
    assert all(np.array_equal(s.T_BS, np.eye(4)) for s in m.metadata.sensors.values())

    # Extrinsics given for some sensors: the others are named.
    T = [[1, 0, 0, 0.3], [0, 1, 0, 0], [0, 0, 1, 0.2], [0, 0, 0, 1]]
    sensors = {
        "dvl": {"topic": "/nav/dvl", "kind": "dvl", "T_BS": T},
        "ahrs": {"topic": "/nav/imu", "kind": "ahrs", "T_BS": np.eye(4).tolist()},
        "depth": {"topic": "/nav/pressure", "kind": "depth"},
    }
    (warning,) = check_mission(read_mission(path, ReaderConfig(sensors=sensors))).warnings
    assert "no extrinsics for depth (no sidecar)" in warning


def test_the_check_reads_no_message(tmp_path):
    """Cheap: it needs only what opening the bag found (the bag itself may be gone by then)."""
    path = recording("mcap", 10.0, Faults(without=("/dvl",))).write(tmp_path)
    m = read_mission(path)
    path.unlink()
    assert len(check_mission(m).refusals) == 1


def test_no_depth_sensor_is_a_warning(tmp_path):
    path = recording("mcap", 10.0, Faults(without=("/pressure",))).write(tmp_path)
    out = assert_accepted(info(path))
    assert "warning: no depth sensor: the vertical position is not measured and drifts" in check_section(out)
