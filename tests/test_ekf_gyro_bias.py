"""The gyro's bias as EKF state (issue 21, stop 43): three entries at the end of the vehicle block (body
axes), prior σ ``sensors.gyro_bias_sigma``, random walk ``sensors.gyro_bias_walk``; the prediction
integrates ω − b_g. σ 0: no bias state (the rates still integrated at the shared density, unlike before stop 43). The Jacobians are in tests/test_ekf_jacobians.py."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.config import SemslamConfig
from semslam.config.estimation import CONSTANT_BIAS_OVER_S, MIN_GYRO_BIAS_WALK
from semslam.ekf.estimator import DeadReckoning, EkfEstimator
from semslam.estimation import Trajectory
from semslam.estimators import create_estimator
from semslam.eval.map_quality import nees_band
from semslam.eval.metrics import position_nees
from semslam.pipeline import run_pipeline
from semslam.sim.dive import DiveSimConfig, simulate_dive
from tests.support.ekf_mission import simulate_circling

RATE = 4.5e-4  # the gyro's white-noise density (rad/s/√Hz), the simulators'


def _truth(sim) -> Trajectory:
    return Trajectory(
        sim.truth_stamps, sim.truth_states[:, :3], np.tile([0.0, 0.0, 0.0, 1.0], (len(sim.truth_stamps), 1))
    )


def test_no_gyro_bias_declared_zero_means_no_bias_state():
    """σ 0 (declared by the mission, or configured): no state, the vehicle block as before (9, 10 or 11)."""
    sim = simulate_circling(seed=0, duration_s=2.0, with_features=False)
    assert sim.metadata.extras["noise"]["ahrs"]["gyro_bias_sigma_rad_s"] == 0.0
    est = EkfEstimator(sim.metadata, SemslamConfig())
    assert est.nav.nv == 9 and est.nav.gyro_walk is None
    assert "gyro_bias" not in sim.run([est])["ekf"].history
    biased = simulate_circling(seed=0, duration_s=2.0, with_features=False, gyro_bias_sigma=1e-3)
    off = SemslamConfig(sensors={"gyro_bias_sigma_rad_s": 0.0})
    assert EkfEstimator(biased.metadata, off).nav.nv == 9
    on = EkfEstimator(biased.metadata, SemslamConfig())
    # declared constant: the least walk that reaches σ over CONSTANT_BIAS_OVER_S (above MIN_GYRO_BIAS_WALK here)
    assert on.nav.nv == 12 and on.nav.gyro_sigma0 == 1e-3
    assert on.nav.gyro_walk == pytest.approx(1e-3 / CONSTANT_BIAS_OVER_S**0.5) and on.nav.gyro_walk > MIN_GYRO_BIAS_WALK


def test_circling_learns_the_drawn_gyro_bias_and_stays_consistent():
    """A drawn bias (σ 2 mrad/s an axis, the AHRS mounted at 90° about z): the EKF's and dead reckoning's
    final b_g within 3σ of the truth on every axis, σ down to < 5 % of the prior, and the position's
    mean NEES inside the 95 % band of one pose (χ²₃). Without the state (σ 0) the same mission's NEES
    is 9.95 (outside the band) and the ATE 0.045 against 0.039 m (measured when this test was written)."""
    sim = simulate_circling(seed=2, duration_s=60.0, dropouts=(), rate_sigma=RATE, gyro_bias_sigma=2e-3)
    cfg = SemslamConfig(motion={"angular_rate_sigma_rad_s": RATE})
    res = sim.run([EkfEstimator(sim.metadata, cfg), DeadReckoning(sim.metadata, cfg)])
    truth = sim.extras["gyro_bias_B"]
    lo, hi = nees_band()
    for name, r in res.items():
        stamps, b, sb = r.history["gyro_bias"]
        assert b.shape == sb.shape == (len(stamps), 3) and r.history["vehicle_cov"][1].shape[1:] == (12, 12)
        z = (b[-1] - truth) / sb[-1]
        assert np.all(np.abs(z) < 3.0), (name, z)
        assert np.all(sb[-1] < 0.05 * 2e-3), (name, sb[-1])
        nees = position_nees(r.trajectory, _truth(sim))
        assert lo < nees < hi, (name, nees)


@pytest.mark.parametrize("seed", [0, 1])
def test_dive_final_gyro_bias_within_three_sigma_of_the_summary(seed):
    """A simulated dive (80 s, one line) with the simulator's drawn bias (σ 2e-4 rad/s, declared): the
    EKF's final b_g in the AHRS's axes within 3σ of the summary's ``gyro_bias_rad_s`` on every axis, and
    z (the axis the surface fixes and the DVL separate from the heading bias's drift) learnt below its prior."""
    line = {"lines": 1, "line_length_m": 40.0}
    dive = {"surface_start_s": 15.0, "surface_end_s": 15.0, "descent_s": 15.0, "ascent_s": 15.0}
    cfg = DiveSimConfig.model_validate(
        {"seed": seed, "trajectory": line, "dive": dive, "ahrs": {"gyro_bias_sigma_rad_s": 2e-4}}
    )
    mission = simulate_dive(cfg)
    est = create_estimator("ekf", mission.metadata, SemslamConfig())
    r = run_pipeline(mission, [est], []).results["ekf"]
    _, b, sb = r.history["gyro_bias"]
    R_BS = mission.metadata.extrinsic("ahrs")[:3, :3]
    truth = R_BS @ np.array(mission.metadata.extras["gyro_bias_rad_s"])  # the AHRS's axes → {B}
    z = (b[-1] - truth) / sb[-1]
    assert np.all(np.abs(z) < 3.0), z
    assert sb[-1, 2] < 0.8 * 2e-4 and np.all(sb[-1, :2] < 0.5 * 2e-4), sb[-1]
