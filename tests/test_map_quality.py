"""Map quality that cannot hide (issue 21): per-class duplicates, misses and false landmarks; the
position+yaw alignment; the NEES band of a consistent and of an overconfident estimator."""

import numpy as np

from semslam.estimation import LandmarkEstimate, Trajectory
from semslam.eval.map_quality import (
    align_position_yaw,
    ate_position_yaw,
    landmark_quality,
    moved,
    nees_consistency,
)
from semslam.eval.metrics import match_landmarks
from semslam.mission.ground_truth import GroundTruthMap, GtObject, GtPipe

TRUTH = GroundTruthMap(
    objects=(GtObject(0, "valve", (1.0, 0.0, 4.5)), GtObject(1, "elbow", (2.0, 0.0, 4.5))),
    pipes=(GtPipe(0, (0.0, 0.0, 4.5), (0.9, 0.0, 4.5), 0.05), GtPipe(1, (0.0, 1.0, 4.5), (0.9, 1.0, 4.5), 0.05)),
    seen_objects=(0, 1),
    seen_pipes=(0,),  # pipe 1 was never seen: not missed
)


def _obj(i, x):
    return LandmarkEstimate(i, "object", position=np.array(x, float))


def test_per_class_counts():
    lms = [
        _obj(1, (1.01, 0.0, 4.5)),
        _obj(2, (1.05, 0.02, 4.5)),  # valve again: a twin
        _obj(3, (6.0, 0.0, 4.5)),  # nothing there: false
        LandmarkEstimate(4, "pipe", p=np.array([0.05, 0.01, 4.5]), q=np.array([0.8, 0.01, 4.5])),
    ]
    q = landmark_quality(lms, TRUTH, match_landmarks)
    assert (q["object_mapped"], q["object_duplicates"], q["object_false"]) == (3, 1, 1)
    assert q["object_missed"] == 1  # the elbow
    assert (q["pipe_seen"], q["pipe_missed"], q["pipe_duplicates"], q["pipe_false"]) == (1, 0, 0, 0)
    assert q["objects_once"] is False
    once = landmark_quality([_obj(1, (1.01, 0.0, 4.5)), _obj(2, (2.0, 0.01, 4.5))], TRUTH, match_landmarks)
    assert once["objects_once"] is True and once["object_p90_error_m"] < 0.011


def _trajectory(positions, cov=None):
    n = len(positions)
    quats = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    return Trajectory(np.arange(n, dtype=np.int64) * 100_000_000, np.asarray(positions, float), quats, cov)


def test_position_yaw_alignment_removes_a_yaw_and_shift_but_not_a_tilt():
    rng = np.random.default_rng(1)
    truth = rng.uniform(-3, 3, (200, 3))
    yaw = np.radians(7.0)
    Rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    est = truth @ Rz.T + [0.3, -0.2, 0.1]
    np.testing.assert_allclose(align_position_yaw(est, truth), truth, atol=1e-9)
    ate, T = ate_position_yaw(_trajectory(est), _trajectory(truth))
    assert ate < 1e-9
    # a map turned with the trajectory is right once moved by the same alignment
    valve = LandmarkEstimate(1, "object", position=Rz @ np.array([1.0, 0.0, 4.5]) + [0.3, -0.2, 0.1])
    np.testing.assert_allclose(moved([valve], T)[0].position, [1.0, 0.0, 4.5], atol=1e-9)
    tilt = np.radians(5.0)
    Rx = np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]])
    assert ate_position_yaw(_trajectory(truth @ Rx.T), _trajectory(truth))[0] > 0.05  # not a gauge freedom


def _random_walk_errors(n, sigma, rng):
    """Errors of a drifting estimate: a random walk of known per-pose covariance σ²·t."""
    steps = rng.normal(0, sigma, (n, 3))
    e = np.cumsum(steps, axis=0)
    cov = np.array([np.eye(3) * sigma**2 * (k + 1) for k in range(n)])
    return e, cov


def test_nees_band_holds_a_consistent_drift_and_rejects_an_overconfident_one():
    rng = np.random.default_rng(3)
    truth = _trajectory(np.zeros((600, 3)))
    shares = []
    for _ in range(20):
        e, cov = _random_walk_errors(600, 0.01, rng)
        q = nees_consistency(_trajectory(e, cov), truth)
        assert q["nees_in_band"] is True
        shares.append(q["nees_share_in_pose_band"])
    assert abs(np.mean(shares) - 0.95) < 0.03
    e, cov = _random_walk_errors(600, 0.01, rng)
    over = nees_consistency(_trajectory(e, cov / 16.0), truth)  # σ four times too small
    assert over["nees_in_band"] is False and over["nees_share_above_pose_band"] > 0.3
