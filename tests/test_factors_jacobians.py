"""Every domain factor's Jacobians against central differences of its whitened error, at random
states and near the singular configurations of the parametrisations."""

import gtsam
import numpy as np
import pytest

from factors.geometry import so3_exp
from factors.landmarks import (
    LineAnchor,
    line_factor,
    line_observation_covariance,
    line_residual,
    point_factor,
    point_residual,
    point_residual_at,
    structure_factor,
    structure_residual,
)
from factors.navigation import (
    MIN_DISPLACEMENT_SIGMA_M,
    DvlPreintegrator,
    ahrs_body_rotation,
    attitude_factor,
    depth_factor,
    displacement_factor,
    dvl_residual,
    dvl_to_body,
    dvl_velocity_factor,
    smoothed_displacement_factor,
)

RNG = np.random.default_rng(7)


def random_pose(rng, scale=5.0) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3) * scale)


def random_extrinsic(rng) -> np.ndarray:
    return random_pose(rng, 0.5).matrix()


def random_cov(rng, n, scale=0.05):
    A = rng.normal(size=(n, n)) * scale
    return A @ A.T + np.eye(n) * scale**2


def _perturbed(values: gtsam.Values, key: int, k: int, h: float) -> gtsam.Values:
    out = gtsam.Values(values)
    try:
        pose = values.atPose3(key)
        delta = np.zeros(6)
        delta[k] = h
        out.update(key, pose.retract(delta))
    except RuntimeError:
        vec = np.array(values.atVector(key), dtype=float)
        vec[k] += h
        out.update(key, vec)
    return out


def _dim(values, key) -> int:
    try:
        values.atPose3(key)
        return 6
    except RuntimeError:
        return len(values.atVector(key))


def check_factor_jacobians(factor, values: gtsam.Values, h=1e-6, atol=1e-5, rtol=1e-4):
    """Compare the whitened Jacobian of ``factor.linearize`` with central differences."""
    jf = factor.linearize(values)
    A, _ = jf.jacobian()
    col = 0
    for key in factor.keys():
        n = _dim(values, key)
        num = np.zeros((A.shape[0], n))
        for k in range(n):
            ep = factor.whitenedError(_perturbed(values, key, k, h))
            em = factor.whitenedError(_perturbed(values, key, k, -h))
            num[:, k] = (ep - em) / (2 * h)
        # linearize returns −(whitened error) in b and the Jacobian in A (same sign as the error).
        np.testing.assert_allclose(A[:, col : col + n], num, atol=atol, rtol=rtol, err_msg=f"key {key}")
        col += n


@pytest.mark.parametrize("seed", range(5))
def test_point_factor_jacobians(seed):
    """The built-in bearing-range factor: GTSAM's Jacobians hold where the bearing residual is
    small (it takes the derivative of Unit3's local coordinates as the identity), so they are
    checked at a state 1 mm from the measurement, as the graph's states are after a few views."""
    rng = np.random.default_rng(seed)
    T, T_BS = random_pose(rng), random_extrinsic(rng)
    l = rng.normal(size=3) * 5
    z = point_residual(T, l, T_BS, np.zeros(3)) + rng.normal(size=3) * 0.001
    f = point_factor(1, 2, z, random_cov(rng, 3) * 1e-2, T_BS)
    v = gtsam.Values()
    v.insert(1, T)
    v.insert(2, l)
    scale = np.abs(f.linearize(v).jacobian()[0]).max()
    check_factor_jacobians(f, v, atol=1e-3 * scale, rtol=1e-3)
    # And the residual vanishes at the true landmark.
    assert np.allclose(point_residual(T, l, T_BS, point_residual(T, l, T_BS, np.zeros(3))), 0)
    f0 = point_factor(1, 2, point_residual(T, l, T_BS, np.zeros(3)), np.eye(3) * 1e-4, T_BS)
    assert np.allclose(f0.whitenedError(v), 0, atol=1e-6)


@pytest.mark.parametrize("seed", range(5))
def test_point_factor_matches_the_cartesian_residual(seed):
    """Its whitened error equals the Cartesian one of point_residual with the sensor-frame
    covariance, to first order: within 3 % for errors of a few σ at ranges of metres."""
    rng = np.random.default_rng(seed)
    T, T_BS = random_pose(rng), random_extrinsic(rng)
    l = T.transformFrom(T_BS[:3, :3] @ (rng.normal(size=3) + np.array([0, 0, 3.0])) + T_BS[:3, 3])
    cov = random_cov(rng, 3) * 1e-4
    z = point_residual(T, l, T_BS, np.zeros(3))
    L = np.linalg.cholesky(np.linalg.inv(cov))
    for _ in range(5):
        dz = rng.multivariate_normal(np.zeros(3), cov) * 3
        f = point_factor(1, 2, z + dz, cov, T_BS)
        v = gtsam.Values()
        v.insert(1, T)
        v.insert(2, l)
        e_cart = L.T @ point_residual(T, l, T_BS, z + dz)
        assert np.linalg.norm(f.whitenedError(v)) == pytest.approx(np.linalg.norm(e_cart), rel=0.03)


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("tilt", [0.0, 1e-9, 0.4, 2.5])
def test_line_factor_jacobians(seed, tilt):
    """tilt = |(α, β)|: 0 and 1e-9 exercise the Exp/J_r small-angle branch, 2.5 rad nears the
    chart's singular boundary at π."""
    rng = np.random.default_rng(seed)
    T, T_BS = random_pose(rng), random_extrinsic(rng)
    anchor = LineAnchor.from_points(rng.normal(size=3) * 3, rng.normal(size=3) * 3)
    ang = rng.uniform(0, 2 * np.pi)
    theta = np.array([tilt * np.cos(ang), tilt * np.sin(ang), *rng.normal(size=2)])
    # Observed endpoints: two points of the line (plus noise), expressed in the sensor frame.
    T_WS = T.compose(gtsam.Pose3(T_BS))
    ends_W = [anchor.point(theta) + s * anchor.direction(theta) for s in (-1.3, 0.8)]
    p_S, q_S = (T_WS.transformTo(e) + rng.normal(size=3) * 0.02 for e in ends_W)
    cov4 = line_observation_covariance(T, theta, anchor, T_BS, random_cov(rng, 6, 0.02))
    f = line_factor(1, 2, anchor, p_S, q_S, cov4, T_BS)
    v = gtsam.Values()
    v.insert(1, T)
    v.insert(2, theta)
    check_factor_jacobians(f, v, atol=2e-5)


def test_line_single_observation_is_full_rank():
    """One segment determines the 4-DoF line: no gauge freedom, information matrix rank 4."""
    rng = np.random.default_rng(3)
    T, T_BS = random_pose(rng), random_extrinsic(rng)
    p_W, q_W = np.array([1.0, 2.0, 3.0]), np.array([1.5, 2.0, 3.0])
    anchor = LineAnchor.from_points(p_W, q_W)
    T_WS = T.compose(gtsam.Pose3(T_BS))
    _, _, H_l = line_residual(T, np.zeros(4), anchor, T_BS, T_WS.transformTo(p_W), T_WS.transformTo(q_W), jac=True)
    assert np.linalg.matrix_rank(H_l.T @ H_l, tol=1e-9) == 4
    # ... and the residual of the exact line is zero.
    r = line_residual(T, np.zeros(4), anchor, T_BS, T_WS.transformTo(p_W), T_WS.transformTo(q_W))
    assert np.allclose(r, 0, atol=1e-12)


def test_line_residual_ignores_sliding_along_the_line():
    rng = np.random.default_rng(4)
    T, T_BS = random_pose(rng), random_extrinsic(rng)
    anchor = LineAnchor.from_points(np.zeros(3), np.array([0.0, 0.0, 1.0]))
    theta = np.array([0.1, -0.2, 0.3, 0.4])
    d, c = anchor.direction(theta), anchor.point(theta)
    T_WS = T.compose(gtsam.Pose3(T_BS))
    r1 = line_residual(T, theta, anchor, T_BS, T_WS.transformTo(c + 0.1 * d), T_WS.transformTo(c + 0.2 * d))
    r2 = line_residual(T, theta, anchor, T_BS, T_WS.transformTo(c - 3 * d), T_WS.transformTo(c + 5 * d))
    assert np.allclose(r1, 0, atol=1e-12) and np.allclose(r2, 0, atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_structure_factor_and_residual_jacobians(seed):
    rng = np.random.default_rng(seed)
    T, M, T_BS = random_pose(rng), random_pose(rng), random_extrinsic(rng)
    T_WS = T.compose(gtsam.Pose3(T_BS))
    T_S_model = T_WS.between(M).compose(
        gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3) * 0.05), rng.normal(size=3) * 0.05)
    )
    cov = random_cov(rng, 6, 0.05)
    f = structure_factor(1, 2, T_S_model.matrix(), cov, T_BS)
    v = gtsam.Values()
    v.insert(1, T)
    v.insert(2, M)
    check_factor_jacobians(f, v)
    # The association residual is the factor's unwhitened error, with its Jacobians.
    err, H_x, H_m = structure_residual(T, M, T_BS, T_S_model.matrix(), jac=True)
    np.testing.assert_allclose(err, f.unwhitenedError(v), atol=1e-10)
    L = np.linalg.cholesky(np.linalg.inv(cov)).T
    A, _ = f.linearize(v).jacobian()
    np.testing.assert_allclose(A, L @ np.hstack([H_x, H_m]), atol=1e-8)


@pytest.mark.parametrize("seed", range(4))
def test_depth_factor_jacobians(seed):
    rng = np.random.default_rng(seed)
    T = random_pose(rng)
    f = depth_factor(1, 3.0, 0.01**2, rng.normal(size=3) * 0.3)
    v = gtsam.Values()
    v.insert(1, T)
    check_factor_jacobians(f, v)


def test_depth_factor_uses_lever_arm():
    T = gtsam.Pose3(gtsam.Rot3.Roll(np.pi / 2), np.array([0.0, 0.0, 5.0]))  # rolled 90°: body y points down
    f = depth_factor(1, 5.5, 1e-4, np.array([0.0, 0.5, 0.0]))
    v = gtsam.Values()
    v.insert(1, T)
    assert abs(f.unwhitenedError(v)[0]) < 1e-12


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("kind", ["gap", "samples", "smoothed"])
def test_displacement_factor_jacobians(seed, kind):
    """The displacement factor over a dropout and over samples, and the smoothed interval's factor."""
    rng = np.random.default_rng(seed)
    Ti = random_pose(rng)
    pre = DvlPreintegrator(0.0, Ti.rotation().matrix(), accel_sigma=0.05, attitude_sigma=0.01)
    if kind != "gap":
        for t in np.arange(0.2, 1.0, 0.2):
            R = Ti.rotation().matrix() @ so3_exp(rng.normal(size=3) * 0.05)
            pre.add(t, R, rng.normal(size=3) * 0.3, random_cov(rng, 3, 0.01))
    Rj = Ti.rotation().matrix() @ so3_exp(rng.normal(size=3) * 0.05)
    d = pre.integrate(1.1, Rj)
    assert d.n_samples == (0 if kind == "gap" else 4)
    if kind == "smoothed":
        f = smoothed_displacement_factor(1, 2, 3, 4, pre.smoothed(1.1, Rj))
    else:
        f = displacement_factor(1, 2, 3, 4, d)
    v = gtsam.Values()
    v.insert(1, Ti)
    v.insert(2, gtsam.Pose3(gtsam.Rot3(Rj), Ti.translation() + rng.normal(size=3)))
    v.insert(3, rng.normal(size=3))
    v.insert(4, rng.normal(size=3))
    check_factor_jacobians(f, v)


def test_smoothed_interval_samples_inform_the_velocity_states():
    """Five samples of a constant velocity: the interval's Gaussian puts v_i, v_j and δ there, and
    v_i is known better than from one sample (the samples inform it; integrate() leaves it free)."""
    v, sigma = np.array([0.1, -0.02, 0.05]), 0.01
    pre = DvlPreintegrator(0.0, np.eye(3), accel_sigma=0.01)
    for t in np.arange(0.2, 1.0, 0.2):
        pre.add(t, np.eye(3), v, np.eye(3) * sigma**2)
    s = pre.smoothed(1.0, np.eye(3))
    np.testing.assert_allclose(s.z0, np.r_[v * 1.0, v, v], atol=1e-9)
    cov = np.linalg.inv(s.C_T.T @ s.C_T)
    assert cov[3, 3] < 0.6 * sigma**2 and cov[6, 6] < 0.6 * sigma**2


def test_smoothed_interval_with_a_sample_at_its_end_integrates_over_the_interval_only():
    """A keyframe made at a DVL sample's stamp (the sample is the interval's last knot, at t_j itself): the
    displacement of a constant velocity is v·Δt, not v·(Δt + 1 ms) — the floor that keeps the random walk's link
    to that knot finite must not lengthen the trapezoid (it did: a 0.1 % scale error per interval, which made the
    trajectory depend on how many keyframes fell on DVL stamps)."""
    v, sigma = np.array([0.25, -0.1, 0.02]), 0.01
    pre = DvlPreintegrator(0.0, np.eye(3), accel_sigma=0.02)
    for t in (0.2, 0.4, 0.6, 0.8, 1.0):
        pre.add(t, np.eye(3), v, np.eye(3) * sigma**2)
    s = pre.smoothed(1.0, np.eye(3))
    np.testing.assert_allclose(s.z0, np.r_[v * 1.0, v, v], atol=1e-9)


def test_preintegration_motion_model_uncertainty_grows_with_gap():
    """A dropout is bridged by the velocity states with σ² = σ_a² Δt³/12, not by a fixed velocity."""
    sig = []
    for gap in (1.0, 2.0, 4.0):
        d = DvlPreintegrator(0.0, np.eye(3), accel_sigma=0.05).integrate(gap, np.eye(3))
        assert np.allclose(d.c, 0) and np.allclose(d.A, gap / 2 * np.eye(3)) and np.allclose(d.B, gap / 2 * np.eye(3))
        sig.append(d.cov[0, 0])
    floor = MIN_DISPLACEMENT_SIGMA_M**2
    np.testing.assert_allclose(sig, [0.05**2 * g**3 / 12 + floor for g in (1.0, 2.0, 4.0)], rtol=1e-6)
    # two keyframes 37 ms apart are not tied tighter than the floor (iSAM2 found that indeterminate)
    short = DvlPreintegrator(0.0, np.eye(3), accel_sigma=0.05).integrate(0.037, np.eye(3))
    assert short.cov[0, 0] >= floor


def test_preintegration_recovers_constant_turn_displacement():
    """Constant body velocity on a constant yaw rate: the integral matches the exact arc."""
    v_B, w, T = np.array([0.5, 0.1, 0.0]), 0.2, 2.0
    pre = DvlPreintegrator(0.0, np.eye(3), accel_sigma=0.05)
    ts = np.arange(0.01, T, 0.01)
    for t in ts:
        pre.add(t, so3_exp(np.array([0, 0, w * t])), v_B, np.eye(3) * 1e-4)
    d = pre.integrate(T, so3_exp(np.array([0, 0, w * T])))
    pred = d.c + d.A @ v_B + d.B @ v_B
    # exact: ∫ Rz(wt) v dt
    exact = np.array(
        [
            (np.sin(w * T) * v_B[0] - (1 - np.cos(w * T)) * v_B[1]) / w,
            ((1 - np.cos(w * T)) * v_B[0] + np.sin(w * T) * v_B[1]) / w,
            0.0,
        ]
    )
    np.testing.assert_allclose(pred, exact, atol=1e-5)


@pytest.mark.parametrize("seed", range(4))
def test_dvl_factor_equals_lever_arm_residual(seed):
    """The built-in prior on v_B gives the same Mahalanobis norm as R_SB(v_B + ω×t_BS) − v_S."""
    rng = np.random.default_rng(seed)
    T_BS, cov_S, w = random_extrinsic(rng), random_cov(rng, 3, 0.01), rng.normal(size=3) * 0.3
    v_S = rng.normal(size=3)
    f = dvl_velocity_factor(1, v_S, cov_S, T_BS, w)
    for _ in range(3):
        v_B = rng.normal(size=3)
        vals = gtsam.Values()
        vals.insert(1, v_B)
        r = dvl_residual(v_B, v_S, T_BS, w)
        assert np.isclose(2 * f.error(vals), r @ np.linalg.solve(cov_S, r))
    v_B, _ = dvl_to_body(v_S, cov_S, T_BS, w)
    assert np.allclose(dvl_residual(v_B, v_S, T_BS, w), 0)


def test_attitude_factor_from_ahrs():
    rng = np.random.default_rng(5)
    R_BS = so3_exp(rng.normal(size=3) * 0.3)
    R_WB = so3_exp(np.array([0.1, -0.05, 1.2]))
    R_WS = R_WB @ R_BS
    R, cov = ahrs_body_rotation(R_WS, np.diag([1e-4, 1e-4, 4e-4]), R_BS)
    np.testing.assert_allclose(R, R_WB, atol=1e-12)
    f = attitude_factor(1, R, cov)
    v = gtsam.Values()
    v.insert(1, gtsam.Pose3(gtsam.Rot3(R_WB), np.array([5.0, 1, 2])))
    assert f.error(v) < 1e-18
    check_factor_jacobians(f, v)
    # A pure yaw error of δ costs δ²/σ_yaw², whatever the AHRS mounting.
    v2 = gtsam.Values()
    v2.insert(1, gtsam.Pose3(gtsam.Rot3(so3_exp(np.array([0, 0, 0.01])) @ R_WB), np.zeros(3)))
    assert np.isclose(2 * f.error(v2), 0.01**2 / 4e-4, rtol=0.05)


@pytest.mark.parametrize("seed", range(5))
def test_biased_attitude_factor_jacobians(seed):
    from factors.navigation import biased_attitude_factor, biased_attitude_residual

    rng = np.random.default_rng(seed)
    T = random_pose(rng)
    b = float(rng.normal(0, 0.05))
    R_meas = so3_exp(np.array([0, 0, b + 0.01])) @ T.rotation().matrix() @ so3_exp(rng.normal(0, 0.01, 3))
    f = biased_attitude_factor(1, 2, R_meas, random_cov(rng, 3, 0.01))
    v = gtsam.Values()
    v.insert(1, T)
    v.insert(2, np.array([b]))
    check_factor_jacobians(f, v)
    # The residual vanishes when the measurement is the true attitude turned by the bias.
    R_exact = so3_exp(np.array([0, 0, b])) @ T.rotation().matrix()
    assert np.allclose(biased_attitude_residual(T, b, R_exact), 0, atol=1e-12)
    # ... and a bias equal to the heading offset absorbs it exactly.
    assert np.allclose(biased_attitude_residual(T, b + 0.3, so3_exp(np.array([0, 0, 0.3])) @ R_exact), 0, atol=1e-12)


# --------------------------------------------------------------------------------------------
# The fast callbacks and built-in replacements give the reference residuals' numbers.


def _reference_factor(noise, keys, residual):
    """A CustomFactor straight from a reference residual function returning (r, [H...])."""

    def error(this, values, H):
        r, Hs = residual(values)
        if H is not None:
            for k, Hk in enumerate(Hs):
                H[k] = Hk
        return r

    return gtsam.CustomFactor(noise, keys, error)


def assert_same_linearization(f, ref, v):
    np.testing.assert_allclose(f.whitenedError(v), ref.whitenedError(v), rtol=1e-12, atol=1e-9)
    A, b = f.linearize(v).jacobian()
    A_ref, b_ref = ref.linearize(v).jacobian()
    np.testing.assert_allclose(A, A_ref, rtol=1e-10, atol=1e-8 * max(1.0, np.abs(A_ref).max()))
    np.testing.assert_allclose(b, b_ref, rtol=1e-10, atol=1e-9)


@pytest.mark.parametrize("seed", range(6))
def test_depth_factor_builtin_equals_depth_residual(seed):
    """GPSFactorArm with precisions (0, 0, 1/σ²): whitened error (0, 0, r/σ), r = depth_residual,
    and Jacobian (0, 0, H/σ) at random states and lever arms."""
    from factors.navigation import depth_residual

    rng = np.random.default_rng(seed)
    t_BS, sigma = rng.normal(size=3) * 0.5, 0.01 + rng.uniform() * 0.1
    depth = rng.uniform(0, 50)
    f = depth_factor(1, depth, sigma**2, t_BS)
    for _ in range(5):
        T = random_pose(rng, 20.0)
        v = gtsam.Values()
        v.insert(1, T)
        r, H = depth_residual(T, t_BS, depth, jac=True)
        np.testing.assert_allclose(f.whitenedError(v), [0.0, 0.0, r[0] / sigma], rtol=1e-12, atol=1e-9)
        assert 2 * f.error(v) == pytest.approx((r[0] / sigma) ** 2, rel=1e-12)
        A, b = f.linearize(v).jacobian()
        np.testing.assert_allclose(A[:2], 0.0)
        np.testing.assert_allclose(A[2], H[0] / sigma, rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(b, [0.0, 0.0, -r[0] / sigma], rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("tilt", [0.0, 1e-9, 0.4, 2.5])
def test_line_factor_callback_equals_line_residual(seed, tilt):
    rng = np.random.default_rng(100 + seed)
    T, T_BS = random_pose(rng), random_extrinsic(rng)
    anchor = LineAnchor.from_points(rng.normal(size=3) * 3, rng.normal(size=3) * 3)
    ang = rng.uniform(0, 2 * np.pi)
    theta = np.array([tilt * np.cos(ang), tilt * np.sin(ang), *rng.normal(size=2)])
    p_S, q_S = rng.normal(size=3) * 2, rng.normal(size=3) * 2
    cov4 = random_cov(rng, 4, 0.02)
    robust = gtsam.noiseModel.mEstimator.Huber.Create(1.345)
    for rob in (None, robust):
        noise = gtsam.noiseModel.Gaussian.Covariance(cov4)
        noise = noise if rob is None else gtsam.noiseModel.Robust.Create(rob, noise)
        f = line_factor(1, 2, anchor, p_S, q_S, cov4, T_BS, rob)

        def res(vals):
            r, H_x, H_l = line_residual(vals.atPose3(1), vals.atVector(2), anchor, T_BS, p_S, q_S, jac=True)
            return r, (H_x, H_l)

        ref = _reference_factor(noise, [1, 2], res)
        for _ in range(3):
            v = gtsam.Values()
            v.insert(1, T.retract(rng.normal(size=6) * 0.1))
            v.insert(2, theta + rng.normal(size=4) * 0.05)
            assert_same_linearization(f, ref, v)


def _same_at_random_poses_and_velocities(f, ref, rng, n: int = 4) -> None:
    """``f`` and ``ref`` (on poses 1, 2 and velocities 3, 4) linearise alike at ``n`` random states."""
    for _ in range(n):
        v = gtsam.Values()
        v.insert(1, random_pose(rng))
        v.insert(2, random_pose(rng))
        v.insert(3, rng.normal(size=3))
        v.insert(4, rng.normal(size=3))
        assert_same_linearization(f, ref, v)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("gap", [False, True])
def test_displacement_factor_callback_equals_displacement_residual(seed, gap):
    from factors.navigation import displacement_residual

    rng = np.random.default_rng(200 + seed)
    Ti = random_pose(rng)
    pre = DvlPreintegrator(0.0, Ti.rotation().matrix(), accel_sigma=0.05, attitude_sigma=0.01)
    if not gap:
        for t in np.arange(0.2, 1.0, 0.2):
            pre.add(
                t,
                Ti.rotation().matrix() @ so3_exp(rng.normal(size=3) * 0.05),
                rng.normal(size=3) * 0.3,
                random_cov(rng, 3, 0.01),
            )
    d = pre.integrate(1.1, Ti.rotation().matrix() @ so3_exp(rng.normal(size=3) * 0.05))
    f = displacement_factor(1, 2, 3, 4, d)

    def res(vals):
        r, Hs = displacement_residual(vals.atPose3(1), vals.atPose3(2), vals.atVector(3), vals.atVector(4), d, jac=True)
        return r, Hs

    ref = _reference_factor(gtsam.noiseModel.Gaussian.Covariance(d.cov), [1, 2, 3, 4], res)
    _same_at_random_poses_and_velocities(f, ref, rng)


@pytest.mark.parametrize("seed", range(4))
def test_biased_attitude_factor_callback_equals_residual(seed):
    from factors.navigation import biased_attitude_factor, biased_attitude_residual

    rng = np.random.default_rng(300 + seed)
    R_meas = so3_exp(rng.normal(size=3))
    cov = random_cov(rng, 3, 0.01)
    f = biased_attitude_factor(1, 2, R_meas, cov)

    def res(vals):
        r, H_x, H_b = biased_attitude_residual(vals.atPose3(1), float(vals.atVector(2)[0]), R_meas, jac=True)
        return r, (H_x, H_b)

    ref = _reference_factor(gtsam.noiseModel.Gaussian.Covariance(cov), [1, 2], res)
    for _ in range(4):
        b = float(rng.normal(0, 0.3))
        v = gtsam.Values()
        v.insert(
            1,
            gtsam.Pose3(
                gtsam.Rot3(so3_exp(np.array([0, 0, -b])) @ R_meas @ so3_exp(rng.normal(size=3) * 0.3)),
                rng.normal(size=3),
            ),
        )
        v.insert(2, np.array([b]))
        assert_same_linearization(f, ref, v)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("bias_scale", [0.0, 1e-3, 30.0])
def test_gyro_factor_callback_equals_residual(seed, bias_scale):
    """The scalar callback against :func:`gyro_rotation_residual` (GTSAM's Expmap and Logmap with their
    Jacobians): the bias's correction at zero, of the size a mission has (its Exp by series), and large."""
    from factors.navigation import gyro_rotation_factor, gyro_rotation_residual

    rng = np.random.default_rng(400 + seed)
    R_ij, J_b = so3_exp(rng.normal(size=3) * 0.3), rng.normal(size=(3, 3)) * 2.0
    b_bar = rng.normal(size=3) * 0.05
    f = gyro_rotation_factor(1, 2, 3, R_ij, J_b, b_bar, 0.01)

    def res(vals):
        r, H_i, H_j, H_g = gyro_rotation_residual(
            vals.atPose3(1), vals.atPose3(2), vals.atVector(3), R_ij, J_b, b_bar, jac=True
        )
        return r, (H_i, H_j, H_g)

    ref = _reference_factor(gtsam.noiseModel.Isotropic.Sigma(3, 0.01), [1, 2, 3], res)
    for _ in range(4):
        v = gtsam.Values()
        v.insert(1, random_pose(rng))
        v.insert(2, random_pose(rng))
        v.insert(3, b_bar + rng.normal(size=3) * bias_scale)
        assert_same_linearization(f, ref, v)


@pytest.mark.parametrize("seed", range(4))
def test_smoothed_displacement_callback_equals_relative_position(seed):
    """The scalar callback against Cᵀ (z − z0) with δ and its Jacobians from :func:`relative_position`."""
    from factors.navigation import relative_position

    rng = np.random.default_rng(500 + seed)
    Ti = random_pose(rng)
    pre = DvlPreintegrator(0.0, Ti.rotation().matrix(), accel_sigma=0.05, attitude_sigma=0.01)
    for t in np.arange(0.2, 1.0, 0.2):
        R = Ti.rotation().matrix() @ so3_exp(rng.normal(size=3) * 0.05)
        pre.add(t, R, rng.normal(size=3) * 0.3, random_cov(rng, 3, 0.01))
    s = pre.smoothed(1.1, Ti.rotation().matrix() @ so3_exp(rng.normal(size=3) * 0.05))
    f = smoothed_displacement_factor(1, 2, 3, 4, s)

    def res(vals):
        delta, H_i, H_j = relative_position(vals.atPose3(1), vals.atPose3(2))
        z = np.concatenate([delta, vals.atVector(3), vals.atVector(4)])
        C_d = s.C_T[:, :3]
        return s.C_T @ (z - s.z0), (C_d @ H_i, C_d @ H_j, s.C_T[:, 3:6], s.C_T[:, 6:9])

    ref = _reference_factor(gtsam.noiseModel.Unit.Create(9), [1, 2, 3, 4], res)
    _same_at_random_poses_and_velocities(f, ref, rng)


@pytest.mark.parametrize("seed", range(3))
def test_point_residual_jacobians_against_central_differences(seed):
    """The association's point linearisation (point_residual_at, the pose as R, t): H_x for the right
    perturbation T·Exp(ξ), H_l for l + δ, both against central differences."""
    rng = np.random.default_rng(seed)
    T, T_BS = random_pose(rng), random_extrinsic(rng)
    l, z = rng.normal(size=3) * 5, rng.normal(size=3)
    r, H_x, H_l = point_residual_at(T.rotation().matrix(), T.translation(), l, T_BS, z, jac=True)
    np.testing.assert_allclose(r, point_residual(T, l, T_BS, z))
    h = 1e-6
    num_x = np.column_stack(
        [
            (
                point_residual(T.retract(h * np.eye(6)[k]), l, T_BS, z)
                - point_residual(T.retract(-h * np.eye(6)[k]), l, T_BS, z)
            )
            / (2 * h)
            for k in range(6)
        ]
    )
    num_l = np.column_stack(
        [(point_residual(T, l + h * e, T_BS, z) - point_residual(T, l - h * e, T_BS, z)) / (2 * h) for e in np.eye(3)]
    )
    np.testing.assert_allclose(H_x, num_x, atol=1e-6)
    np.testing.assert_allclose(H_l, num_l, atol=1e-6)
