"""Tentative landmarks (tracks) of the graph: a scan's unpaired views continue them one-to-one by
the assignment of least total cost, so that a missed object in a row of them does not shift every
view into its neighbour's track."""

import gtsam
import numpy as np

from semslam.backend import GraphEstimator
from semslam.config import SemslamConfig
from semslam.observations import PointObservation
from tests.support.synthetic_mission import SyntheticConfig, simulate

ROW = [np.array([x, 0.0, 3.0]) for x in (0.0, 0.3, 0.6)]  # three objects 30 cm apart, seen from the origin


def _scan(est, k, seen):
    obs = [PointObservation(k, "laser", position=ROW[i], covariance=np.eye(3) * 0.03**2, truth_id=i) for i in seen]
    est._current_obs, est._ambiguous = obs, set()
    pose_cov = np.diag([1e-6] * 3 + [0.06**2] * 3)  # the first seconds' pose σ: 6 cm
    est._extend_tracks(k, k, [(z, np.eye(4)) for z in obs], gtsam.Pose3(), pose_cov, [], gtsam.Values())


def test_a_missed_object_does_not_shift_the_row_of_tracks():
    mission = simulate(SyntheticConfig(duration_s=5.0, seed=0))
    est = GraphEstimator(mission.metadata, SemslamConfig(association={"min_observations": 10}))
    _scan(est, 1, [1, 2])  # object 0 missed
    # object 2 missed: both views fit the two tracks shifted by one (each 30 cm, inside the gate);
    # greedily, or by an assignment that must pair as many as it can, 0 takes 1's track, 1 takes 2's
    _scan(est, 2, [0, 1])
    _scan(est, 3, [0, 1, 2])
    tracks = {tuple(sorted({r.observation.truth_id for r in tr.records})): len(tr.records) for tr in est.tracks}
    assert tracks == {(0,): 2, (1,): 3, (2,): 2}
