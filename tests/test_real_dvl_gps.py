"""Vendor DVL messages (Water Linked ROS 2 and ROS 1 drivers, UUV Simulator) by their vendors'
semantics, and GPS fixes (NavSatFix, GPSFix) in the local NED frame about the datum."""

from __future__ import annotations

import numpy as np
import pymap3d
import pytest
from real_recordings import Recording, S

from semslam.errors import MissionError
from semslam.mission import Depth, GpsFix, Mission, MissionMetadata, SensorInfo
from semslam.mission.bag import read_mission, sidecar_path, write_mission
from semslam.mission.config import ReaderConfig
from semslam.mission.geodesy import Geodetic

T0 = 1_600_000_000 * S
DATUM = Geodetic(59.33, 18.06, 20.0)
GIVEN = np.array([[4e-6, 1e-7, 0], [1e-7, 5e-6, 0], [0, 0, 9e-6]])


def waterlinked_cases(rec: Recording):
    """(message, expected valid, expected covariance or None, expected altitude)."""
    v = (0.4, -0.1, 0.02)
    cases = [
        (dict(valid=True, cov=GIVEN, fom=0.003), True, GIVEN, 4.0),
        (dict(valid=True, cov=None, fom=0.01), True, np.eye(3) * 1e-4, 4.0),  # no covariance: fom² per axis
        (dict(valid=False, cov=GIVEN), False, None, None),  # no bottom lock
        (dict(valid=True, cov=GIVEN, beams=(True, False, False, True)), False, None, None),  # 2 of 4 beams
        (dict(valid=True, cov=None, fom=0.0), True, np.eye(3) * 0.02**2, 4.0),  # nothing: assumed σ
        (dict(valid=True, cov=GIVEN, fom=0.5), True, GIVEN, 4.0),  # a poor fom, no limit configured
    ]
    if rec.ros1:  # the ROS 1 driver's message has no covariance: fom decides
        cases = [
            (dict(kw, cov=None), ok, None if cov is None else np.eye(3) * kw.get("fom", 0.002) ** 2, alt)
            for kw, ok, cov, alt in cases
        ]
        cases[4] = (dict(valid=True, fom=0.0), True, np.eye(3) * 0.02**2, 4.0)
    return [(rec.waterlinked_dvl(T0 + k * S, v, **kw), ok, cov, alt) for k, (kw, ok, cov, alt) in enumerate(cases)]


@pytest.mark.parametrize("fmt", ["mcap", "sqlite3", "ros1", "humble"])
def test_water_linked_dvl(tmp_path, fmt):
    rec = Recording("sqlite3" if fmt == "humble" else fmt)
    cases = waterlinked_cases(rec)
    msgtype = "waterlinked_a50_ros_driver/msg/DVL" if rec.ros1 else "dvl_msgs/msg/DVL"
    for k, (msg, *_) in enumerate(cases):
        rec.add("/dvl/data", msgtype, T0 + k * S, msg)
    forget = ("dvl_msgs/msg/DVL", "dvl_msgs/msg/DVLBeam") if fmt == "humble" else ()
    path = rec.write(tmp_path, forget_definitions=forget)
    m = read_mission(path)
    out = list(m)
    assert [x.valid for x in out] == [c[1] for c in cases]
    for x, (_, ok, cov, alt) in zip(out, cases):
        np.testing.assert_allclose(x.velocity, (0.4, -0.1, 0.02))
        if ok:
            np.testing.assert_allclose(x.covariance, cov, rtol=1e-12)
        else:
            assert np.isnan(x.covariance).all()
        assert x.altitude == alt
    assert out[3].beam_valid == (True, False, False, True)
    assert m.notes["dvl/data"] == {"covariance unknown: σ 0.02 m/s assumed": 1}
    # A figure-of-merit limit makes the poor reading invalid.
    strict = list(read_mission(path, ReaderConfig(dvl_max_fom_m_s=0.1)))
    assert [x.valid for x in strict] == [True, True, False, False, True, False]


@pytest.mark.parametrize("fmt", ["mcap", "ros1", "humble"])
def test_uuv_simulator_dvl(tmp_path, fmt):
    rec = Recording("sqlite3" if fmt == "humble" else fmt)
    marked = np.full(9, -1.0)
    msgs = [
        rec.uuv_dvl(T0, (0.5, 0, 0), GIVEN),
        rec.uuv_dvl(T0 + S, (0.5, 0, 0), marked),  # invalid: covariance -1
        rec.uuv_dvl(T0 + 2 * S, (0.5, 0, 0), GIVEN, beam_ranges=(4.0, -1.0, -1.0, 4.0)),  # 2 beams
        rec.uuv_dvl(T0 + 3 * S, (0.5, 0, 0), np.zeros(9), altitude=-1.0),  # covariance unknown
    ]
    for k, msg in enumerate(msgs):
        rec.add("/dvl", "uuv_sensor_ros_plugins_msgs/msg/DVL", T0 + k * S, msg)
    forget = ("uuv_sensor_ros_plugins_msgs/msg/DVL", "uuv_sensor_ros_plugins_msgs/msg/DVLBeam")
    m = read_mission(rec.write(tmp_path, forget_definitions=forget if fmt == "humble" else ()))
    out = list(m)
    assert [x.valid for x in out] == [True, False, False, True]
    assert out[2].beam_valid == (True, False, False, True)
    np.testing.assert_allclose(out[0].covariance, GIVEN)
    np.testing.assert_allclose(out[3].covariance, np.eye(3) * 0.02**2)
    assert out[0].altitude == 4.0 and out[3].altitude is None


def offset_fix(north: float, east: float, up: float) -> Geodetic:
    return Geodetic(*pymap3d.ned2geodetic(north, east, -up, DATUM.latitude_deg, DATUM.longitude_deg, DATUM.altitude_m))


@pytest.mark.parametrize("fmt", ["mcap", "sqlite3", "ros1"])
def test_navsatfix_in_ned_about_the_first_fix(tmp_path, fmt):
    rec = Recording(fmt)
    cov_enu = np.array([[1.0, 0.3, 0.0], [0.3, 4.0, 0.0], [0.0, 0.0, 9.0]])
    fixes = [
        (0, rec.navsatfix(T0, DATUM, cov_enu, 3)),  # the datum: the first fix with a position
        (1, rec.navsatfix(T0 + S, offset_fix(30.0, -40.0, 1.5), cov_enu, 3)),
        (2, rec.navsatfix(T0 + 2 * S, None, status=-1)),  # NO_FIX
        (3, rec.navsatfix(T0 + 3 * S, Geodetic(np.nan, 18.0, 0.0), status=0)),  # a fix without a position
        (4, rec.navsatfix(T0 + 4 * S, offset_fix(-5.0, 2.0, 0.0), cov_enu, 2)),  # diagonal known
        (5, rec.navsatfix(T0 + 5 * S, offset_fix(1000.0, 1000.0, 0.0), None, 0)),  # covariance unknown
    ]
    for k, msg in fixes:
        rec.add("/gps/fix", "sensor_msgs/msg/NavSatFix", T0 + k * S, msg)
    m = read_mission(rec.write(tmp_path))
    out = list(m)
    assert all(isinstance(x, GpsFix) for x in out) and [x.stamp for x in out] == [T0, T0 + S, T0 + 4 * S, T0 + 5 * S]
    assert m.metadata.datum == DATUM
    np.testing.assert_allclose(out[0].position, 0.0, atol=1e-9)
    np.testing.assert_allclose(out[1].position, [30.0, -40.0, -1.5], atol=1e-6)
    np.testing.assert_allclose(out[2].position, [-5.0, 2.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(out[3].position, [1000.0, 1000.0, 0.0], atol=1e-6)
    # ENU → NED: north-north is the ENU north variance; the E-N correlation stays; up → down.
    np.testing.assert_allclose(out[1].covariance, [[4.0, 0.3, 0.0], [0.3, 1.0, 0.0], [0.0, 0.0, 9.0]])
    np.testing.assert_allclose(out[2].covariance, np.diag([4.0, 1.0, 9.0]))  # DIAGONAL_KNOWN: no correlation
    np.testing.assert_allclose(out[3].covariance, np.diag([2.5**2, 2.5**2, 5.0**2]))
    assert m.dropped_fields["gps/fix"] == {"status NO_FIX": 1, "position not finite": 1}
    assert m.notes["gps/fix"] == {"covariance unknown: σ 2.5 m horizontal, 5 m vertical assumed": 1}
    # A configured datum wins over the first fix.
    other = Geodetic(59.33, 18.07, 0.0)
    cfg = ReaderConfig(datum={"latitude_deg": 59.33, "longitude_deg": 18.07}, unknown_covariance={"gps_vertical_m": 7})
    m2 = read_mission(m.path, cfg)
    first = next(iter(m2))
    expected = pymap3d.geodetic2ned(59.33, 18.06, 20.0, other.latitude_deg, other.longitude_deg, 0.0)
    np.testing.assert_allclose(first.position, expected, atol=1e-6)
    assert m2.plan.datum.how == "configured"


def test_gpsfix_uncertainties_and_fixes_below_the_surface(tmp_path):
    rec = Recording("mcap")
    rho_g = 1025.0 * 9.80665
    for k in range(6):
        t = T0 + k * S
        depth = [0.0, 0.1, 2.0, 2.0, 0.3, 0.0][k]
        rec.add(
            "/pressure", "sensor_msgs/msg/FluidPressure", t - S // 10, rec.pressure(t - S // 10, 101325 + rho_g * depth)
        )
        rec.add("/gps_umd", "gps_msgs/msg/GPSFix", t, rec.gpsfix(t, offset_fix(k, 0, 0), err_horz=4.896, err_vert=3.92))
    m = read_mission(rec.write(tmp_path), ReaderConfig(atmospheric_pressure_pa=101325))
    fixes = [x for x in m if isinstance(x, GpsFix)]
    assert [round(f.position[0]) for f in fixes] == [0, 1, 4, 5]  # 2 and 3 taken 2 m deep
    assert m.dropped_fields["gps_umd"] == {"taken below 0.5 m depth": 2}
    np.testing.assert_allclose(np.sqrt(np.diag(fixes[0].covariance)), [2.0, 2.0, 2.0], rtol=1e-3)
    assert m.notes["gps_umd"] == {"covariance unknown: σ from err_horz/err_vert (95 %)": 4}
    assert len([x for x in m if isinstance(x, Depth)]) == 6


@pytest.mark.parametrize("name", ["g.bag", "g_ros2", "g.mcap"])
def test_gps_fixes_written_as_navsatfix_read_back_with_the_datum(tmp_path, name):
    cov = np.array([[1.0, 0.2, 0.0], [0.2, 2.0, 0.0], [0.0, 0.0, 5.0]])
    fixes = [GpsFix(T0 + k * S, "gps", position=(3.0 * k, -2.0 * k, -0.2), covariance=cov) for k in range(5)]
    meta = MissionMetadata(name="gps", sensors={"gps": SensorInfo("gps", "gps", topic="/gps/fix")}, datum=DATUM)
    path = write_mission(Mission.from_measurements(meta, fixes), tmp_path / name)
    assert '"latitude_deg": 59.33' in sidecar_path(path).read_text()
    back = read_mission(path)
    assert back.metadata.datum == DATUM and back.plan.datum.how == "from the mission's sidecar"
    got = list(back)
    assert [x.stamp for x in got] == [x.stamp for x in fixes]
    for a, b in zip(fixes, got):
        np.testing.assert_allclose(b.position, a.position, atol=1e-8)
        np.testing.assert_allclose(b.covariance, a.covariance, rtol=1e-12)
    no_datum = MissionMetadata(name="gps", sensors=meta.sensors)
    with pytest.raises(
        MissionError, match="sensor 'gps' at t=1600000000.000000 s: a GPS fix needs the mission's datum"
    ):
        write_mission(Mission.from_measurements(no_datum, fixes), tmp_path / ("again_" + name))
