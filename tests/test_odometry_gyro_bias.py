"""The odometry front-end's estimate of the gyro's bias (from the AHRS's attitude against its rates
integrated) and the held rotation turned by it (issue 23, stop 47)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from frontends.odometry.frontend import OdometryFrontend
from frontends.odometry.prior import GyroBias, NavigationPrior
from semslam.mission.measurements import Attitude, GroundTruthPose, PointCloud
from semslam.mission.mission import MissionMetadata, SensorInfo

S = 1_000_000_000
META = MissionMetadata(sensors={"ahrs": SensorInfo("ahrs", "ahrs")})


def test_the_estimated_bias_is_the_simulated_constant_bias_within_what_the_noise_allows():
    """300 s of a vehicle turning and wobbling, AHRS attitudes at 20 Hz (0.1° roll/pitch, 0.5° heading, no
    heading drift) and rates with σ_ω = 2 mrad/s plus a constant bias. The rates' white noise integrates to a
    random walk of the attitude (σ_ω²·dt per second) that no attitude reading can tell from the bias's
    mean: the best any estimator does is σ_b² = 1/(1/σ_prior² + T/(σ_ω²·dt)) per axis (the readings' own
    noise, averaged over 6000 of them, adds less than 1 % to it). The filter says that σ and hits the bias
    within 3 of it on every axis."""
    rng = np.random.default_rng(4)
    sigma_w, dt, T, prior = 0.002, 0.05, 300.0, 3e-4
    bias = np.array([2.5e-4, -3e-4, 2e-4])
    s_rp, s_h = np.radians(0.1), np.radians(0.5)

    def true_R(t):
        return Rotation.from_euler(
            "ZYX", [0.03 * t + 0.5 * np.sin(t / 40), 0.03 * np.sin(t / 7.3), 0.02 * np.cos(t / 5)]
        )

    estimator = GyroBias(prior, 0.0, walk_b=0.0, walk_rho=0.0)
    p = NavigationPrior(META, horizon_s=10.0, gyro_sigma_rad_s=sigma_w, gyro_bias=estimator)
    cov = np.diag([s_rp**2, s_rp**2, s_h**2])
    for k in range(int(T / dt) + 1):
        t = k * dt
        noisy = Rotation.from_euler("ZYX", true_R(t).as_euler("ZYX") + rng.normal(0.0, [s_h, s_rp, s_rp]))
        rate = (true_R(t - 1e-4).inv() * true_R(t + 1e-4)).as_rotvec() / 2e-4 + bias + rng.normal(0.0, sigma_w, 3)
        p.add(Attitude(int(t * S), "ahrs", orientation=noisy.as_quat(), covariance=cov, angular_rate=rate))
    best = (1 / prior**2 + T / (sigma_w**2 * dt)) ** -0.5  # 2.5e-5 rad/s
    said = np.sqrt(np.diag(estimator.covariance))
    assert said == pytest.approx(np.full(3, best), rel=0.1)
    assert np.all(np.abs(estimator.bias - bias) < 3 * best), (estimator.bias, bias, best)


def test_a_heading_that_drifts_like_the_bias_leaves_the_vertical_axis_to_the_prior():
    """The AHRS's heading bias drifting at a rate ρ moves the heading exactly as a gyro bias about the
    vertical does: with ρ's prior as wide as the bias's, the filter must not claim the vertical axis (its σ
    stays near the prior's) while it still learns the horizontal ones."""
    rng = np.random.default_rng(5)
    sigma_w, dt, T, prior = 0.002, 0.05, 300.0, 3e-4
    estimator = GyroBias(prior, 1e-3, walk_b=0.0, walk_rho=0.0)
    p = NavigationPrior(META, horizon_s=10.0, gyro_sigma_rad_s=sigma_w, gyro_bias=estimator)
    cov = np.diag([1e-6, 1e-6, 1e-4])
    for k in range(int(T / dt) + 1):
        t = k * dt
        R = Rotation.from_euler("ZYX", [0.03 * t, 0.0, 0.0])
        noisy = Rotation.from_euler("ZYX", R.as_euler("ZYX") + rng.normal(0.0, [1e-2, 1e-3, 1e-3]))
        rate = np.array([0.0, 0.0, 0.03]) + rng.normal(0.0, sigma_w, 3)
        p.add(Attitude(int(t * S), "ahrs", orientation=noisy.as_quat(), covariance=cov, angular_rate=rate))
    said = np.sqrt(np.diag(estimator.covariance))
    assert said[2] > 0.9 * prior
    assert np.all(said[:2] < 0.2 * prior)


@pytest.fixture(scope="module")
def biased_mission():
    from semslam.sim.config import TankSimConfig
    from semslam.sim.simulate import simulate_tank

    cfg = {
        "seed": 11,
        "trajectory": {"loops": 0.5},
        "ahrs": {"gyro_bias_sigma_rad_s": 5e-4, "heading_bias_drift_deg": 0},
    }
    return simulate_tank(TankSimConfig.model_validate(cfg))


def _rotation_errors(mission, frontend: OdometryFrontend, from_s: float, span_s: float = 2.0) -> np.ndarray:
    """The prior's rotation error (rad, body frame at the interval's end) over every ``span_s`` interval
    ending after ``from_s``, each asked for when its last reading has come (as a scan would)."""
    truth, errors = {}, []
    t0 = next(iter(mission)).stamp
    pending = int(t0 + (from_s + span_s) * S)
    for m in mission:
        if isinstance(m, GroundTruthPose):
            truth[m.stamp] = Rotation.from_quat(m.orientation)
            continue
        if isinstance(m, PointCloud):  # the prior alone: no registrations
            continue
        if m.stamp >= pending and truth:
            a, b = pending - int(span_s * S), pending
            stamps = np.array(sorted(truth))
            ta, tb = stamps[np.abs(stamps - a).argmin()], stamps[np.abs(stamps - b).argmin()]
            relative = (truth[ta].inv() * truth[tb]).as_matrix()
            errors.append(Rotation.from_matrix(relative.T @ frontend.prior.motion(ta, tb)[:3, :3]).as_rotvec())
            pending += int(span_s * S)
        frontend.process(m)
    return np.array(errors)


def test_the_held_rotation_over_a_scan_interval_is_unbiased_on_a_mission_with_a_gyro_bias(biased_mission):
    """A tank mission whose gyro has a bias of ~5e-4 rad/s per axis (1e-3 rad per 2 s scan interval against
    the interval's own σ of 6e-4 from the rates' white noise) and whose AHRS heading does not drift: over the
    mission's second half the prior's rotation between scans is unbiased (mean error within 3 σ of the mean
    of independent intervals plus the bias estimate's own σ over 2 s); the raw rates (``estimate: false``) are
    off by the bias times the interval."""
    bias = biased_mission.metadata.extras["noise"]["ahrs"]
    assert bias["gyro_bias_sigma_rad_s"] == 5e-4
    stamps = [m.stamp for m in biased_mission]
    half = 0.5 * (max(stamps) - min(stamps)) / S
    fe = OdometryFrontend(biased_mission.metadata, {"gyro_bias": {"estimate": True}})
    errors = _rotation_errors(biased_mission, fe, half)
    raw = _rotation_errors(
        biased_mission, OdometryFrontend(biased_mission.metadata, {"gyro_bias": {"estimate": False}}), half
    )
    per_interval = np.sqrt(fe.prior.gyro_variance() * 0.05 * 2.0)
    tolerance = 3 * (per_interval / np.sqrt(len(errors)) + 2.0 * np.sqrt(np.diag(fe.prior.gyro_bias.covariance)))
    assert np.all(np.abs(errors.mean(axis=0)) < tolerance), (errors.mean(axis=0), tolerance)
    assert np.any(np.abs(raw.mean(axis=0)) > 2 * tolerance)
