"""EKF configuration and initialisation."""

import numpy as np
import pytest

from semslam.config import SemslamConfig
from semslam.ekf import EkfEstimator
from semslam.errors import ConfigError, SemslamError
from semslam.mission.measurements import GroundTruthPose
from semslam.observations import PointObservation
from tests.support.ekf_mission import simulate_circling


def test_invalid_section_is_one_clear_line(tmp_path):
    from semslam.config import load_config

    f = tmp_path / "c.yaml"
    f.write_text("ekf:\n  max_prediction_step_s: -1\n")
    with pytest.raises(ConfigError, match=r"ekf\.max_prediction_step_s"):
        load_config(f)
    f.write_text("ekf:\n  bogus: 1\n")
    with pytest.raises(ConfigError, match=r"ekf\.bogus"):
        load_config(f)


def test_without_ground_truth_the_filter_starts_at_the_origin_at_the_measured_depth():
    sim = simulate_circling(seed=0, duration_s=5.0, with_features=False)
    meta = sim.metadata
    del meta.sensors["gt"]
    est = EkfEstimator(meta, SemslamConfig())
    for m in sim.measurements:
        if not isinstance(m, GroundTruthPose):
            est.process_measurement(m)
    r = est.finish()
    assert np.linalg.norm(r.trajectory.positions[0, :2]) < 1e-9
    assert abs(r.trajectory.positions[-1, 2] - sim.truth_states[-1, 2]) < 0.1


def test_observation_of_an_unknown_sensor_is_a_user_error():
    sim = simulate_circling(seed=0, duration_s=2.0, with_features=False)
    est = EkfEstimator(sim.metadata, SemslamConfig())
    for m in sim.measurements:
        est.process_measurement(m)
    with pytest.raises(SemslamError, match="sonar9"):
        est.process_observations(sim.measurements[-1].stamp, [PointObservation(0, "sonar9")])
