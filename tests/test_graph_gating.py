"""The graph's gates take the pose's uncertainty relative to the map: what it had when the map was
started (metres after the DVL-less descent of a tank mission) is common to every landmark and pose."""

import gtsam
import numpy as np

from semslam.backend.landmarks import GaugeFreeCovariance


def _pose(yaw: float) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3.Yaw(yaw), np.array([1.0, 2.0, 3.0]))


def _body(cov_world: np.ndarray, yaw: float) -> np.ndarray:
    R = _pose(yaw).rotation().matrix()
    B = np.kron(np.eye(2), R)
    return B.T @ cov_world @ B


def test_before_the_map_the_pose_covariance_is_its_own():
    g = GaugeFreeCovariance()
    cov = np.diag([1e-4, 1e-4, 1e-3, 25.0, 25.0, 1e-4])
    np.testing.assert_array_equal(g.relative(_pose(0.3), cov), cov)


def test_what_the_pose_had_when_the_map_started_is_taken_out_whatever_the_heading_since():
    start_world = np.diag([1e-4, 1e-4, 1e-3, 25.0, 16.0, 1e-4])  # 5 m and 4 m horizontal σ: the descent
    grown_world = np.diag([2e-6, 2e-6, 4e-5, 0.01, 0.0225, 1e-6])  # since then: 10 cm, 15 cm
    g = GaugeFreeCovariance()
    g.start(_pose(0.2), _body(start_world, 0.2))
    rel = g.relative(_pose(1.4), _body(start_world + grown_world, 1.4))
    np.testing.assert_allclose(rel, _body(grown_world, 1.4), atol=1e-9)
    assert np.linalg.eigvalsh(g.relative(_pose(0.2), _body(start_world, 0.2))).min() > 0  # clipped, not singular


def test_the_common_part_shrinks_when_the_pose_becomes_surer():
    start_world = np.diag([1e-4, 1e-4, 1e-3, 25.0, 25.0, 1e-4])
    g = GaugeFreeCovariance()
    g.start(_pose(0.0), _body(start_world, 0.0))
    relocked = np.diag([1e-4, 1e-4, 1e-3, 2.25, 2.25, 1e-4])  # the DVL back: 1.5 m
    g.relative(_pose(0.0), _body(relocked, 0.0))
    later = relocked + np.diag([0, 0, 0, 0.01, 0.01, 0])  # 10 cm more since the relock
    rel = g.relative(_pose(0.0), _body(later, 0.0))
    np.testing.assert_allclose(np.sqrt(np.diag(rel)[3:5]), [0.1, 0.1], rtol=1e-6)
