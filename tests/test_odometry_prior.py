"""The odometry front-end's navigation prior: how uncertain it says its predicted motion is, from the
covariances its DVL, AHRS and depth readings carry (experiments/odometry_covariance.py compares it
with the prior's real errors)."""

import numpy as np
import pytest

from frontends.odometry.prior import NavigationPrior
from semslam.mission.measurements import Attitude, Depth, DvlVelocity
from semslam.mission.mission import MissionMetadata, SensorInfo

S = 1_000_000_000
META = MissionMetadata(sensors={n: SensorInfo(n, k) for n, k in (("ahrs", "ahrs"), ("dvl", "dvl"), ("depth", "depth"))})


def _prior(sigma_v=0.01, sigma_att=0.01, depth_var=0.0004, valid=lambda t: True, walk=0.02, seconds=4.0):
    p = NavigationPrior(META, horizon_s=60.0, hold_walk_m_s=walk)
    for k in range(int(seconds * 20) + 1):  # AHRS at 20 Hz, DVL at 5 Hz, depth at 4 Hz
        t = k * S // 20
        p.add(Attitude(t, "ahrs", covariance=np.eye(3) * sigma_att**2))
        if k % 4 == 0:
            ok = valid(t)
            p.add(
                DvlVelocity(t, "dvl", velocity=np.array([0.2, 0.0, 0.0]), covariance=np.eye(3) * sigma_v**2, valid=ok)
            )
        if k % 5 == 0:
            p.add(Depth(t, "depth", depth=1.0, variance=depth_var))
    return p


def test_motion_covariance_adds_up_the_readings_errors():
    p = _prior()
    cov = p.motion_covariance(1 * S, 3 * S)
    assert np.allclose(p.motion(1 * S, 3 * S)[:3, 3], [0.4, 0.0, 0.0], atol=1e-9)
    assert np.allclose(np.diag(cov)[:3], 2 * 0.01**2)  # two attitude readings
    # ten DVL readings, each held 0.2 s: (σ² · 0.2² + walk² · 0.2³ / 3) · 10 per axis; the heading error turns 0.4 m
    dvl = 10 * (0.01**2 * 0.2**2 + 0.02**2 * 0.2**3 / 3)
    turned = 0.01**2 * 0.4**2
    assert cov[3, 3] == pytest.approx(dvl + turned, rel=1e-6)
    assert cov[5, 5] == pytest.approx(dvl + turned + 2 * 0.0004, rel=1e-6)  # and two depth readings along z
    assert np.allclose(cov - np.diag(np.diag(cov)), 0.0)


def test_a_reading_held_through_a_dropout_grows_the_covariance():
    dropout = _prior(valid=lambda t: not (1 * S < t < 3 * S))
    steady = _prior()
    held, normal = dropout.motion_covariance(1 * S, 3 * S)[3, 3], steady.motion_covariance(1 * S, 3 * S)[3, 3]
    assert held > normal + 0.01**2 * 2.0**2 * 0.9  # one reading's error times the 2 s it was held
    no_walk = _prior(valid=lambda t: not (1 * S < t < 3 * S), walk=0.0).motion_covariance(1 * S, 3 * S)[3, 3]
    assert held - no_walk == pytest.approx(0.02**2 * 2.0**3 / 3, rel=0.05)  # the velocity's random walk


def test_deep_in_a_dropout_the_velocity_error_since_the_reading_counts():
    """Over [5, 7] s of a dropout that began at 1 s, the held velocity is 4 s stale when the interval
    starts: the random walk's variance q²·4 s acts over the 2 s, (a − h)Δ² + Δ³/3, not the
    increments of a cumulative variance (which would say q²·(6³ − 4³)/3)."""
    p = _prior(valid=lambda t: not (1 * S < t < 9 * S), seconds=8.0, depth_var=0.0, sigma_att=0.0)
    var = p.motion_covariance(5 * S, 7 * S)[3, 3]
    assert var == pytest.approx(0.01**2 * 2.0**2 + 0.02**2 * (4.0 * 2.0**2 + 2.0**3 / 3), rel=1e-6)


def test_rotation_between_stamps_is_the_integrated_angular_rate_with_its_own_noise():
    """Turning at 0.04 rad/s while the pitch wobbles, AHRS attitudes with 0.5° of heading noise and
    rates with 3 mrad/s: the rotation between two stamps 2 s apart is the rates' (error ~0.04°, where
    two attitude readings differ by ~0.7°), the rates' noise is estimated from their second differences,
    and the covariance says so."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    sigma_w, turn = 0.003, 0.04

    def true_R(t):
        return Rotation.from_euler("ZYX", [turn * t, 0.02 * np.sin(2 * np.pi * t / 7.3), 0.0])

    p = NavigationPrior(META, horizon_s=60.0)
    errors, nees = [], []
    for k in range(20 * 30 + 1):
        t = k / 20
        noisy = true_R(t) * Rotation.from_rotvec(rng.normal(0.0, [0.002, 0.002, np.radians(0.5)]))
        rate = (true_R(t - 1e-4).inv() * true_R(t + 1e-4)).as_rotvec() / 2e-4 + rng.normal(0.0, sigma_w, 3)
        p.add(Attitude(int(t * S), "ahrs", orientation=noisy.as_quat(), covariance=np.eye(3), angular_rate=rate))
        if t >= 4 and k % 20 == 0:
            a, b = int((t - 2) * S), int(t * S)
            truth = (true_R(t - 2).inv() * true_R(t)).as_matrix()
            e = Rotation.from_matrix(truth.T @ p.motion(a, b)[:3, :3]).as_rotvec()
            errors.append(np.linalg.norm(e))
            nees.append(e @ np.linalg.solve(p.motion_covariance(a, b)[:3, :3], e))
    assert np.sqrt(p.gyro_variance()) == pytest.approx(sigma_w, rel=0.1)
    assert np.degrees(np.median(errors)) < 0.1
    assert 1.5 < np.mean(nees) < 5.0  # 3 DoF


def test_a_dvl_behind_the_body_origin_gives_the_body_motion_while_the_vehicle_turns():
    """The DVL head sits 0.25 m aft and 0.30 m below the body origin (the simulator's mount) and measures its own
    velocity, v_B + ω × t_BS. Turning at 0.1 rad/s, the head swings sideways at 2.5 cm/s: over a 2 s interval the
    body's motion is 5 cm off across the track unless the lever arm's ω × t_BS is taken out."""
    from scipy.spatial.transform import Rotation

    turn, speed, t_BS = 0.1, 0.2, np.array([-0.25, 0.0, 0.30])
    T_dvl = np.eye(4)
    T_dvl[:3, 3] = t_BS
    meta = MissionMetadata(
        sensors={
            "ahrs": SensorInfo("ahrs", "ahrs"),
            "dvl": SensorInfo("dvl", "dvl", T_BS=T_dvl),
            "depth": SensorInfo("depth", "depth"),
        }
    )
    p = NavigationPrior(meta, horizon_s=60.0)
    omega = np.array([0.0, 0.0, turn])
    for k in range(20 * 6 + 1):
        t = k / 20
        R = Rotation.from_euler("z", turn * t)
        p.add(Attitude(int(t * S), "ahrs", orientation=R.as_quat(), covariance=np.eye(3) * 1e-6, angular_rate=omega))
        if k % 4 == 0:
            head = np.array([speed, 0.0, 0.0]) + np.cross(omega, t_BS)
            p.add(DvlVelocity(int(t * S), "dvl", velocity=head, covariance=np.eye(3) * 1e-4))

    def position(t):  # the body origin on its circle, world frame
        return speed / turn * np.array([np.sin(turn * t), 1.0 - np.cos(turn * t), 0.0])

    for a, b in ((1.0, 3.0), (2.0, 4.0), (3.5, 5.5)):
        truth = Rotation.from_euler("z", turn * a).as_matrix().T @ (position(b) - position(a))
        predicted = p.motion(int(a * S), int(b * S))[:3, 3]
        assert np.linalg.norm(predicted - truth) < 0.005, (a, b, predicted, truth)


def test_before_the_first_dvl_reading_the_displacement_is_not_known_to_a_millimetre():
    """A vehicle descending without bottom lock: the AHRS and the depth sensor report, the DVL not yet. The prior
    predicts no horizontal motion, and its covariance must say that this is a guess (the velocity's random walk
    since the start), not a millimetre: else every registration there is a many-σ 'disagreement'."""
    p = _prior(valid=lambda t: t > 20 * S, seconds=24.0)
    sigma = np.sqrt(p.motion_covariance(8 * S, 10 * S)[3, 3])
    assert sigma == pytest.approx(0.02 * np.sqrt(8.0 * 2.0**2 + 2.0**3 / 3), rel=0.02)  # q²((a − t0)Δ² + Δ³/3)
    assert p.motion_covariance(21 * S, 23 * S)[3, 3] < 0.01**2  # the readings' own, once they come
