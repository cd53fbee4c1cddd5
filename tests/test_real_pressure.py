"""reader.atmospheric_pressure_pa: auto — depth within 2 cm (median) of the truth at any surface
pressure of 80–105 kPa and water density of 997–1028 kg/m³, found from the surface periods."""

from __future__ import annotations

import numpy as np
import pytest
from real_recordings import Recording, S
from typer.testing import CliRunner

from semslam.cli import app
from semslam.mission import Depth
from semslam.mission.bag import read_mission
from semslam.mission.config import ReaderConfig
from semslam.mission.geodesy import Geodetic

T0 = 1_600_000_000 * S
G = 9.80665
RATE = 8.0  # Hz, as the tank's pressure sensor


def descent(t: np.ndarray) -> np.ndarray:
    """At the surface for 15 s (waves: ±3 cm), then down at 0.25 m/s to 6 m and along."""
    return np.where(t < 15.0, 0.03 * np.sin(2 * np.pi * t / 4.0), np.minimum(6.0, 0.25 * (t - 15.0)))


def ascent(t: np.ndarray) -> np.ndarray:
    """Starts 2 m deep (the recording began after the dive), up at 0.2 m/s from 30 s, at the surface at 40 s."""
    return np.where(t < 30.0, 2.0, np.maximum(0.03 * np.sin(2 * np.pi * t / 4.0), 2.0 - 0.2 * (t - 30.0)))


def pressure_bag(tmp_path, p_atm: float, rho: float, profile, seconds: float, gps: bool, seed: int = 0):
    rng = np.random.default_rng(seed)
    rec = Recording("sqlite3")
    t = np.arange(0.0, seconds, 1.0 / RATE)
    depth = profile(t)
    stamps = [T0 + int(round(ti * 1e9)) for ti in t]
    for stamp, d in zip(stamps, depth):
        pa = p_atm + rho * G * (d + rng.normal(0.0, 0.01))  # 1 cm of sensor noise
        rec.add("/depth", "sensor_msgs/msg/FluidPressure", stamp, rec.pressure(stamp, pa))
    if gps:
        for ti in np.arange(0.0, seconds, 1.0):
            stamp = T0 + int(ti * 1e9)
            at_surface = profile(np.array([ti]))[0] < 0.1
            where = Geodetic(43.0, 5.0, 0.0) if at_surface else None
            rec.add(
                "/gps", "sensor_msgs/msg/NavSatFix", stamp, rec.navsatfix(stamp, where, status=0 if at_surface else -1)
            )
    return rec.write(tmp_path), dict(zip(stamps, depth))


@pytest.mark.parametrize("p_atm", [80_000.0, 92_500.0, 105_000.0])
@pytest.mark.parametrize("rho", [997.0, 1028.0])
@pytest.mark.parametrize("surface", ["first seconds", "gps"])
def test_depth_within_2cm_of_truth_with_auto_surface_pressure(tmp_path, p_atm, rho, surface):
    profile = descent if surface == "first seconds" else ascent
    path, truth = pressure_bag(tmp_path, p_atm, rho, profile, 60.0, gps=surface == "gps")
    m = read_mission(path, ReaderConfig(water_density_kg_m3=rho))
    depths = [x for x in m if isinstance(x, Depth)]
    assert len(depths) == 480
    err = np.array([x.depth - truth[x.stamp] for x in depths])
    assert abs(np.median(err)) <= 0.02, (np.median(err), m.plan.atmosphere)
    found = m.plan.atmosphere
    assert abs(found.value - p_atm) <= 0.02 * rho * G
    assert ("while the GPS had a fix" if surface == "gps" else "before the depth rose") in found.how


def test_numeric_surface_pressure_and_what_info_says(tmp_path):
    path, truth = pressure_bag(tmp_path, 90_000.0, 1000.0, descent, 30.0, gps=False)
    m = read_mission(path, ReaderConfig(atmospheric_pressure_pa=90_000.0, water_density_kg_m3=1000.0))
    assert m.plan.atmosphere.value == 90_000.0 and m.plan.atmosphere.how == "configured"
    r = CliRunner().invoke(app, ["info", str(path), "--allow-missing", "dvl,ahrs"])
    assert r.exit_code == 0, r.output
    assert "atmospheric pressure: 900" in r.stdout and "(auto: median of " in r.stdout
    assert "pressure readings of the first 1" in r.stdout and "s, before the depth rose)" in r.stdout


def test_a_recording_starting_under_water_without_gps_warns_and_assumes_the_standard_atmosphere(tmp_path):
    path, _ = pressure_bag(tmp_path, 101_325.0, 1025.0, lambda t: 12.0 + 0.0 * t, 20.0, gps=False)
    m = read_mission(path)
    assert m.plan.atmosphere.value == 101_325.0
    assert "not an atmospheric pressure (did the recording start under water?)" in m.plan.atmosphere.warning
    r = CliRunner().invoke(app, ["info", str(path)])
    assert "warnings:\n  atmosphere: " in r.stdout
