"""The newest pose's marginal from iSAM2's root clique (semslam.backend.marginal)."""

import gtsam
import numpy as np
import pytest

from semslam.backend.marginal import (
    _root_conditional,
    joint_covariance,
    marginal_covariance,
    root_joint_covariance,
    root_marginal_covariance,
)

X, L = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.L


def _isam(n: int = 12) -> gtsam.ISAM2:
    """A trajectory of n poses seeing four points, built one keyframe at a time."""
    rng = np.random.default_rng(3)
    isam = gtsam.ISAM2()
    odo = gtsam.noiseModel.Diagonal.Sigmas(np.r_[0.01, 0.02, 0.03, 0.1, 0.2, 0.05])
    obs = gtsam.noiseModel.Isotropic.Sigma(3, 0.1)
    pts = rng.normal(size=(4, 3)) * 3
    for k in range(n):
        g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
        pose = gtsam.Pose3(gtsam.Rot3.Yaw(0.1 * k), np.array([k, 0.5 * k, 0.0]))
        v.insert(X(k), pose)
        if k == 0:
            g.add(gtsam.PriorFactorPose3(X(0), pose, gtsam.noiseModel.Isotropic.Sigma(6, 0.1)))
        else:
            prev = gtsam.Pose3(gtsam.Rot3.Yaw(0.1 * (k - 1)), np.array([k - 1, 0.5 * (k - 1), 0.0]))
            g.add(gtsam.BetweenFactorPose3(X(k - 1), X(k), prev.between(pose), odo))
        for j, p in enumerate(pts):
            if (k + j) % 3:
                continue
            if k < 3:
                v.insert(L(j), p + rng.normal(size=3) * 0.05)
            if k < 3 or isam.valueExists(L(j)):
                g.add(_point_factor(X(k), L(j), pose.transformTo(p), obs))
        isam.update(g, v)
    return isam


def _point_factor(x, l, p_B, noise):
    """A point seen from a pose: bearing (2) and range (1)."""
    return gtsam.BearingRangeFactor3D(x, l, gtsam.Unit3(p_B), float(np.linalg.norm(p_B)), noise)


def test_newest_pose_from_root_matches_isam2():
    isam = _isam()
    newest = X(11)
    cov = root_marginal_covariance(isam, newest)
    assert cov is not None  # new keys are ordered last: the newest pose is in the root
    ref = isam.marginalCovariance(newest)
    assert np.max(np.abs(cov - ref)) <= 1e-9 * np.max(np.abs(ref))
    # Every frontal of the root, wherever it sits in R (a point, an older pose, the newest pose).
    root_keys = _root_conditional(isam, newest).keys()
    assert len(root_keys) > 2 and any(gtsam.Symbol(k).chr() == ord("l") for k in root_keys)
    for key in root_keys:
        ref = isam.marginalCovariance(key)
        assert np.max(np.abs(root_marginal_covariance(isam, key) - ref)) <= 1e-9 * np.max(np.abs(ref))


def test_key_outside_the_root_falls_back():
    isam = _isam()
    assert root_marginal_covariance(isam, X(0)) is None
    np.testing.assert_array_equal(marginal_covariance(isam, X(0)), isam.marginalCovariance(X(0)))


def test_joint_of_root_keys_matches_isam2():
    # The joint marginal of several root frontals (in any order) is iSAM2's, cross-covariances included.
    isam = _isam()
    root_keys = list(_root_conditional(isam, X(11)).keys())
    for keys in (root_keys[::-1], root_keys[1:], [X(11), root_keys[0]]):
        cov = root_joint_covariance(isam, keys)
        joint = isam.jointMarginalCovariance(gtsam.KeyVector(keys))
        ref = np.block([[np.asarray(joint.at(a, b)) for b in keys] for a in keys])
        assert cov is not None and cov.shape == ref.shape
        assert np.max(np.abs(cov - ref)) <= 1e-9 * np.max(np.abs(ref))
    # a key outside the root: iSAM2's joint marginal
    assert root_joint_covariance(isam, [X(11), X(0)]) is None
    joint = isam.jointMarginalCovariance(gtsam.KeyVector([X(11), X(0)]))
    np.testing.assert_allclose(joint_covariance(isam, [X(11), X(0)])[6:, :6], np.asarray(joint.at(X(0), X(11))))


@pytest.mark.parametrize("drift", [False, True])
def test_the_newest_keyframe_is_read_from_the_root_in_a_mission(monkeypatch, drift):
    # The session eliminates each update's newest keyframe (pose, velocity, heading bias) last, so
    # that every refresh reads its joint marginal from the root clique; before, half of the
    # refreshes of this mission (all of the tank's observation updates) fell back to iSAM2's
    # jointMarginalCovariance (~0.7 ms each), the velocity not being a frontal of the root.
    import semslam.backend.marginal as marginal
    from frontends.oracle import OracleFrontend
    from semslam.backend.graph import GraphEstimator
    from semslam.config import SemslamConfig
    from semslam.pipeline import run_pipeline
    from tests.support.synthetic_mission import SyntheticConfig, simulate

    calls = []
    root = marginal.root_joint_covariance
    monkeypatch.setattr(
        marginal, "root_joint_covariance", lambda isam, keys: calls.append(root(isam, keys)) or calls[-1]
    )
    mission = simulate(SyntheticConfig(duration_s=80.0, seed=0))
    if drift:  # a declared heading drift: the bias B(k) and its rate D(k) are states too (review, stop 42)
        ahrs = mission.metadata.extras.setdefault("noise", {}).setdefault("ahrs", {})
        ahrs.update(heading_bias_drift_rad=0.02, heading_bias_drift_over_s=80.0)
    est = GraphEstimator(mission.metadata, SemslamConfig(), batch=False)
    assert est.keyframes.has_rate == drift
    run_pipeline(mission, [est], [OracleFrontend(mission.metadata, {"seed": 0})], keep_observations=False)
    assert len(calls) > 60
    assert sum(c is None for c in calls) <= 1  # the first update: iSAM2's batch, its own ordering
