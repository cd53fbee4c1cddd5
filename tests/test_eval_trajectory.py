"""Trajectory errors: the SE(3)-aligned ATE removes a rotation and shift of the whole trajectory
(the global frame that a heading-biased AHRS leaves unobservable), and nothing else."""

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.estimation import Trajectory
from semslam.eval.metrics import _aligned_ate, trajectory_errors


def _circle(n=400):
    t = np.linspace(0, 2 * np.pi, n)
    pos = np.c_[2 * np.cos(t), 2 * np.sin(t), 3 + 0.3 * np.sin(3 * t)]
    quat = Rotation.from_euler("z", (t + np.pi / 2)[:, None]).as_quat()
    return Trajectory((np.arange(n) * 1e8).astype(np.int64), pos, quat)


def test_a_rotated_and_shifted_trajectory_has_no_aligned_error():
    truth = _circle()
    R = Rotation.from_euler("z", 0.5, degrees=True)
    moved = Trajectory(
        truth.stamps,
        R.apply(truth.positions) + [0.02, -0.01, 0.0],
        (R * Rotation.from_quat(truth.orientations)).as_quat(),
    )
    assert trajectory_errors(moved, truth).ate_rmse_m > 0.02
    assert _aligned_ate(moved, truth) < 1e-6


def test_aligned_error_keeps_the_shape_error():
    truth = _circle()
    noisy = Trajectory(
        truth.stamps,
        truth.positions + np.random.default_rng(0).normal(0, 0.01, truth.positions.shape),
        truth.orientations,
    )
    assert 0.012 < _aligned_ate(noisy, truth) < 0.02  # √3 × 1 cm, barely reduced by the fit
