"""The graph links consecutive keyframes' attitudes by the body rates integrated between them (issue 21/23,
stop 42), as the EKF's prediction does between its AHRS updates; the gyro's noise density is the mission's
declared one, shared by every estimator."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from factors.geometry import so3_exp
from semslam.backend.graph import GraphEstimator
from semslam.backend.navigation import NavigationBuffer
from semslam.compare import estimators_input
from semslam.config import SemslamConfig
from semslam.mission.measurements import Attitude, DvlVelocity, GroundTruthPose
from semslam.mission.mission import Mission, MissionMetadata, SensorInfo
from semslam.pipeline import run_pipeline
from tests.support.replay import Replay

S = 1_000_000_000
DURATION = 40
HEADING_SIGMA = np.radians(0.5)
RATE_SIGMA = 0.002  # per reading, at 20 Hz


def yaw_true(t):
    return 0.4 * np.sin(0.15 * t)


def rate_true(t):
    return 0.06 * np.cos(0.15 * t)


def metadata() -> MissionMetadata:
    sensors = {
        n: SensorInfo(n, kind, f"/{n}", "x", np.eye(4))
        for n, kind in (("ahrs", "ahrs"), ("dvl", "dvl"), ("gt", "ground_truth"))
    }
    noise = {"ahrs": {"angular_rate_sigma_rad_s": RATE_SIGMA, "rate_hz": 20.0}}
    return MissionMetadata(name="yawing", sensors=sensors, extras={"noise": noise})


def quat(yaw: float) -> np.ndarray:
    return Rotation.from_euler("z", yaw).as_quat()


def yawing(seed: int) -> Mission:
    """40 s in place, yawing (0.4 sin 0.15t): AHRS 20 Hz with white heading noise 0.5° and a rate with
    white noise 0.002 rad/s, a still DVL at 5 Hz, ground truth for the start."""
    rng = np.random.default_rng(seed)
    acov = np.diag([np.radians(0.1) ** 2, np.radians(0.1) ** 2, HEADING_SIGMA**2])
    ms = [
        Attitude(
            k * S // 20,
            "ahrs",
            orientation=quat(yaw_true(k / 20) + HEADING_SIGMA * rng.standard_normal()),
            covariance=acov,
            angular_rate=np.array([0.0, 0.0, rate_true(k / 20)]) + RATE_SIGMA * rng.standard_normal(3),
        )
        for k in range(DURATION * 20)
    ]
    ms += [
        DvlVelocity(k * S // 5 + 2, "dvl", velocity=0.005 * rng.standard_normal(3), covariance=np.eye(3) * 0.005**2)
        for k in range(DURATION * 5)
    ]
    ms += [
        GroundTruthPose(k * S // 10 + 3, "gt", position=np.zeros(3), orientation=quat(yaw_true(k / 10)))
        for k in range(DURATION * 10)
    ]
    return Mission.from_measurements(metadata(), ms)


def yaw_rms(mission: Mission) -> float:
    config = SemslamConfig()
    est = GraphEstimator(mission.metadata, config)
    result = run_pipeline(estimators_input(mission, config), [est], [Replay({})], keep_observations=False)
    traj = result.results["graph"].trajectory
    t = traj.stamps * 1e-9
    yaw = Rotation.from_quat(traj.orientations).as_euler("ZYX")[:, 0]
    err = np.angle(np.exp(1j * (yaw - yaw_true(t))))
    return float(np.sqrt(np.mean(err[t > 3.0] ** 2)))


@pytest.mark.parametrize("seed", [0, 1])
def test_the_gyro_between_keyframes_cuts_the_heading_noise(seed, monkeypatch):
    mission = yawing(seed)
    linked = yaw_rms(mission)
    # each keyframe's attitude from its own readings alone (as before stop 42)
    monkeypatch.setattr(NavigationBuffer, "gyro_rotation", lambda self, t: None)
    alone = yaw_rms(mission)
    # alone: ~0.5°/√20 = 2 mrad a keyframe; linked by the rates' 0.45 mrad/√s, a smoother of a walk
    # measured once a second reaches ~√(2 · 0.45) ≈ 0.95 mrad (measured 0.93 and 1.75 on seed 0)
    assert alone > 1.4e-3, alone
    assert linked < 0.65 * alone, (linked, alone)


def test_the_rates_integrate_to_the_rotation_between_keyframes():
    nav = NavigationBuffer(metadata(), 0.02, 1e-4)
    w = np.array([0.05, -0.02, 0.3])
    acov = np.eye(3) * 1e-4
    nav.add(Attitude(0, "ahrs", orientation=np.array([0, 0, 0, 1.0]), covariance=acov, angular_rate=w))
    nav.start_interval(0.0, np.eye(3), 0.01)
    for k in range(1, 20):  # the orientation readings do not enter: the rates alone
        nav.add(Attitude(k * S // 20, "ahrs", orientation=np.array([0, 0, 0, 1.0]), covariance=acov, angular_rate=w))
    R_ij, h, _ = nav.gyro_rotation(1.0)
    assert h == pytest.approx(1.0)
    np.testing.assert_allclose(R_ij, so3_exp(w * 1.0), atol=1e-12)


def test_no_gyro_link_from_attitudes_differenced():
    """An AHRS without rates (a ROS Imu whose angular_velocity_covariance[0] is -1): the attitudes differenced
    are no gyro, so no rotation between keyframes is made of them; one such reading in an interval is enough."""
    nav = NavigationBuffer(metadata(), 0.02, 0.01)
    acov = np.eye(3) * 1e-4

    def reading(k, rate):
        q = Rotation.from_rotvec([0, 0, 0.2 * k / 20]).as_quat()
        return Attitude(k * S // 20, "ahrs", orientation=q, covariance=acov, angular_rate=rate)

    nav.add(reading(0, None))
    nav.start_interval(0.0, np.eye(3), 0.01)
    for k in range(1, 20):
        nav.add(reading(k, None))
    assert nav.gyro_rotation(1.0) is None
    nav.start_interval(1.0, np.eye(3), 0.01)
    for k in range(20, 40):  # measured rates but one reading without
        nav.add(reading(k, None if k == 30 else np.array([0, 0, 0.2])))
    assert nav.gyro_rotation(2.0) is None
    nav.start_interval(2.0, np.eye(3), 0.01)
    for k in range(40, 60):
        nav.add(reading(k, np.array([0, 0, 0.2])))
    R_ij, h, _ = nav.gyro_rotation(3.0)
    np.testing.assert_allclose(R_ij, so3_exp(np.array([0, 0, 0.2]) * h), atol=1e-9)


def test_the_rate_density_is_the_missions_declared_one_unless_configured():
    md = metadata()
    assert SemslamConfig().motion.angular_rate_density(md) == pytest.approx(RATE_SIGMA / np.sqrt(20.0))
    assert SemslamConfig(motion={"angular_rate_sigma_rad_s": 0.03}).motion.angular_rate_density(md) == 0.03
    assert SemslamConfig().motion.angular_rate_density(MissionMetadata()) == 0.01
