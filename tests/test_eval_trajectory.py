"""Trajectory errors: the SE(3)-aligned ATE removes a rotation and shift of the whole trajectory
(the global frame that a heading-biased AHRS leaves unobservable), and nothing else."""

import itertools

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


def _evo_reference(estimate: Trajectory, truth: Trajectory, alignment: str) -> tuple[float, float]:
    """ATE and RPE RMSE as evo computes them from positions and quaternions alone (its own pose
    matrices, built pose by pose)."""
    from evo.core import metrics, sync
    from evo.core.trajectory import PoseTrajectory3D
    from evo.core.units import Unit

    def evo(t):
        return PoseTrajectory3D(t.positions, t.orientations[:, [3, 0, 1, 2]], t.stamps * 1e-9)

    ref, est = sync.associate_trajectories(evo(truth), evo(estimate), max_diff=0.05)
    if alignment == "se3":
        est.align(ref)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    rpe = metrics.RPE(metrics.PoseRelation.translation_part, delta=1.0, delta_unit=Unit.meters)
    rpe.process_data((ref, est))
    return ape.get_statistic(metrics.StatisticsType.rmse), rpe.get_statistic(metrics.StatisticsType.rmse)


def test_errors_are_evos_from_positions_and_quaternions():
    """The pose matrices made at once give evo's numbers (float noise at most), aligned or not, with
    poses of the estimate between those of the truth."""
    rng = np.random.default_rng(1)
    truth = _circle(600)
    keep = np.sort(rng.choice(600, 350, replace=False))
    R = Rotation.from_euler("zyx", [0.02, 0.01, -0.01])
    rot = Rotation.from_rotvec(rng.normal(0, 0.02, (350, 3))) * Rotation.from_quat(truth.orientations[keep])
    estimate = Trajectory(
        truth.stamps[keep] + rng.integers(-(10**7), 10**7, 350),
        R.apply(truth.positions[keep]) + rng.normal(0, 0.02, (350, 3)),
        (R * rot).as_quat() * rng.choice([-1.0, 1.0], (350, 1)),  # either sign of a quaternion
    )
    for alignment, (a, b) in itertools.product(("none", "se3"), ((estimate, truth), (truth, estimate))):
        ours = trajectory_errors(a, b, alignment=alignment)  # the shorter trajectory first, then second
        ate, rpe = _evo_reference(a, b, alignment)
        assert ours.ate_rmse_m > 0.01
        assert abs(ours.ate_rmse_m - ate) < 1e-12 and abs(ours.rpe_rmse_m - rpe) < 1e-12


def test_stamp_matching_is_evos():
    """Stamps matched at once as evo matches them one by one: nearest within the gap, its tie
    rules, stamps beyond either end, repeated stamps, and evo's own search for unsorted ones."""
    from evo.core.sync import matching_time_indices as evos

    from semslam.eval.metrics import matching_time_indices

    rng = np.random.default_rng(2)
    for trial in range(30):
        s2 = np.sort(rng.choice(np.arange(0.0, 20.0, 0.05), 200))  # on a grid: ties and repeats happen
        s1 = np.round(rng.uniform(-1.0, 21.0, 150), 3 if trial % 2 else 2)
        if trial == 29:
            s2 = rng.permutation(s2)
        for gap in (0.0, 0.02, 0.05, 0.5):
            assert matching_time_indices(s1, s2, gap) == evos(s1, s2, gap)
