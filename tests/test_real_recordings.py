"""Real AUV recordings as they are (issue 19): the all-traits acceptance bag through `semslam info`
and `semslam compare` with no configuration, in ROS 2 MCAP, ROS 2 sqlite3 and ROS 1; the choice of
one topic per sensor kind and `--write-config`; topics nobody needs never stop a read."""

from __future__ import annotations

import json

import numpy as np
import pytest
from real_recordings import FORMATS, HOUSEKEEPING, Dive, Recording, S, all_traits
from typer.testing import CliRunner

from semslam.cli import app
from semslam.config import load_config
from semslam.mission import Attitude, DvlVelocity, GpsFix, GroundTruthPose
from semslam.mission.bag import read_mission
from semslam.mission.config import ReaderConfig

runner = CliRunner()
DIVE = Dive(seconds=40.0, surface_s=8.0)
SURFACE_FIXES = sum(DIVE.at_surface(t) for t in range(40))  # 1 Hz fixes at the surface: 17 of 40
CHOSEN = {"ahrs/data": "/ahrs/data", "dvl/data": "/dvl/data", "gps/fix": "/gps/fix", "pressure": "/pressure"}


@pytest.fixture(scope="module", params=FORMATS)
def acceptance_bag(request, tmp_path_factory):
    return all_traits(request.param, DIVE).write(tmp_path_factory.mktemp(request.param))


def test_info_with_no_config_shows_the_binding_and_the_unread_topics(acceptance_bag):
    r = runner.invoke(app, ["info", str(acceptance_bag)])
    assert r.exit_code == 0, r.output
    out = r.stdout
    for sensor, topic in CHOSEN.items():
        assert f"  {topic} → {sensor} (" in out and "chosen by the rule" in out
    assert "ahrs/data: receive time + offset (auto: header stamps are all zero)" in out
    assert "(-3.00 days)" in out  # the recorder's clock, days away from the vehicle's
    unread = out.split("unread topics (never read nor checked):")[1]
    for topic in HOUSEKEEPING:
        assert f"  {topic} " in unread, topic
    assert "/housing/pressure" in unread and "its name says it is not the vehicle's sensor" in unread
    assert "/dvl/twist" in unread and "a plainer message type" in unread
    assert "/imu/data_raw" in unread and "a raw IMU, not an AHRS" in unread
    assert "/odometry/filtered" in unread and "the vehicle's own navigation, not ground truth" in unread
    assert "ground truth: none" in out
    no_fix = 40 - SURFACE_FIXES
    assert f"gps/fix: {no_fix} message(s) dropped (non-finite or unusable field: status NO_FIX ×{no_fix})" in out
    assert "atmospheric pressure: 101" in out and "while the GPS had a fix" in out


def test_acceptance_bag_reads_as_a_real_mission(acceptance_bag):
    m = read_mission(acceptance_bag)
    assert m.metadata.ground_truth is None and not m.metadata.sensors_of_kind("ground_truth")
    assert {s: i.topic for s, i in m.metadata.sensors.items()} == CHOSEN
    got: dict[str, list] = {}
    for x in m:
        got.setdefault(type(x).__name__, []).append(x)
    assert not any(isinstance(x, GroundTruthPose) for v in got.values() for x in v)
    assert len(got["Attitude"]) == 800 and len(got["Depth"]) == 400
    fixes = got["GpsFix"]
    assert len(fixes) == SURFACE_FIXES
    # The AHRS, stamped by receive time mapped onto the vehicle clock, within the recorder's latency.
    t_ahrs = np.array([a.stamp for a in got["Attitude"]]) - DIVE.t0_vehicle
    np.testing.assert_allclose(t_ahrs, np.arange(0, 40, 0.05) * 1e9, atol=20e6)
    # Fixes in the local NED frame about the first one (the antenna 0.3 m above the sea).
    for f in fixes:
        t = (f.stamp - DIVE.t0_vehicle) * 1e-9
        np.testing.assert_allclose(f.position, DIVE.position(t)[:2].tolist() + [0.0], atol=1e-6)
    dvl = got["DvlVelocity"]
    locked = sum(DIVE.depth(t) > 0.5 for t in np.arange(0, 40, 0.2))  # no bottom lock near the surface
    assert len(dvl) == 200 and sum(d.valid for d in dvl) == locked == 103
    assert m.metadata.datum is not None


@pytest.mark.parametrize("fmt", FORMATS)
def test_compare_with_no_config_runs_dr_ekf_and_graph(tmp_path, fmt):
    path = all_traits(fmt, Dive(seconds=24.0, surface_s=4.0)).write(tmp_path)
    r = runner.invoke(app, ["compare", str(path), "--out", str(tmp_path / "out")])
    assert r.exit_code == 0, r.output
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    for est in ("dr", "ekf", "graph"):
        e = metrics["estimators"][est]
        assert e["ate_rmse_m"] is None  # no ground truth: nothing invented
        rows = (tmp_path / "out" / f"trajectory_{est}.tum").read_text().splitlines()[1:]
        assert len(rows) > 10
        last = np.array(rows[-1].split()[1:4], float)
        assert np.isfinite(last).all() and 3.0 < np.hypot(*last[:2]) < 20.0  # ~ 12 m at 0.5 m/s, unaided
    assert metrics["mission"]["gt_objects"] in (None, 0)


def test_write_config_lists_every_candidate_and_reads_back(tmp_path):
    path = all_traits("mcap", DIVE).write(tmp_path)
    cfg_path = tmp_path / "binding.yaml"
    r = runner.invoke(app, ["info", str(path), "--write-config", str(cfg_path)])
    assert r.exit_code == 0, r.output
    text = cfg_path.read_text()
    for topic in ("/dvl/twist", "/housing/pressure", "/imu/data_raw", "/odometry/filtered"):
        assert f"#      topic: {topic}" in text  # a candidate, commented out
    assert "#   /battery (sensor_msgs/BatteryState): no sensor kind reads this message type" in text
    cfg = load_config(cfg_path)
    assert {n: (b.topic, b.kind) for n, b in cfg.reader.sensors.items()} == {
        "ahrs/data": ("/ahrs/data", "ahrs"),
        "dvl/data": ("/dvl/data", "dvl"),
        "gps/fix": ("/gps/fix", "gps"),
        "pressure": ("/pressure", "depth"),
    }
    again = read_mission(path, cfg.reader)
    assert {s: i.topic for s, i in again.metadata.sensors.items()} == CHOSEN
    # Swap the DVL for its twist and take the vehicle's odometry as ground truth: uncomment, comment out.
    for name in ("dvl/data", "dvl/twist", "odometry/filtered"):
        text = toggle(text, name)
    (tmp_path / "swapped.yaml").write_text(text)
    m = read_mission(path, load_config(tmp_path / "swapped.yaml").reader)
    assert m.metadata.sensors["dvl/twist"].topic == "/dvl/twist" and "dvl/data" not in m.metadata.sensors
    assert m.metadata.sensors["odometry/filtered"].kind == "ground_truth"
    kinds = {type(x) for x in m}
    assert GroundTruthPose in kinds and DvlVelocity in kinds


def toggle(text: str, sensor: str) -> str:
    """Comment out the YAML block of ``sensor`` in reader.sensors, or uncomment it."""
    lines = text.splitlines()
    i = next(k for k, line in enumerate(lines) if line.lstrip("#").startswith(f"    {sensor}:"))
    j = i + 1
    while j < len(lines) and lines[j].lstrip("#").startswith("      "):
        j += 1
    commented = lines[i].startswith("#")
    lines[i:j] = [line[1:] if commented else "#" + line for line in lines[i:j]]
    return "\n".join(lines) + "\n"


def test_topics_nobody_needs_never_stop_a_read(tmp_path):
    """A corrupt message on an unread topic, a type with no definition at all (a Humble-era sqlite3
    bag), and the vendor DVL read with the shipped definition."""
    rec = all_traits("sqlite3", Dive(seconds=12.0, surface_s=4.0))
    for k in range(3):
        rec.add_raw("/modem/garbage", "acme_msgs/msg/ModemRaw", DIVE.t0_vehicle + DIVE.receive_offset + k * S, b"\x01")
    path = rec.write(
        tmp_path, forget_definitions=("acme_msgs/msg/ModemRaw", "dvl_msgs/msg/DVL", "dvl_msgs/msg/DVLBeam")
    )
    m = read_mission(path)
    assert len([x for x in m if isinstance(x, DvlVelocity)]) == 60
    reasons = {u.topic: u.reason for u in m.plan.binding.unread}
    assert (
        reasons["/modem/raw"]
        == reasons["/modem/garbage"]
        == "unknown message type (no definition in the bag or shipped)"
    )
    # The same bag with the modem bound: now its garbage is read, and the error names file, topic, stamp.
    cfg = ReaderConfig(sensors={"modem": {"topic": "/modem/raw", "kind": "dvl"}})
    r = runner.invoke(app, ["info", str(path), "--config", str(_yaml(tmp_path, cfg))])
    assert r.exit_code == 1 and len(r.stderr.strip().splitlines()) == 1
    assert f"{path}: topic /modem/raw: message type acme_msgs/ModemRaw is not supported" in r.stderr


def test_a_corrupt_message_on_a_bound_topic_is_one_line_naming_file_topic_and_stamp(tmp_path):
    rec = all_traits("ros1", Dive(seconds=6.0, surface_s=2.0))
    t_bad = DIVE.t0_vehicle + DIVE.receive_offset + 3 * S
    rec.add_raw("/pressure", "sensor_msgs/msg/FluidPressure", t_bad, b"\x00" * 7)
    path = rec.write(tmp_path)
    r = runner.invoke(app, ["info", str(path)])
    assert r.exit_code == 1, r.output
    (line,) = r.stderr.strip().splitlines()
    assert (
        f"{path}: topic /pressure: message at t={t_bad * 1e-9:.6f} s cannot be decoded as sensor_msgs/FluidPressure"
        in line
    )


def test_choice_rule_prefers_name_then_type_then_rate(tmp_path):
    rec = Recording("mcap")
    t0 = 1_600_000_000 * S
    q, cov = (0, 0, 0, 1), np.diag([1e-4] * 3)
    for k in range(40):
        t = t0 + k * S // 20
        rec.add("/imu/raw", "sensor_msgs/msg/Imu", t, rec.imu(t, q, cov))  # has an orientation, but "raw"
        rec.add("/ahrs_fast", "sensor_msgs/msg/Imu", t, rec.imu(t, q, cov))
        if k % 2 == 0:
            rec.add("/ahrs_slow", "sensor_msgs/msg/Imu", t, rec.imu(t, q, cov))
            rec.add("/gps", "sensor_msgs/msg/NavSatFix", t, rec.navsatfix(t, DIVE.datum))
            rec.add("/gps_umd", "gps_msgs/msg/GPSFix", t, rec.gpsfix(t, DIVE.datum))
    m = read_mission(rec.write(tmp_path))
    assert {s: i.topic for s, i in m.metadata.sensors.items()} == {"ahrs_fast": "/ahrs_fast", "gps": "/gps"}
    reasons = {u.topic: u.reason for u in m.plan.binding.unread}
    assert reasons == {
        "/ahrs_slow": "alternative ahrs (chosen: /ahrs_fast; this one: fewer messages)",
        "/imu/raw": "alternative ahrs (chosen: /ahrs_fast; this one: its name says it is not the vehicle's sensor)",
        "/gps_umd": "alternative gps (chosen: /gps; this one: a plainer message type)",
    }
    assert all(isinstance(x, (Attitude, GpsFix)) for x in m)


def _yaml(tmp_path, cfg: ReaderConfig):
    import yaml

    p = tmp_path / "cfg.yaml"
    p.write_text(yaml.safe_dump({"reader": cfg.model_dump(mode="json", exclude_defaults=True)}))
    return p
