"""The gyro's bias as a state of the graph (issue 21, stop 43): G(k) per keyframe (3-vector, body axes),
a prior at keyframe 0 and a random walk between keyframes, and the gyro factor between consecutive
keyframes with the rates integrated at the bias b̄ and corrected to first order (ΔR(b) ≈ ΔR̄ Exp(J_b (b − b̄)),
as IMU preintegration does)."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from factors.geometry import so3_exp, so3_log
from factors.navigation import GYRO_BIAS_UNIT_S, gyro_rotation_factor, gyro_rotation_residual
from semslam.backend.graph import GraphEstimator
from semslam.backend.navigation import NavigationBuffer
from semslam.backend.window import G, X
from semslam.compare import estimators_input
from semslam.config import SemslamConfig
from semslam.mission.measurements import Attitude, GroundTruthPose
from semslam.pipeline import run_pipeline
from semslam.sim.dive import DiveSimConfig, simulate_dive
from tests.test_factors_jacobians import check_factor_jacobians
from tests.test_graph_gyro import metadata

S = 1_000_000_000
# A short dive (two survey lines, ~3.7 min) with the AHRS's heading unbiased (no heading-bias drift, so
# that its heading is the reference the gyro's z bias is seen against) and a gyro bias drawn ten times
# the simulators' default (5e-4 rad/s, ~100°/h, a consumer MEMS rate sensor's): large against what the
# dive can resolve (σ ≈ 3e-5 rad/s at the end), so that a graph without the state is clearly off. The AHRS is
# mounted upside down and turned 90° (its x along the body's y, its z along the body's −z), so that G, in body
# axes, differs from the drawn bias, in the AHRS's axes, on every axis.
AHRS_RPY_DEG = (180.0, 0.0, 90.0)
DIVE = {
    "trajectory": {"lines": 2},
    "dive": {"surface_start_s": 20.0, "surface_end_s": 20.0},
    "ahrs": {
        "heading_bias_drift_deg": 0.0,
        "gyro_bias_sigma_rad_s": 5e-4,
        "mount": {"rpy_deg": AHRS_RPY_DEG},
    },
}


def _random_values(rng) -> gtsam.Values:
    v = gtsam.Values()
    v.insert(X(0), gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3)))
    v.insert(X(1), gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3)))
    v.insert(G(0), rng.normal(size=3) * 0.05)
    return v


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gyro_factor_jacobians_against_numerical_derivatives(seed):
    rng = np.random.default_rng(seed)
    R_ij = so3_exp(rng.normal(size=3) * 0.3)
    J_b = rng.normal(size=(3, 3)) * 2.0  # large: the bias's correction is far from zero
    b_bar = rng.normal(size=3) * 0.05
    f = gyro_rotation_factor(X(0), X(1), G(0), R_ij, J_b, b_bar, 0.1)
    values = _random_values(rng)
    check_factor_jacobians(f, values)
    # the residual: Log((ΔR̄ Exp(J_b (g − b̄)/τ))ᵀ R_iᵀ R_j)
    Ri, Rj = values.atPose3(X(0)).rotation().matrix(), values.atPose3(X(1)).rotation().matrix()
    dR = R_ij @ so3_exp(J_b @ (values.atVector(G(0)) - b_bar) / GYRO_BIAS_UNIT_S)
    np.testing.assert_allclose(f.unwhitenedError(values), so3_log(dR.T @ Ri.T @ Rj), atol=1e-9)
    r = gyro_rotation_residual(values.atPose3(X(0)), values.atPose3(X(1)), values.atVector(G(0)), R_ij, J_b, b_bar)
    np.testing.assert_allclose(r, f.unwhitenedError(values), atol=1e-12)


def _integrated(rates: np.ndarray, bias: np.ndarray):
    """The NavigationBuffer's integral of 20 Hz body rates ``rates`` over 1 s at the bias ``bias`` (rad/s)."""
    nav = NavigationBuffer(metadata(), 0.02, 1e-4)
    acov = np.eye(3) * 1e-4
    q = np.array([0, 0, 0, 1.0])
    nav.add(Attitude(0, "ahrs", orientation=q, covariance=acov, angular_rate=rates[0]))
    nav.start_interval(0.0, np.eye(3), 0.01, gyro_bias=bias)
    for k in range(1, len(rates)):
        nav.add(Attitude(k * S // 20, "ahrs", orientation=q, covariance=acov, angular_rate=rates[k]))
    return nav.gyro_rotation(1.0)


def test_the_integrations_bias_jacobian_is_the_first_order_change():
    """ΔR(b̄ + δ) = ΔR(b̄) Exp(J δ) + O(δ²): the integral's Jacobian against integrating again at b̄ + δ."""
    rng = np.random.default_rng(3)
    rates = np.array([0.05, -0.2, 0.6]) + 0.3 * rng.normal(size=(20, 3))
    b_bar = np.array([0.01, -0.02, 0.005])
    R0, h, J = _integrated(rates, b_bar)
    assert h == pytest.approx(1.0)
    for scale in (1e-3, 1e-4):
        d = rng.normal(size=3) * scale
        R1, _, _ = _integrated(rates, b_bar + d)
        first = so3_log((R0 @ so3_exp(J @ d)).T @ R1)
        zeroth = so3_log(R0.T @ R1)
        assert np.linalg.norm(first) < 0.01 * np.linalg.norm(zeroth), (scale, first, zeroth)
    # the bias is subtracted from the rates: at the mean rate, no rotation
    R_mean, _, _ = _integrated(np.tile(rates.mean(axis=0), (20, 1)), rates.mean(axis=0))
    np.testing.assert_allclose(R_mean, np.eye(3), atol=1e-12)


def _run(mission, gyro_bias_sigma):
    config = SemslamConfig(sensors={"gyro_bias_sigma_rad_s": gyro_bias_sigma})
    est = GraphEstimator(mission.metadata, config)
    result = run_pipeline(estimators_input(mission, config), [est], [], keep_observations=False)
    return est, result.results["graph"].trajectory


def _yaw_rms(mission, traj) -> float:
    gt = [m for m in mission if isinstance(m, GroundTruthPose)]
    t = np.array([m.stamp for m in gt])
    yaw = np.unwrap(Rotation.from_quat([m.orientation for m in gt]).as_euler("ZYX")[:, 0])
    err = Rotation.from_quat(traj.orientations).as_euler("ZYX")[:, 0] - np.interp(traj.stamps, t, yaw)
    return float(np.sqrt(np.mean(np.angle(np.exp(1j * err)) ** 2)))


@pytest.mark.parametrize("seed", [0, 1])
def test_the_graph_learns_a_drawn_gyro_bias(seed):
    mission = simulate_dive(DiveSimConfig.model_validate({"seed": seed, **DIVE}))
    R_BS = mission.metadata.extrinsic("ahrs")[:3, :3]
    np.testing.assert_allclose(R_BS, Rotation.from_euler("ZYX", AHRS_RPY_DEG[::-1], degrees=True).as_matrix())
    truth = R_BS @ np.array(mission.metadata.extras["gyro_bias_rad_s"])  # the drawn bias (AHRS axes) in {B}, G's
    est, traj = _run(mission, None)  # the declared σ
    kf = est.keyframes
    assert kf.has_gyro_bias
    g = kf.gyro_bias / GYRO_BIAS_UNIT_S
    sd = np.sqrt(np.diag(kf.state_cov[-3:, -3:])) / GYRO_BIAS_UNIT_S
    z = (g - truth) / sd
    assert np.all(np.abs(z) < 3.0), (g, truth, sd)
    assert abs(truth[2]) > 5 * sd[2]  # taking the rates as unbiased (G = 0) is clearly off
    # without the state: no G, the gyro link without its bias, and the heading off (the bias integrated between keyframes)
    est0, traj0 = _run(mission, 0.0)
    assert not est0.keyframes.has_gyro_bias
    assert not any(gtsam.Symbol(k).chr() == ord("g") for k in est0.session.window_keys())
    with_state, without = _yaw_rms(mission, traj), _yaw_rms(mission, traj0)
    assert without > 1.15 * with_state, (with_state, without)  # measured 0.87 / 1.14 and 0.79 / 0.98 mrad


def test_the_window_takes_the_gyro_bias_with_its_keyframe():
    # a window shorter than the dive: every G that left it went with its keyframe (marginalised into the
    # prior on what stays, frozen beside its pose), and the window holds exactly its keyframes' G's
    mission = simulate_dive(DiveSimConfig.model_validate({"seed": 0, **DIVE}))
    config = SemslamConfig(graph={"window_s": 40.0}, association={"track_timeout_s": 10.0})
    est = GraphEstimator(mission.metadata, config)
    run_pipeline(estimators_input(mission, config), [est], [], keep_observations=False)
    kf, window = est.keyframes, est.keyframes.window
    assert window.first_active > 0
    in_window = {k for k in est.session.window_keys() if gtsam.Symbol(k).chr() == ord("g")}
    assert in_window == {G(i) for i in range(window.first_active, len(kf))}
    frozen = gtsam.Values()
    window.frozen.insert_into(frozen)
    assert all(frozen.exists(G(i)) for i in range(window.first_active))
