"""Faulty recordings, made by the tests: a vehicle's navigation topics (AHRS 20 Hz, pressure 8 Hz,
DVL 5 Hz, a laser at 1 Hz) with a topic left out, a clock reset, repeated stamps, NaN readings or finite nonsense."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from real_recordings import Recording, S

T0 = 1_700_000_000 * S
LATENCY = 3_000_000  # every message is received 3 ms after its stamp
RATES = {"/ahrs": 20.0, "/pressure": 8.0, "/dvl": 5.0, "/laser": 1.0}
TYPES = {
    "/ahrs": "sensor_msgs/msg/Imu",
    "/pressure": "sensor_msgs/msg/FluidPressure",
    "/dvl": "geometry_msgs/msg/TwistWithCovarianceStamped",
    "/laser": "sensor_msgs/msg/PointCloud2",
}


@dataclass(frozen=True)
class Faults:
    without: tuple[str, ...] = ()  # topics left out
    reset_at_s: float | None = None  # a clock reset at this mission time ...
    back_s: float = 30.0  # ... sending the header stamps this far back
    recorder_too: bool = False  # ... and the recorder's clock with them (one computer, one clock)
    reset_only: tuple[str, ...] = ()  # the reset hits only these topics (a sensor's own clock); () = all
    nan_dvl_at: tuple[int, ...] = ()  # DVL readings (by index) with a NaN velocity
    huge_dvl_at: tuple[int, ...] = ()  # DVL readings (by index) of 1e188 m/s, finite, with a sane covariance
    huge_pressure_at: tuple[int, ...] = ()  # pressure readings (by index) of 1e12 Pa: ~1e8 m deep
    repeat_dvl_at: tuple[int, ...] = ()  # DVL readings (by index) stamped like the one before, different data
    wild_dvl_at: tuple[int, ...] = ()  # DVL readings (by index) stamped 100 s in the past, alone
    ahrs_zero_stamps: bool = False  # an AHRS driver that leaves header stamps at zero (read by receive time)
    duplicate_dvl_at: tuple[int, ...] = ()  # DVL readings (by index) recorded twice, byte for byte


def recording(fmt: str, seconds: float = 60.0, faults: Faults = Faults()) -> Recording:
    """The recording; messages are stamped by the vehicle's clock and received LATENCY later."""
    rec = Recording(fmt)
    rng = np.random.default_rng(0)
    f = faults
    for topic, rate in RATES.items():
        if topic in f.without:
            continue
        times = np.arange(0.0, seconds, 1.0 / rate)
        for k, t in enumerate(times):
            stamp = T0 + int(round(t * S))
            receive = stamp + LATENCY
            if f.reset_at_s is not None and t >= f.reset_at_s and (not f.reset_only or topic in f.reset_only):
                stamp -= int(f.back_s * S)
                if f.recorder_too:
                    receive -= int(f.back_s * S)
            if topic == "/dvl" and k in f.repeat_dvl_at:
                stamp = T0 + int(round(times[k - 1] * S))
            if topic == "/dvl" and k in f.wild_dvl_at:
                stamp -= 100 * S
            if topic == "/ahrs" and f.ahrs_zero_stamps:
                stamp = 0
            msg = _message(rec, topic, stamp, t, rng, nan=topic == "/dvl" and k in f.nan_dvl_at)
            if topic == "/dvl" and k in f.huge_dvl_at:
                msg = rec.twist(stamp, (1e188, 0.0, 0.0))
            if topic == "/pressure" and k in f.huge_pressure_at:
                msg = rec.pressure(stamp, 1e12)
            rec.add(topic, TYPES[topic], receive, msg)
            if topic == "/dvl" and k in f.duplicate_dvl_at:
                rec.add(topic, TYPES[topic], receive + 1_000_000, msg)
    return rec


def _message(rec: Recording, topic: str, stamp: int, t: float, rng, nan: bool):
    if topic == "/ahrs":
        yaw = 0.01 * t
        return rec.imu(stamp, (0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)), np.diag([1e-4] * 3))
    if topic == "/pressure":
        return rec.pressure(stamp, 101325.0 + 1025 * 9.80665 * max(0.0, 0.1 * (t - 5.0)))  # dives after 5 s
    if topic == "/dvl":
        v = (np.nan, 0.0, 0.0) if nan else (0.5 + 0.01 * rng.standard_normal(), 0.0, 0.0)
        return rec.twist(stamp, v)
    points = rng.normal(size=(50, 3)).astype(np.float32) + np.float32(3.0)
    return rec.pointcloud2(stamp, points)
