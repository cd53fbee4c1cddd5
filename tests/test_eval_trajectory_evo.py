"""The trajectory metrics computed at once are evo's: its pairs of poses a path length apart, its
Umeyama alignment (and where it refuses one), its origin alignment."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.estimation import Trajectory
from semslam.eval.metrics import GeometryException, path_pairs, trajectory_errors, umeyama


def _walk(rng, n: int, stall: bool) -> np.ndarray:
    """A wandering path with speeds varying along it; ``stall``: some poses repeat the previous one."""
    steps = rng.normal(0, 1, (n, 3)) * rng.uniform(0.001, 0.2, (n, 1))
    if stall:
        steps[rng.random(n) < 0.2] = 0.0
    return np.cumsum(steps, axis=0)


def test_path_pairs_are_evos():
    from evo.core.filters import filter_pairs_by_path

    rng = np.random.default_rng(3)
    for trial in range(12):
        p = _walk(rng, 1500, stall=trial % 2 == 1)
        poses = [np.block([[np.eye(3), x[:, None]], [np.zeros((1, 3)), np.ones((1, 1))]]) for x in p]
        for delta in (0.05, 0.3, 1.0, 4.0):
            ours = path_pairs(p, delta)
            assert ours == filter_pairs_by_path(poses, delta)
            assert len(ours) > 0 or delta == 4.0
    # steps of 0.1 m (their sums round either side of 0.3 and 1.0) with standstills of up to 12 poses
    grid = np.repeat(np.arange(300)[:, None] * [[0.1, 0.0, 0.0]], rng.integers(1, 13, 300), axis=0)
    poses = [np.block([[np.eye(3), x[:, None]], [np.zeros((1, 3)), np.ones((1, 1))]]) for x in grid]
    for delta in (0.3, 1.0, 0.7):
        assert path_pairs(grid, delta) == filter_pairs_by_path(poses, delta)
    assert path_pairs(np.zeros((5, 3)), 1.0) == []  # standing still: no pair, as evo
    assert path_pairs(np.zeros((1, 3)), 1.0) == []


def test_umeyama_is_evos_and_refuses_where_evo_does():
    from evo.core.geometry import GeometryException as EvoGeometryException
    from evo.core.geometry import umeyama_alignment

    rng = np.random.default_rng(4)
    x = rng.normal(0, 2, (400, 3))
    R = Rotation.from_rotvec([0.3, -0.2, 1.1]).as_matrix()
    for flip in (1.0, -1.0):  # a reflection in the data: evo's sign correction
        y = (x * [1, 1, flip]) @ R.T + [1.0, -2.0, 0.5] + rng.normal(0, 0.05, x.shape)
        r, t = umeyama(x, y)
        r_evo, t_evo, _ = umeyama_alignment(x.T, y.T)
        assert np.abs(r - r_evo).max() < 1e-12 and np.abs(t - t_evo).max() < 1e-12
        assert np.linalg.det(r) == pytest.approx(1.0)
    line = np.outer(np.linspace(0, 1, 50), [1.0, 2.0, 0.5])  # a straight line fixes no rotation about itself
    with pytest.raises(EvoGeometryException):
        umeyama_alignment(line.T, (line + 1.0).T)
    with pytest.raises(GeometryException):
        umeyama(line, line + 1.0)


def test_origin_alignment_is_evos():
    from evo.core import metrics, sync
    from evo.core.trajectory import PoseTrajectory3D
    from evo.core.units import Unit

    rng = np.random.default_rng(5)
    n = 500
    stamps = (np.arange(n) * 1e8).astype(np.int64)
    truth = Trajectory(stamps, _walk(rng, n, stall=False), Rotation.random(n, random_state=6).as_quat())
    drift = Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.002, (n, 3)), axis=0))
    estimate = Trajectory(
        stamps,
        truth.positions + np.cumsum(rng.normal(0, 0.01, (n, 3)), axis=0) + [3.0, 1.0, -1.0],
        (drift * Rotation.from_quat(truth.orientations)).as_quat(),
    )

    def evo(t):
        return PoseTrajectory3D(t.positions, t.orientations[:, [3, 0, 1, 2]], t.stamps * 1e-9)

    ref, est = sync.associate_trajectories(evo(truth), evo(estimate), max_diff=0.05)
    est.align_origin(ref)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    rpe = metrics.RPE(metrics.PoseRelation.translation_part, delta=1.0, delta_unit=Unit.meters)
    rpe.process_data((ref, est))
    ours = trajectory_errors(estimate, truth, alignment="origin")
    assert ours.ate_rmse_m > 0.05
    assert abs(ours.ate_rmse_m - ape.get_statistic(metrics.StatisticsType.rmse)) < 1e-12
    assert abs(ours.rpe_rmse_m - rpe.get_statistic(metrics.StatisticsType.rmse)) < 1e-12
    assert abs(ours.ate_max_m - ape.get_statistic(metrics.StatisticsType.max)) < 1e-12
