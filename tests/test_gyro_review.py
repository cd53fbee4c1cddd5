"""The gyro link's review points (issue 21, stop 43's review, items 3 and 4): a rotation carried with the AHRS's
last rate has the σ of the rate's white noise integrated over the interval (density·√Δt, as the integrated one),
a rate older than the AHRS's age limit carries nothing, and the readings, the keyframes' attitude and the DVL's
lever arm turn at the rate less the gyro's bias b̄, as the gyro link does."""

import numpy as np
import pytest

import semslam.backend.keyframes as keyframes_module
from factors.geometry import so3_exp, so3_log, so3_right_jacobian
from semslam.backend.graph import GraphEstimator
from semslam.backend.navigation import NavigationBuffer
from semslam.compare import estimators_input
from semslam.config import SemslamConfig
from semslam.mission.measurements import Attitude, DvlVelocity, GroundTruthPose
from semslam.mission.mission import Mission
from semslam.pipeline import run_pipeline
from tests.support.replay import Replay
from tests.test_graph_gyro import metadata, quat

S = 1_000_000_000
DENSITY = 0.002 / np.sqrt(20.0)  # tests.test_graph_gyro's declared gyro: 0.002 rad/s at 20 Hz


def _held_rate_mission() -> Mission:
    """6 s in place turning at 0.05 rad/s: AHRS at 20 Hz, DVL at 50 Hz between its readings, so that keyframes
    20 ms apart (at DVL readings) mostly have no AHRS reading between them."""
    ms = [
        Attitude(
            k * S // 20,
            "ahrs",
            orientation=quat(0.05 * k / 20),
            covariance=np.diag(np.radians([0.1, 0.1, 0.5]) ** 2),
            angular_rate=np.array([0.0, 0.0, 0.05]),
        )
        for k in range(6 * 20)
    ]
    ms += [
        DvlVelocity(k * S // 50 + 3_000_000, "dvl", velocity=np.zeros(3), covariance=np.eye(3) * 0.005**2)
        for k in range(6 * 50)
    ]
    ms.append(GroundTruthPose(0, "gt", position=np.zeros(3), orientation=quat(0.0)))  # the start
    return Mission.from_measurements(metadata(), ms)


def _links(monkeypatch, **config) -> tuple[list, np.ndarray, np.ndarray, GraphEstimator]:
    """The σ of every rotation link between keyframes on the held-rate mission, the keyframes' intervals, which of
    them have no AHRS reading, and the estimator."""
    links = []
    for name in ("rotation_carry_factor", "gyro_rotation_factor"):
        make = getattr(keyframes_module, name)

        def recording(*args, _make=make):
            links.append(args[-1])
            return _make(*args)

        monkeypatch.setattr(keyframes_module, name, recording)
    mission = _held_rate_mission()
    config = SemslamConfig(graph={"keyframe_max_interval_s": 0.02}, **config)
    est = GraphEstimator(mission.metadata, config)
    run_pipeline(estimators_input(mission, config), [est], [Replay({})], keep_observations=False)
    stamps = np.array(est.keyframes.stamps) * 1e-9
    ahrs = np.arange(6 * 20) / 20
    no_reading = np.array([not np.any((ahrs > a) & (ahrs <= b)) for a, b in zip(stamps[:-1], stamps[1:])])
    return links, np.diff(stamps), no_reading, est


@pytest.mark.parametrize("gyro_bias_sigma", [0.0, 5e-5])
def test_a_held_rate_carries_the_rate_noise_integrated_over_the_interval(gyro_bias_sigma, monkeypatch):
    links, dt, no_reading, _ = _links(monkeypatch, sensors={"gyro_bias_sigma_rad_s": gyro_bias_sigma})
    assert len(links) == len(dt) and no_reading.sum() > 0.5 * len(dt)
    # every link, with a reading between its keyframes or not: density·√Δt (was density·Δt without one, ~7× tight)
    np.testing.assert_allclose(links, DENSITY * np.sqrt(dt), rtol=1e-9)


def _reading(t: float, yaw: float, rate) -> Attitude:
    return Attitude(
        int(round(t * S)), "ahrs", orientation=quat(yaw), covariance=np.eye(3) * 1e-6, angular_rate=np.asarray(rate)
    )


def test_a_stale_rate_carries_nothing_past_its_age_limit():
    w = np.array([0.0, 0.0, 0.2])
    nav = NavigationBuffer(metadata(), 0.02, DENSITY, rate_max_age=0.5)
    nav.add(_reading(0.0, 0.0, w))
    nav.start_interval(0.0, np.eye(3), 0.01)
    # the reading's rate over its first 0.5 s, then held still: the keyframe's attitude and the gyro link agree
    R, cov = nav.attitude_at(3.0)
    np.testing.assert_allclose(R, quat_matrix(0.2 * 0.5), atol=1e-12)
    assert cov[2, 2] > nav.attitude.cov[2, 2] + (DENSITY * 0.5) ** 2  # σ grows over the whole age, not the held part
    dR, h, J = nav.gyro_rotation(3.0)
    assert h == pytest.approx(3.0)
    np.testing.assert_allclose(dR, quat_matrix(0.2 * 0.5), atol=1e-12)
    np.testing.assert_allclose(J, -so3_right_jacobian(w * 0.5) * 0.5, atol=1e-12)  # b̄ acts over the 0.5 s held
    np.testing.assert_allclose(nav.omega(3.0), 0.0)  # nor turns the DVL's lever arm
    np.testing.assert_allclose(nav.omega(0.4), w)
    # within the age limit the rate carries all of it
    np.testing.assert_allclose(nav.attitude_at(0.4)[0], quat_matrix(0.2 * 0.4), atol=1e-12)


def quat_matrix(yaw: float) -> np.ndarray:
    return so3_exp(np.array([0.0, 0.0, yaw]))


def test_readings_keyframes_and_the_dvl_lever_arm_turn_at_the_rate_less_the_bias():
    b = np.array([0.01, -0.02, 0.03])  # b̄, the interval's gyro bias (body axes = the AHRS's here)
    w = np.array([0.05, 0.0, 0.2])
    nav = NavigationBuffer(metadata(), 0.02, DENSITY)
    nav.add(_reading(0.0, 0.0, w))
    nav.start_interval(0.0, np.eye(3), 0.01, gyro_bias=b)
    cov0 = nav.fused.cov.copy()
    nav.add(_reading(0.05, 0.0, w))
    # the reading at 0 carried to the one at 0.05 with the rate less b̄, then updated with it (identity)
    carried, P = so3_exp((w - b) * 0.05), cov0 + np.eye(3) * DENSITY**2 * 0.05  # white rate noise over 0.05 s
    K = P @ np.linalg.inv(P + nav.attitude.cov)
    np.testing.assert_allclose(nav.fused.R_WB, carried @ so3_exp(K @ so3_log(carried.T)), atol=1e-12)
    F = nav.fused.R_WB.copy()
    # the AHRS's newest reading carried to a keyframe 30 ms later
    R, _ = nav.attitude_at(0.08)
    np.testing.assert_allclose(R, quat_matrix(0.0) @ so3_exp((w - b) * 0.03), atol=1e-12)
    # the readings fused since the keyframe, carried with the same rate
    R_f, _, n = nav.take_fused_attitude(0.08)
    assert n == 2
    np.testing.assert_allclose(R_f, F @ so3_exp((w - b) * 0.03), atol=1e-12)
    # the DVL's lever arm turns at the rate less the bias
    assert np.allclose(nav.omega(0.06), w - b)
    nav.add(DvlVelocity(int(0.06 * S), "dvl", velocity=np.zeros(3), covariance=np.eye(3) * 1e-4))
    np.testing.assert_allclose(nav.dvl.omega_B, w - b)
    # and the gyro link integrates the same rates (stop 43)
    dR, _, _ = nav.gyro_rotation(0.08)
    np.testing.assert_allclose(dR, so3_exp((w - b) * 0.05) @ so3_exp((w - b) * 0.03), atol=1e-12)


def test_without_the_gyro_link_only_a_keyframe_without_a_reading_is_carried(monkeypatch):
    links, dt, no_reading, est = _links(monkeypatch, motion={"gyro_link": False})
    assert not est.keyframes.has_gyro_bias  # no link, no bias state (the declared σ notwithstanding)
    assert 0 < len(links) == no_reading.sum() < len(dt)
    np.testing.assert_allclose(links, DENSITY * np.sqrt(dt[no_reading]), rtol=1e-9)
