"""Every EKF Jacobian against central finite differences, including lines near β = ±90°."""

import numpy as np
import pytest

from semslam.ekf import geometry as g
from semslam.ekf import models as mdl


def numjac(f, x0, h=1e-6):
    x0 = np.asarray(x0, float)
    f0 = np.asarray(f(x0))
    J = np.zeros((f0.size, x0.size))
    for i in range(x0.size):
        dx = np.zeros_like(x0)
        dx[i] = h
        J[:, i] = (np.asarray(f(x0 + dx)) - np.asarray(f(x0 - dx))).ravel() / (2 * h)
    return J


def assert_jac(A, N, rtol=1e-5, atol=1e-6):
    scale = max(1.0, np.abs(N).max())
    np.testing.assert_allclose(A, N, rtol=rtol, atol=atol * scale)


RNG = np.random.default_rng(7)
X = np.array([3.0, -2.0, 4.5, 0.1, -0.15, 2.4, 0.4, 0.05, -0.03])
R_BS = g.rot(0.05, np.pi / 2 - 0.2, 0.3)  # a down/forward-looking sensor, not axis-aligned
T_BS = np.array([0.6, 0.1, 0.35])


def test_euler_round_trip_and_rates():
    for _ in range(20):
        e = np.array([RNG.uniform(-3, 3), RNG.uniform(-1.4, 1.4), RNG.uniform(-3, 3)])
        np.testing.assert_allclose(g.euler(g.rot(*e)), e, atol=1e-12)
        E = g.euler_rate_to_body(e[0], e[1])
        np.testing.assert_allclose(g.body_to_euler_rate(e[0], e[1]) @ E, np.eye(3), atol=1e-12)
        # R(e + δe) = R(e) Exp(E δe)
        N = numjac(lambda d: g.so3_log(g.rot(*e).T @ g.rot(*(e + d))), np.zeros(3))  # noqa: B023
        assert_jac(E, N)
        w = RNG.normal(size=3)
        assert_jac(g.euler_rate_jacobian(e[0], e[1], w), numjac(lambda ee: g.body_to_euler_rate(ee[0], ee[1]) @ w, e))  # noqa: B023


def test_so3_jacobians():
    w = np.array([0.3, -0.5, 0.8])
    N = numjac(lambda d: g.so3_log(g.so3_exp(w) @ g.so3_exp(d)), np.zeros(3))
    assert_jac(g.so3_right_jacobian_inv(w), N)
    N = numjac(lambda d: g.so3_log(g.so3_exp(d) @ g.so3_exp(w)), np.zeros(3))
    assert_jac(g.so3_left_jacobian_inv(w), N)


def test_prediction_jacobian():
    w = np.array([0.05, -0.1, 0.2])
    _, F, Q = mdl.predict(X, w, 0.1, 0.05, 0.01)
    assert_jac(F, numjac(lambda x: mdl.predict(x, w, 0.1, 0.05, 0.01)[0], X))
    assert np.all(np.linalg.eigvalsh(Q) > 0)


def test_depth_jacobian():
    u = mdl.depth_update(X, 0.0, 0.01, T_BS)
    assert_jac(u.H, -numjac(lambda x: mdl.depth_update(x, 0.0, 0.01, T_BS).innovation, X))


def test_dvl_jacobian():
    w = np.array([0.05, -0.1, 0.2])
    u = mdl.dvl_update(X, np.zeros(3), np.eye(3), R_BS, T_BS, w)
    assert_jac(u.H, -numjac(lambda x: mdl.dvl_update(x, np.zeros(3), np.eye(3), R_BS, T_BS, w).innovation, X))


def test_attitude_extrinsic_covariance():
    """δe_B = E⁻¹(e_B) R_BS E(e_S) δe_S: the mapping of the AHRS covariance to body angles."""
    e_S = np.array([0.2, -0.3, 1.0])
    f = lambda e: g.euler(g.rot(*e) @ R_BS.T)
    N = numjac(f, e_S)
    Sigma = np.diag([1e-4, 2e-4, 5e-4])
    _, cov_B = mdl.attitude_in_body(g.rot(*e_S), Sigma, R_BS)
    np.testing.assert_allclose(cov_B, N @ Sigma @ N.T, rtol=1e-6, atol=1e-12)


def test_point_measurement_and_initialisation():
    l = np.array([4.0, -1.0, 6.0])
    h, H_x, H_l = mdl.point_measurement(X, l, R_BS, T_BS)
    assert_jac(H_x, numjac(lambda x: mdl.point_measurement(x, l, R_BS, T_BS)[0], X))
    assert_jac(H_l, numjac(lambda ll: mdl.point_measurement(X, ll, R_BS, T_BS)[0], l))
    l2, G_x, G_z = mdl.point_initialise(X, h, R_BS, T_BS)
    np.testing.assert_allclose(l2, l, atol=1e-12)
    assert_jac(G_x, numjac(lambda x: mdl.point_initialise(x, h, R_BS, T_BS)[0], X))
    assert_jac(G_z, numjac(lambda z: mdl.point_initialise(X, z, R_BS, T_BS)[0], h))


def _world_line(beta):
    """A pipe with [α β γ ρ] = [0.4, β, -1.1, 5] and two points on it."""
    l = np.array([0.4, beta, -1.1, 5.0])
    m, d = g.line_plucker(l)
    c = g.closest_point(m, d)
    return l, c - 0.7 * d, c + 1.3 * d


def _to_sensor(x, pts):
    R, t, _, _ = mdl.sensor_pose(x, R_BS, T_BS)
    return (pts - t) @ R


BETAS = [0.3, -1.0, np.deg2rad(89.5), -np.deg2rad(89.5), np.deg2rad(89.95), -np.deg2rad(89.95)]


@pytest.mark.parametrize("beta", BETAS)
def test_line_parametrisation_jacobians(beta):
    l, _, _ = _world_line(beta)
    J = g.line_params_jacobian(l)
    N = numjac(lambda ll: np.concatenate(g.line_plucker(ll)), l, h=1e-7)
    assert_jac(J, N)
    # the inverse: parameters from (m, d) through the error map
    m, d = g.line_plucker(l)
    U = g.rot(*l[:3])
    T = g.line_params_from_error(l) @ g.line_error_map(U, l[3])
    N = numjac(
        lambda md: g.line_params(md[:3], md[3:] / np.linalg.norm(md[3:])) - np.r_[0, 0, 0, 0], np.r_[m, d], h=1e-8
    )
    # only perturbations that keep (m, d) a valid line (d ⊥ m, |d| = 1) are meaningful: project
    B = g.line_error_inverse(U, l[3])
    assert_jac(T @ B, N @ B, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(g.line_error_map(U, l[3]) @ B, np.eye(4), atol=1e-12)


@pytest.mark.parametrize("beta", BETAS)
def test_line_measurement_jacobians(beta):
    l, pw, qw = _world_line(beta)
    ps, qs = _to_sensor(X, np.array([pw, qw]))
    # an observation slightly off the prediction
    obs = mdl.LineObservationModel.from_endpoints(ps + [0.02, -0.01, 0.03], qs + [-0.01, 0.02, 0.0], np.eye(6) * 1e-4)
    nu, H_x, H_l, R = mdl.line_innovation(X, l, obs, R_BS, T_BS)
    assert np.linalg.norm(nu) < 0.1
    assert_jac(H_x, -numjac(lambda x: mdl.line_innovation(x, l, obs, R_BS, T_BS)[0], X, h=1e-7), rtol=1e-4, atol=1e-6)
    assert_jac(H_l, -numjac(lambda ll: mdl.line_innovation(X, ll, obs, R_BS, T_BS)[0], l, h=1e-7), rtol=1e-4, atol=1e-6)

    # R is the endpoint covariance pushed through ∂ν/∂(p, q)
    def nu_of(pq):
        o = mdl.LineObservationModel.from_endpoints(pq[:3], pq[3:], np.eye(6))
        return mdl.line_innovation(X, l, o, R_BS, T_BS)[0]

    pq0 = np.r_[obs.m * 0, 0, 0, 0]  # placeholder replaced below
    pq0 = np.r_[ps + [0.02, -0.01, 0.03], qs + [-0.01, 0.02, 0.0]]
    N = numjac(nu_of, pq0, h=1e-7)
    Sigma = np.diag([1e-4, 2e-4, 1e-4, 3e-4, 1e-4, 2e-4])
    o = mdl.LineObservationModel.from_endpoints(pq0[:3], pq0[3:], Sigma)
    R = mdl.line_innovation(X, l, o, R_BS, T_BS)[3]
    np.testing.assert_allclose(R, N @ Sigma @ N.T, rtol=1e-4, atol=1e-10)


def test_line_observation_direction_is_irrelevant():
    l, pw, qw = _world_line(0.3)
    ps, qs = _to_sensor(X, np.array([pw, qw]))
    a = mdl.line_innovation(X, l, mdl.LineObservationModel.from_endpoints(ps, qs + 0.01, np.eye(6) * 1e-4), R_BS, T_BS)
    b = mdl.line_innovation(X, l, mdl.LineObservationModel.from_endpoints(qs + 0.01, ps, np.eye(6) * 1e-4), R_BS, T_BS)
    for u, v in zip(a, b):
        np.testing.assert_allclose(u, v, atol=1e-10)


@pytest.mark.parametrize("beta", BETAS)
def test_line_initialisation_jacobians(beta):
    l, pw, qw = _world_line(beta)
    ps, qs = _to_sensor(X, np.array([pw, qw]))
    l2, G_x, G_pq = mdl.line_initialise(X, ps, qs, R_BS, T_BS)
    np.testing.assert_allclose(l2, l, atol=1e-8)
    f = lambda x: mdl.line_initialise(x, ps, qs, R_BS, T_BS)[0]
    assert_jac(G_x, numjac(f, X, h=1e-8), rtol=1e-4, atol=1e-5)
    f = lambda pq: mdl.line_initialise(X, pq[:3], pq[3:], R_BS, T_BS)[0]
    assert_jac(G_pq, numjac(f, np.r_[ps, qs], h=1e-8), rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("beta", BETAS)
@pytest.mark.parametrize("reverse", [False, True])
def test_line_difference_is_zero_on_one_line_and_its_jacobians(beta, reverse):
    l, pw, qw = _world_line(beta)
    # the same line with its direction reversed has other parameters but no difference
    same = g.line_params(*(-np.array(g.line_plucker(l)))) if reverse else l
    nu0, _, _ = g.line_difference(l, same)
    np.testing.assert_allclose(nu0, 0.0, atol=1e-9)
    # a nearby line: 2 cm off, 1° turned
    lb = same + np.array([0.01, -0.012, 0.015, 0.02])
    nu, H_a, H_b = g.line_difference(l, lb)
    assert 0.01 < np.linalg.norm(nu) < 0.1
    assert_jac(H_a, numjac(lambda la: g.line_difference(la, lb)[0], l, h=1e-7), rtol=1e-4, atol=1e-5)
    assert_jac(H_b, numjac(lambda x: g.line_difference(l, x)[0], lb, h=1e-7), rtol=1e-4, atol=1e-5)


def test_rot_batch_matches_rot():
    e = RNG.uniform(-1.5, 1.5, size=(10, 3))
    np.testing.assert_allclose(g.rot_batch(e), np.array([g.rot(*r) for r in e]), atol=1e-14)


XB = np.r_[X, 0.03]  # with an AHRS heading bias (rad)


def test_biased_prediction_jacobian():
    """The heading bias is a random walk beside the paper's model: F = diag(F₉, 1), Q_bb = σ_b² Δt."""
    w = np.array([0.05, -0.1, 0.2])
    xn, F, Q = mdl.predict_biased(XB, w, 0.1, 0.05, 0.01, 0.002)
    xn9, F9, Q9 = mdl.predict(X, w, 0.1, 0.05, 0.01)
    np.testing.assert_allclose(xn[:9], xn9)
    assert xn[mdl.BIAS] == XB[mdl.BIAS]
    assert_jac(F, numjac(lambda x: mdl.predict_biased(x, w, 0.1, 0.05, 0.01, 0.002)[0], XB))
    np.testing.assert_allclose(Q[:9, :9], Q9)
    assert Q[9, 9] == pytest.approx(0.002**2 * 0.1) and not Q[9, :9].any()


def test_biased_attitude_jacobian_and_the_graph_model():
    """The AHRS reading R_meas = Rz(b) R_WB (factors.navigation.biased_attitude_residual): its Euler
    angles are (φ, θ, ψ + b), so the innovation is zero at the truth, and H is the numerical Jacobian
    of the rotation-form model."""
    Rz = lambda b: g.rot(0.0, 0.0, b)
    h = lambda x: g.euler(Rz(x[mdl.BIAS]) @ g.rot(*x[3:6]))
    z = h(XB)
    u = mdl.biased_attitude_update(XB, z, np.eye(3))
    np.testing.assert_allclose(u.innovation, 0.0, atol=1e-12)
    assert u.H.shape == (3, 10)
    assert_jac(u.H, numjac(h, XB))
    assert_jac(u.H, -numjac(lambda x: mdl.biased_attitude_update(x, z, np.eye(3)).innovation, XB))
    # near ψ + b = ±π the innovation is wrapped
    xb = XB.copy()
    xb[5], xb[mdl.BIAS] = np.pi - 0.01, 0.03
    u = mdl.biased_attitude_update(xb, h(xb), np.eye(3))
    np.testing.assert_allclose(u.innovation, 0.0, atol=1e-12)


ANCHOR = np.array([1.5, -2.0, 0.7])


def test_anchored_line_measurement_and_initialisation_jacobians():
    """A pipe whose moment is about an anchor: the innovation's and the initialisation's Jacobians
    against numerical ones, and the same world line as without the anchor."""
    l0, pw, qw = _world_line(0.3)
    ps, qs = _to_sensor(X, np.array([pw, qw]))
    l, G_x, G_pq = mdl.line_initialise(X, ps, qs, R_BS, T_BS, ANCHOR)
    m, d = g.anchored_plucker(l, ANCHOR)
    m0, d0 = g.line_plucker(l0)
    np.testing.assert_allclose(np.r_[m, d], np.r_[m0, d0], atol=1e-9)
    assert_jac(G_x, numjac(lambda x: mdl.line_initialise(x, ps, qs, R_BS, T_BS, ANCHOR)[0], X, h=1e-8), 1e-4, 1e-5)
    f = lambda pq: mdl.line_initialise(X, pq[:3], pq[3:], R_BS, T_BS, ANCHOR)[0]
    assert_jac(G_pq, numjac(f, np.r_[ps, qs], h=1e-8), rtol=1e-4, atol=1e-5)
    obs = mdl.LineObservationModel.from_endpoints(ps + [0.02, -0.01, 0.03], qs + [-0.01, 0.02, 0.0], np.eye(6) * 1e-4)
    nu, H_x, H_l, _ = mdl.line_innovation(X, l, obs, R_BS, T_BS, anchor=ANCHOR)
    # the same innovation as the pipe about the origin: the anchor changes the chart, not the line
    np.testing.assert_allclose(nu, mdl.line_innovation(X, l0, obs, R_BS, T_BS)[0], atol=1e-9)
    inn = lambda x, ll: mdl.line_innovation(x, ll, obs, R_BS, T_BS, anchor=ANCHOR)[0]
    assert_jac(H_x, -numjac(lambda x: inn(x, l), X, h=1e-7), rtol=1e-4, atol=1e-6)
    assert_jac(H_l, -numjac(lambda ll: inn(X, ll), l, h=1e-7), rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("d", [[0, 0, 1.0], [1.0, 0, 0], [0.6, 0.0, 0.8], [0.05, 0.03, -1.0]])
def test_line_anchor_is_square_to_the_line_at_its_distance_and_never_level_with_it(d):
    d = np.asarray(d) / np.linalg.norm(d)
    c = np.array([0.3, -0.2, 4.5])
    a = g.line_anchor(c, d, 4.0)
    assert np.linalg.norm(a - c) == pytest.approx(4.0)
    assert abs((a - c) @ d) < 1e-9
    # about the anchor: ρ is the distance, the closest point is c, and the moment is not vertical
    m = g.cross3(c - a, d)
    assert np.linalg.norm(m) == pytest.approx(4.0)
    assert abs(m[2]) / np.linalg.norm(m) < 0.99


@pytest.mark.parametrize("heading", ["none", "bias", "rate"])
def test_gyro_bias_prediction_jacobian(heading):
    """The gyro's bias b_g (the vehicle block's last 3 entries): the attitude integrates ω − b_g, b_g a
    random walk; F against finite differences with and without the heading bias (and its rate) before it."""
    w, bg = np.array([0.05, -0.1, 0.2]), np.array([0.01, -0.02, 0.015])
    hb = {"none": [], "bias": [0.004], "rate": [0.004, 0.2]}[heading]
    walks = {"none": (None, None), "bias": (0.002, None), "rate": (0.002, 1e-4)}[heading]
    x = np.r_[X, hb, bg]
    f = lambda xx: mdl.predict_biased(xx, w, 0.1, 0.05, 0.01, *walks, 3e-4)
    xn, F, Q = f(x)
    ref, F0, Q0 = (
        mdl.predict_biased(np.r_[X, hb], w - bg, 0.1, 0.05, 0.01, *walks)
        if hb
        else mdl.predict(X, w - bg, 0.1, 0.05, 0.01)
    )
    np.testing.assert_allclose(xn[:-3], ref)  # the model without the bias, fed ω − b_g
    np.testing.assert_array_equal(xn[-3:], bg)
    assert_jac(F, numjac(lambda xx: f(xx)[0], x))
    assert np.abs(F[3:6, -3:]).max() > 0.09  # ∂e'/∂b_g = −E⁻¹ Δt: the bias enters
    np.testing.assert_allclose(F[:-3, :-3], F0)
    np.testing.assert_allclose(Q[:-3, :-3], Q0)
    np.testing.assert_allclose(Q[-3:, -3:], np.eye(3) * 3e-4**2 * 0.1)
    assert not Q[-3:, :-3].any()


def test_gyro_bias_dvl_jacobian():
    """The DVL's lever arm turns at ω − b_g: ∂z/∂b_g = R_BSᵀ [t_BS]×."""
    w, bg = np.array([0.05, -0.1, 0.2]), np.array([0.01, -0.02, 0.015])
    x = np.r_[X, 0.004, bg]
    u = mdl.dvl_update(x, np.zeros(3), np.eye(3), R_BS, T_BS, w, gyro_bias=True)
    np.testing.assert_allclose(u.innovation, mdl.dvl_update(X, np.zeros(3), np.eye(3), R_BS, T_BS, w - bg).innovation)
    N = -numjac(lambda xx: mdl.dvl_update(xx, np.zeros(3), np.eye(3), R_BS, T_BS, w, gyro_bias=True).innovation, x)
    assert u.H.shape == (3, 13) and np.abs(u.H[:, -3:]).max() > 0.1
    assert_jac(u.H, N)
