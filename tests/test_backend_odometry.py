"""Relative-pose observations (e.g. sonar swath registrations) in the graph, between stamps that
need not be keyframes, and the front-end ``finish`` hook of the pipeline."""

import numpy as np
import pytest

from semslam.backend.graph import GraphEstimator
from semslam.config import SemslamConfig
from semslam.mission.measurements import GroundTruthPose, PointCloud
from semslam.observations import OdometryObservation
from semslam.pipeline import run_pipeline
from semslam.registry import FrontendSummary
from tests.support.synthetic_mission import SyntheticConfig, ground_truth_positions, position_errors, simulate


class TrueRelativePose:
    """At every laser stamp, the true relative pose from a ground-truth stamp ``lag_s`` earlier."""

    name = "relative"
    consumes = (PointCloud, GroundTruthPose)

    def __init__(self, lag_s: float, sigma_m: float = 0.01, sigma_rad: float = 0.002, sensor: str = "relative"):
        self.lag_ns = int(lag_s * 1e9)
        self.sensor = sensor
        self.poses: dict[int, np.ndarray] = {}
        self.cov = np.diag([sigma_rad**2] * 3 + [sigma_m**2] * 3)
        self.finished = False
        self.froms: list[int] = []

    def process(self, m, view):
        if isinstance(m, GroundTruthPose):
            self.poses[m.stamp] = m.matrix()
            return []
        if not self.poses:
            return []
        # ground-truth stamps off the navigation sensors' 200 ms grid, where keyframes sit
        past = [s for s in self.poses if s <= m.stamp - self.lag_ns and (s // 50_000_000) % 4 == 1]
        now = max(self.poses)
        if not past:
            return []
        s_from = max(past)
        self.froms.append(s_from)
        rel = np.linalg.inv(self.poses[s_from]) @ self.poses[now]
        return [OdometryObservation(now, self.sensor, stamp_from=s_from, relative_pose=rel, covariance=self.cov)]

    def finish(self, view):
        self.finished = True
        return FrontendSummary(section="relative", metrics={"n_poses": len(self.poses)})


def _ate(result, mission):
    gs, gp = ground_truth_positions(mission)
    e = position_errors(result.trajectory.stamps, result.trajectory.positions, gs, gp)
    return float(np.sqrt(np.mean(e**2)))


@pytest.fixture(scope="module")
def drifting_mission():
    # A long DVL dropout: dead reckoning drifts, relative poses across it bound the drift.
    return simulate(
        SyntheticConfig(duration_s=75.0, n_objects=0, n_pipes=0, n_structures=0, dropouts=((20.0, 40.0),), seed=5)
    )


def test_relative_poses_between_non_keyframe_stamps_bound_the_drift(drifting_mission):
    cfg = SemslamConfig()
    plain = run_pipeline(drifting_mission, [GraphEstimator(drifting_mission.metadata, cfg)])
    fe = TrueRelativePose(lag_s=20.0)
    est = GraphEstimator(drifting_mission.metadata, cfg)
    with_odom = run_pipeline(drifting_mission, [est], [fe])
    r0, r1 = plain.results["graph"], with_odom.results["graph"]
    assert not any("dropped" in d for d in r1.diagnostics)
    # most relative poses start between keyframes: they were carried to the nearest one
    assert np.mean([s not in set(est.keyframes.stamps) for s in fe.froms]) > 0.5
    assert _ate(r1, drifting_mission) < 0.5 * _ate(r0, drifting_mission)
    # the front-end's last word reaches the result
    assert fe.finished and with_odom.frontend_summaries["relative"].metrics["n_poses"] > 100


class OneWrongRegistration(TrueRelativePose):
    """True relative poses measured by the laser, the ``wrong``-th of them shifted by 1 m: a
    registration that converged wrong with a confident covariance."""

    name = "laser_odometry"

    def __init__(self, wrong: int, **kw):
        super().__init__(sensor="laser", **kw)
        self.wrong = wrong

    def process(self, m, view):
        out = super().process(m, view)
        if out and len(self.froms) == self.wrong:
            z = out[0]
            rel = z.relative_pose.copy()
            rel[:3, 3] += rel[:3, :3] @ [0.0, 1.0, 0.0]
            out = [
                OdometryObservation(
                    z.stamp, z.sensor, stamp_from=z.stamp_from, relative_pose=rel, covariance=z.covariance
                )
            ]
        return out


def test_robust_odometry_factor_bounds_the_pull_of_a_wrong_registration(drifting_mission):
    def track(kernel_k: dict, wrong: int):
        cfg = SemslamConfig.model_validate({"graph": {"odometry_cauchy_k": kernel_k}})
        est = GraphEstimator(drifting_mission.metadata, cfg)
        tr = (
            run_pipeline(drifting_mission, [est], [OneWrongRegistration(wrong, lag_s=20.0)]).results["graph"].trajectory
        )
        return tr.stamps, tr.positions

    def pull(a, b):  # how far the wrong registration moved the track
        assert np.array_equal(a[0], b[0])
        return float(np.max(np.linalg.norm(a[1] - b[1], axis=1)))

    robust_clean = track({"laser": 5.3}, wrong=-1)
    gaussian_clean = track({}, wrong=-1)
    robust = track({"laser": 5.3}, wrong=20)
    gaussian = track({}, wrong=20)
    # without the m-estimator the 1 m registration (σ 1 cm) drags the track by decimetres; with it, by millimetres
    assert pull(gaussian, gaussian_clean) > 0.3
    assert pull(robust, robust_clean) < 0.03
