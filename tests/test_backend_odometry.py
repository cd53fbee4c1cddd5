"""Relative-pose observations (e.g. sonar swath registrations) in the graph, between stamps that
need not be keyframes, and the front-end ``finish`` hook of the pipeline."""

from dataclasses import replace

import numpy as np
import pytest

from factors.geometry import so3_exp
from factors.navigation import GYRO_BIAS_UNIT_S
from semslam.backend.graph import GraphEstimator
from semslam.config import SemslamConfig
from semslam.mission.measurements import Attitude, GroundTruthPose, PointCloud
from semslam.mission.mission import Mission
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


class HeldRotation(TrueRelativePose):
    """Laser odometry whose rotation is the gyro's rates integrated between its stamps with the rates' bias
    (``bias_B``, body axes, rad/s) in them: the true relative pose turned by Exp(b·T) on its right."""

    name = "laser_odometry"

    def __init__(self, bias_B, **kw):
        super().__init__(sensor="laser", **kw)
        self.bias_B = np.asarray(bias_B, float)

    def process(self, m, view):
        out = super().process(m, view)
        if not out:
            return out
        z = out[0]
        rel = z.relative_pose.copy()
        rel[:3, :3] = rel[:3, :3] @ so3_exp(self.bias_B * (z.stamp - z.stamp_from) * 1e-9)
        return [
            OdometryObservation(z.stamp, z.sensor, stamp_from=z.stamp_from, relative_pose=rel, covariance=z.covariance)
        ]


def test_held_rotations_take_the_graphs_gyro_bias():
    """Rates biased by 4e-4 rad/s (body z; 8e-4 rad over a factor's ~2 s) in the AHRS and in the odometry's held
    rotation (σ 3e-4 rad per factor): with the factor through G (``graph.odometry_gyro_bias: [laser]``) the
    graph's bias stays within 3σ of the truth; as a plain relative pose (the kind not listed: the default) the
    odometry says the bias is not there and pulls G away from it."""
    base = simulate(SyntheticConfig(duration_s=120.0, n_objects=0, n_pipes=0, n_structures=0, seed=3))
    R_BS = base.metadata.extrinsic("ahrs")[:3, :3]
    bias_B = np.array([1e-4, -1e-4, 4e-4])
    items = [replace(m, angular_rate=m.angular_rate + R_BS.T @ bias_B) if isinstance(m, Attitude) else m for m in base]
    mission = Mission.from_measurements(base.metadata, items)

    def bias_error(kinds: list[str]) -> tuple[np.ndarray, np.ndarray]:  # the graph's at the end, its σ
        cfg = SemslamConfig.model_validate(
            {"sensors": {"gyro_bias_sigma_rad_s": 5e-4}, "graph": {"odometry_gyro_bias": kinds}}
        )
        est = GraphEstimator(mission.metadata, cfg)
        run_pipeline(mission, [est], [HeldRotation(bias_B, lag_s=2.0, sigma_rad=3e-4)], keep_observations=False)
        kf = est.keyframes
        assert kf.has_gyro_bias
        sd = np.sqrt(np.diag(kf.state_cov)[-3:]) / GYRO_BIAS_UNIT_S
        return kf.gyro_bias / GYRO_BIAS_UNIT_S - bias_B, sd

    err, sd = bias_error(["laser"])
    assert np.all(np.abs(err) < 3 * sd), (err, sd)  # measured z −5.3e-5 at σ 1.9e-4
    err_plain, _ = bias_error([])
    # measured z −3.1e-4: the estimate a quarter of the bias, and 6× the error through G
    assert abs(err_plain[2]) > 0.5 * bias_B[2], err_plain
    assert abs(err_plain[2]) > 3 * abs(err[2]), (err, err_plain)
