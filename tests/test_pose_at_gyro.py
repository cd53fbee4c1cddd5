"""The graph's pose after the newest keyframe (``Keyframes.pose_at``, what the sonar front-end places its patches
with) turned by the gyro since the keyframe (issue 21, stop 47): its rotation from the single AHRS reading at t
carried each reading's heading noise into every patch placed between keyframes."""

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.backend.graph import GraphEstimator
from semslam.backend.navigation import NavigationBuffer
from semslam.config import SemslamConfig
from semslam.mission.measurements import Attitude, DvlVelocity
from tests.test_dvl_gyro_turn import HEADING, HEADING_SIGMA, metadata, straight_line

S = 1_000_000_000
NO_BIAS = {"gyro_bias_sigma_rad_s": 0.0, "heading_bias_walk_rad_per_sqrt_s": 0.0}


def yaw_errors(mission, **config) -> tuple[np.ndarray, bool]:
    """pose_at's yaw error against the line's heading at every AHRS reading after the newest keyframe (when it
    arrives) and halfway back to the reading before (a stamp older than the newest reading); whether its rotation
    was the AHRS reading carried to the stamp at every one (to the bit)."""
    est = GraphEstimator(mission.metadata, SemslamConfig(sensors=NO_BIAS, **config))
    kf = est.keyframes
    out, prev, reading = [], None, True
    for m in mission:
        est.process_measurement(m)
        if not isinstance(m, Attitude):
            continue
        stamps = [m.stamp] + ([(prev + m.stamp) // 2] if prev is not None else [])
        for s in stamps:
            if len(kf) > 2 and s > kf.stamps[-1]:
                R = est.view().pose_at(s)[:3, :3]
                out.append(Rotation.from_matrix(R).as_euler("zyx")[0] - HEADING)
                reading &= np.array_equal(R, kf.unbiased(kf.nav.attitude_at(s * 1e-9)[0]))
        prev = m.stamp
    return np.array(out), reading


def without_rates(mission):
    """The same mission with the AHRS's rates taken out."""
    return type(mission).from_measurements(
        mission.metadata,
        [Attitude(m.stamp, m.sensor, m.orientation, m.covariance) if isinstance(m, Attitude) else m for m in mission],
    )


def test_pose_after_the_keyframe_turned_by_the_gyro_not_one_reading():
    """A straight line, 10 mrad white heading noise per reading, a perfect gyro (tests.test_dvl_gyro_turn): the yaw
    between keyframes is the keyframe's (every reading of its interval fused) turned by the gyro, not one reading
    (on main: RMS ≈ the readings' 10 mrad). Without the rates, or with ``motion.gyro_link`` off, it is the reading
    carried to t, as before."""
    for seed in range(3):
        e, reading = yaw_errors(straight_line(seed))
        assert len(e) > 500 and not reading
        assert np.sqrt(np.mean(e**2)) < 0.3 * HEADING_SIGMA, seed
    mission = straight_line(0)
    for e, reading in (yaw_errors(without_rates(mission)), yaw_errors(mission, motion={"gyro_link": False})):
        assert len(e) > 500 and reading
        assert np.sqrt(np.mean(e**2)) > 0.7 * HEADING_SIGMA


def test_the_gyro_rotation_before_the_newest_reading_is_the_one_integrated_then():
    """gyro_rotation_at(t) for t older than the newest reading: what gyro_rotation(t) gave before the readings after
    t arrived (not the newest reading carried back)."""
    rng = np.random.default_rng(1)
    nav = NavigationBuffer(metadata(), 0.05, 1e-3)
    t0 = 1.0
    nav.add(Attitude(int(t0 * S), "ahrs", Rotation.identity().as_quat(), np.eye(3) * 1e-4, angular_rate=np.zeros(3)))
    nav.start_interval(t0, np.eye(3), 0.01, np.array([0.0, 0.0, 0.01]))
    then = {}
    for k in range(1, 30):
        t = t0 + 0.05 * k
        for q in (t - 0.03, t - 0.01):
            then[q] = nav.gyro_rotation_at(q)
        R = Rotation.from_rotvec(rng.normal(0, 0.3, 3)).as_quat()
        nav.add(Attitude(int(round(t * S)), "ahrs", R, np.eye(3) * 1e-4, angular_rate=rng.normal(0, 0.5, 3)))
        nav.add(DvlVelocity(int(round(t * S)) + 2, "dvl", np.zeros(3), np.eye(3) * 1e-4))
    turned = 0
    for q, dR in then.items():
        np.testing.assert_allclose(nav.gyro_rotation_at(q), dR, atol=1e-12)
        turned += np.linalg.norm(Rotation.from_matrix(dR).as_rotvec()) > 0.1
    assert turned > 20
    np.testing.assert_allclose(nav.gyro_rotation_at(t0 + 3.0), nav.gyro_rotation(t0 + 3.0)[0], atol=0)
