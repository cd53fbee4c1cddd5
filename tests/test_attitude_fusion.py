"""The AHRS readings between keyframes fused into one attitude (semslam.backend.navigation)."""

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.backend.navigation import AttitudeSample, NavigationBuffer
from semslam.mission.measurements import Attitude
from semslam.mission.mission import MissionMetadata, SensorInfo

SIG = np.deg2rad([0.1, 0.1, 0.5])  # the tank's AHRS: roll, pitch, heading σ per reading
AHRS_ONLY = MissionMetadata(sensors={"ahrs": SensorInfo("ahrs", "ahrs")})  # mounted with the body's axes


def _readings(rng, n, rate_z=0.0, hz=20.0, rate_sigma=0.01):
    """n readings of a vehicle turning at rate_z about its vertical: attitude with white noise of
    σ SIG, rate with white noise of σ rate_sigma (rad/s)."""
    out, truth = [], []
    phi, theta = -0.01, 0.02
    omega_B = rate_z * np.array([-np.sin(theta), np.sin(phi) * np.cos(theta), np.cos(phi) * np.cos(theta)])
    for i in range(n):
        t = i / hz
        R = Rotation.from_euler("ZYX", [0.3 + rate_z * t, theta, phi])
        noisy = R * Rotation.from_rotvec(rng.normal(0, SIG))
        out.append(
            Attitude(
                stamp=int(t * 1e9),
                sensor="ahrs",
                orientation=noisy.as_quat(),
                covariance=np.diag(SIG**2),
                angular_rate=omega_B + rng.normal(0, rate_sigma, 3),
            )
        )
        truth.append(R)
    return out, truth


def _fused_errors(rate_z, runs=200, n=20, rate_sigma=0.01, hz=20.0):
    rng = np.random.default_rng(1)
    errs, covs = [], []
    for _ in range(runs):
        # the buffer takes the gyro's density: a reading's σ over √rate (as the config derives it from a mission)
        nav = NavigationBuffer(AHRS_ONLY, accel_sigma=0.05, rate_sigma=rate_sigma / np.sqrt(hz))
        readings, truth = _readings(rng, n, rate_z, hz=hz, rate_sigma=rate_sigma)
        for m in readings:
            nav.add(m)
        t = readings[-1].stamp * 1e-9
        R, cov, k = nav.take_fused_attitude(t)
        assert k == n and nav.take_fused_attitude(t) is None  # each reading is used once
        errs.append((truth[-1].inv() * Rotation.from_matrix(R)).as_rotvec())
        covs.append(cov)
    return np.array(errs), np.mean(covs, axis=0)


def test_fused_attitude_averages_the_readings_and_says_so():
    errs, cov = _fused_errors(rate_z=0.2)
    # heading σ of 20 readings fused: well below one reading's 0.5°, and the covariance agrees
    sd = errs.std(axis=0)
    assert sd[2] < 0.5 * SIG[2]
    np.testing.assert_allclose(sd, np.sqrt(np.diag(cov)), rtol=0.25)
    assert np.all(np.abs(errs.mean(axis=0)) < 3 * sd / np.sqrt(len(errs)))  # unbiased while turning


def test_carried_covariance_grows_by_the_density_over_the_time():
    # white rate noise of density q (rad/s/√Hz) integrated over Δt has variance q²·Δt per axis: carried
    # over k AHRS periods the attitude's covariance has grown by k·q²·period, whether carried at once or
    # reading by reading (variances of independent periods add)
    q, period, k = 0.002, 0.05, 10
    cov0 = np.diag(SIG**2)
    s = AttitudeSample(0.0, np.eye(3), cov0, np.array([0.0, 0.0, 0.1]))
    _, once = s.carried_to(k * period, q)
    np.testing.assert_allclose(once - cov0, np.eye(3) * k * q**2 * period, rtol=1e-12, atol=1e-18)
    for i in range(1, k + 1):
        R, cov = s.carried_to(i * period, q)
        s = AttitudeSample(i * period, R, cov, s.omega_B)
    np.testing.assert_allclose(s.cov, once, rtol=1e-12, atol=1e-18)
    # and through the buffer: one reading, then the attitude k periods later
    nav = NavigationBuffer(AHRS_ONLY, accel_sigma=0.05, rate_sigma=q)
    nav.add(
        Attitude(stamp=0, sensor="ahrs", orientation=[0.0, 0.0, 0.0, 1.0], covariance=cov0, angular_rate=[0, 0, 0.1])
    )
    _, cov = nav.attitude_at(k * period)
    np.testing.assert_allclose(cov - cov0, np.eye(3) * k * q**2 * period, rtol=1e-9, atol=1e-18)
