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


def test_pipe_extent_gap_and_inline_object_radius_are_the_shared_association_settings(tmp_path):
    """The graph and the EKF pair a pipe view with a pipe by one rule: the gap beyond its seen extent
    and the radius of an in-line object come from ``association``; the ``ekf`` section has neither."""
    from semslam.config import load_config
    from semslam.ekf.estimator import _Extent

    sim = simulate_circling(seed=0, duration_s=1.0, with_features=False)
    d, m = np.array([1.0, 0.0, 0.0]), np.cross(np.array([0.0, 2.0, 4.0]), np.array([1.0, 0.0, 0.0]))
    ext = _Extent()
    ext.add(np.array([[0.0, 2.0, 4.0], [2.0, 2.0, 4.0]]), 0.01)
    beyond = np.array([[2.4, 2.0, 4.0], [3.0, 2.0, 4.0]])  # 0.4 m beyond what was seen
    valve = np.array([[2.2, 2.1, 4.0]])  # 0.1 m off the axis, in between
    for gap, radius, apart, apart_valve in (
        (0.5, 0.05, False, False),
        (0.3, 0.05, True, True),
        (0.5, 0.15, False, True),
    ):
        est = EkfEstimator(
            sim.metadata, SemslamConfig(association={"pipe_extent_gap_m": gap, "inline_object_radius_m": radius})
        )
        assert est._pipe_apart(ext, beyond, m, d, np.zeros((0, 3))) == apart
        assert est._pipe_apart(ext, beyond, m, d, valve) == apart_valve
    for key in ("pipe_extent_gap_m", "pipe_object_radius_m"):
        f = tmp_path / "old.yaml"
        f.write_text(f"ekf:\n  {key}: 0.5\n")
        with pytest.raises(ConfigError, match=rf"ekf\.{key}"):
            load_config(f)
