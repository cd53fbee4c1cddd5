"""The EKF's fast paths compute what the plain ones do: the scalar prediction, the compressed
navigation updates, the batch measurement models, the scan linearisation and the dense JCBB."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from semslam.config import SemslamConfig
from semslam.ekf import EkfEstimator
from semslam.ekf import batch as bt
from semslam.ekf import geometry as g
from semslam.ekf import models as mdl
from semslam.ekf.features import ScanPairs, pre_gate
from semslam.ekf.filter import EkfState, inv_small
from semslam.mapping.association import PairLinearization, jcbb
from semslam.mapping.builder import Scan
from tests.support.association import individual_nis, joint_nis, solve
from tests.support.ekf_mission import simulate_circling
from tests.support.ekf_reference import predict_reference

RNG = np.random.default_rng(11)
R_BS = g.rot(0.05, np.pi / 2 - 0.2, 0.3)
T_BS = np.array([0.6, 0.1, 0.35])
X = np.array([3.0, -2.0, 4.5, 0.1, -0.15, 2.4, 0.4, 0.05, -0.03])


def test_scalar_prediction_is_the_matrix_model():
    for _ in range(50):
        x = RNG.normal(size=9)
        x[4] = RNG.uniform(-1.2, 1.2)
        w = RNG.normal(size=3)
        for a, b in zip(mdl.predict(x, w, 0.07, 0.05, 0.01), predict_reference(x, w, 0.07, 0.05, 0.01)):
            np.testing.assert_allclose(a, b, atol=1e-13)


def test_small_inverse_and_quaternions():
    for d in (1, 2, 3, 4):
        A = RNG.normal(size=(d, d))
        S = A @ A.T + 0.1 * np.eye(d)
        np.testing.assert_allclose(inv_small(S) @ S, np.eye(d), atol=1e-10)
    q = Rotation.random(5, random_state=3).as_quat()
    for qi in q:
        np.testing.assert_allclose(g.quat_to_rot(qi), Rotation.from_quat(qi).as_matrix(), atol=1e-14)


@pytest.mark.parametrize("nv", [9, 10])
def test_compressed_navigation_updates_equal_full_updates(nv):
    """Predictions and vehicle-only updates applied through the accumulators give the state and
    covariance of updating the whole state at every step; with nv = 10 (the AHRS heading bias in the
    vehicle block) also updates whose H covers only the first 9 entries (DVL, depth), landmark
    updates and augmentations with 9-column vehicle Jacobians (zero on the bias)."""
    n_l = 7
    A = RNG.normal(size=(nv + n_l, nv + n_l))
    P0 = A @ A.T * 0.01 + np.eye(nv + n_l) * 1e-3
    x0 = RNG.normal(size=nv + n_l)
    fast = EkfState(x0[:nv], P0[:nv, :nv])
    assert fast.nv == nv
    fast.augment(x0[nv:], np.zeros((n_l, 9)), np.eye(n_l), np.eye(n_l))  # then overwrite with P0
    fast._P[: nv + n_l, : nv + n_l] = P0
    x, P = x0.copy(), P0.copy()

    def plain_update(nu, Hf, R):
        nonlocal x, P
        S = Hf @ P @ Hf.T + R
        K = P @ Hf.T @ np.linalg.inv(S)
        x = x + K @ nu
        IKH = np.eye(len(x)) - K @ Hf
        P = IKH @ P @ IKH.T + K @ R @ K.T

    for step in range(40):
        F = np.eye(nv) + 0.05 * RNG.normal(size=(nv, nv))
        Qn = np.diag(RNG.uniform(1e-6, 1e-4, nv))
        xv = x[:nv] + 0.01 * RNG.normal(size=nv)
        fast.predict_vehicle(xv.copy(), F, Qn)
        x[:nv] = xv
        Fb = np.eye(len(x))
        Fb[:nv, :nv] = F
        P = Fb @ P @ Fb.T
        P[:nv, :nv] += Qn
        d = int(RNG.integers(1, 4))
        k = nv if step % 2 else 9  # H over the whole vehicle block, or over its first 9 entries
        H = RNG.normal(size=(d, k))
        R = np.eye(d) * RNG.uniform(1e-4, 1e-2)
        nu = RNG.normal(size=d) * 0.01
        fast.update(nu, np.arange(k), H, R)
        Hf = np.zeros((d, len(x)))
        Hf[:, :k] = H
        plain_update(nu, Hf, R)
        if step % 13 == 5:  # reading the full state applies the pending steps
            np.testing.assert_allclose(fast.x, x, atol=1e-10)
            np.testing.assert_allclose(fast.P, P, atol=1e-10)
        if step % 11 == 3:  # a landmark update: the pose columns and one landmark block
            j = nv + int(RNG.integers(0, n_l - 2))
            cols = np.r_[np.arange(9), np.arange(j, j + 3)]
            H = RNG.normal(size=(3, 12))
            nu = RNG.normal(size=3) * 0.01
            R = np.eye(3) * 1e-3
            fast.update(nu, cols, H, R)
            Hf = np.zeros((3, len(x)))
            Hf[:, cols] = H
            plain_update(nu, Hf, R)
        if step % 17 == 8:  # a new landmark from the pose (9-column G_x)
            G_x, G_z, R_z = RNG.normal(size=(3, 9)), RNG.normal(size=(3, 3)), np.eye(3) * 1e-3
            l = RNG.normal(size=3)
            fast.augment(l, G_x, G_z, R_z)
            Gf = np.zeros((3, len(x)))
            Gf[:, :9] = G_x
            cross = Gf @ P
            P = np.block([[P, cross.T], [cross, cross @ Gf.T + G_z @ R_z @ G_z.T]])
            x = np.r_[x, l]
    np.testing.assert_allclose(fast.P, P, atol=1e-10)
    np.testing.assert_allclose(fast.x, x, atol=1e-10)


def _line_obs(k):
    R, t, _, _ = mdl.sensor_pose(X, R_BS, T_BS)
    c = RNG.normal(size=3) + [3.0, -2.0, 7.0]
    d = RNG.normal(size=3)
    d /= np.linalg.norm(d)
    pw, qw = c - 0.3 * d, c + 0.3 * d
    l = g.line_params(g.cross3(pw, d), d)
    e = RNG.normal(0, 0.02, 6)
    p, q = (pw - t) @ R + e[:3], (qw - t) @ R + e[3:]
    if k % 2:
        p, q = q, p
    A = RNG.normal(size=(6, 6))
    return l, mdl.LineObservationModel.from_endpoints(p, q, A @ A.T * 1e-4)


def test_batch_models_equal_the_scalar_ones():
    L = RNG.normal(size=(12, 3)) + [3.0, -2.0, 7.0]
    h, Hx, Hl = bt.point_measurements(X, L, R_BS, T_BS)
    for k in range(len(L)):
        for a, b in zip((h[k], Hx[k], Hl), mdl.point_measurement(X, L[k], R_BS, T_BS)):
            np.testing.assert_allclose(a, b, atol=1e-12)
    pairs = [_line_obs(k) for k in range(16)]
    Ls = np.array([p[0] for p in pairs])
    obs = [p[1] for p in pairs]
    obs_args = (
        np.array([o.U for o in obs]),
        np.array([o.rho for o in obs]),
        np.array([o.d for o in obs]),
        np.array([o.cov for o in obs]),
        R_BS,
        T_BS,
    )
    out = bt.line_innovations(X, Ls, *obs_args)
    for k in range(len(Ls)):
        for a, b in zip((v[k] for v in out), mdl.line_innovation(X, Ls[k], obs[k], R_BS, T_BS)):
            np.testing.assert_allclose(a, b, atol=1e-10, rtol=1e-8)
    # moments about per-pipe anchors
    anchors = RNG.normal(0, 3.0, (len(Ls), 3))
    out = bt.line_innovations(X, Ls, *obs_args, anchors=anchors)
    for k in range(len(Ls)):
        ref = mdl.line_innovation(X, Ls[k], obs[k], R_BS, T_BS, anchor=anchors[k])
        for a, b in zip((v[k] for v in out), ref):
            np.testing.assert_allclose(a, b, atol=1e-10, rtol=1e-8)
    # first-estimates Jacobians: H at L_lin, ν and R at L
    L_lin = Ls + RNG.normal(0, 0.01, Ls.shape)
    out = bt.line_innovations(X, Ls, *obs_args, L_lin=L_lin)
    for k in range(len(Ls)):
        ref = mdl.line_innovation(X, Ls[k], obs[k], R_BS, T_BS, l_lin=L_lin[k])
        for a, b in zip((v[k] for v in out), ref):
            np.testing.assert_allclose(a, b, atol=1e-10, rtol=1e-8)
        at_lin = mdl.line_innovation(X, L_lin[k], obs[k], R_BS, T_BS)
        np.testing.assert_allclose(ref[1], at_lin[1], atol=1e-10)
        np.testing.assert_allclose(ref[0], mdl.line_innovation(X, Ls[k], obs[k], R_BS, T_BS)[0], atol=1e-12)


class _DenseView:
    """An association problem with a given joint covariance (every block correlated)."""

    def __init__(self, Z, L, P, R):
        self.Z, self.L, self.P, self.R = Z, L, P, R
        self.n_observations, self.n_landmarks = len(Z), len(L)

    def pair(self, i, j):
        return PairLinearization(self.Z[i] - (self.L[j] - np.zeros(3)), -np.eye(3), np.eye(3), self.R)

    def covariance(self, a, b):
        ia = slice(0, 3) if a is None else slice(3 + 3 * a, 6 + 3 * a)
        ib = slice(0, 3) if b is None else slice(3 + 3 * b, 6 + 3 * b)
        return self.P[ia, ib]


@pytest.mark.parametrize("seed", range(25))
def test_dense_joint_is_the_direct_joint(seed):
    """The Schur-complement steps on slices of S give, node for node, the joint NIS solved afresh:
    the one search finds the same hypothesis with either."""
    rng = np.random.default_rng(seed)
    m = int(rng.integers(3, 9))
    L = rng.uniform(-1, 1, (m, 3)) * rng.uniform(0.1, 1.0)  # sometimes crowded
    x_true = rng.normal(0, 0.1, 3)
    seen = rng.choice(m, min(m, int(rng.integers(2, 7))), replace=False)
    Z = [L[j] - x_true + rng.normal(0, 0.02, 3) for j in seen] + [rng.uniform(-1, 1, 3) for _ in range(2)]
    rng.shuffle(Z)
    A = rng.normal(size=(3 + 3 * m, 3 + 3 * m)) * 0.02
    P = A @ A.T + np.diag([0.1**2] * 3 + [0.03**2] * (3 * m))  # correlated landmarks
    prob = _DenseView(np.array(Z), L, P, np.eye(3) * 0.02**2)
    out = solve(prob, 0.99)
    assert out == solve(prob, 0.99, joint="direct")
    # restarted from a greedy hypothesis at once: as many pairings, jointly compatible
    stats = {}
    seeded = solve(prob, 0.99, seed_after=1, stats=stats)
    pairs = [(i, j) for i, j in enumerate(seeded) if j is not None]
    assert len(pairs) == sum(j is not None for j in out)
    assert len({j for _, j in pairs}) == len(pairs)
    if pairs:
        assert stats["seeded"] and joint_nis(prob, pairs) < chi2.ppf(0.99, 3 * len(pairs))


@pytest.mark.parametrize("seed", range(15))
def test_the_order_of_the_observations_does_not_matter(seed):
    """Observations are searched most certain first, whatever order the front-end gave them in."""
    rng = np.random.default_rng(100 + seed)
    m = int(rng.integers(3, 8))
    L = rng.uniform(-1, 1, (m, 3)) * rng.uniform(0.1, 1.0)
    x_true = rng.normal(0, 0.1, 3)
    Z = [L[j] - x_true + rng.normal(0, 0.02, 3) for j in rng.choice(m, min(m, 5), replace=False)]
    Z += [rng.uniform(-1, 1, 3) for _ in range(2)]
    A = rng.normal(size=(3 + 3 * m, 3 + 3 * m)) * 0.02
    P = A @ A.T + np.diag([0.1**2] * 3 + [0.03**2] * (3 * m))
    out = solve(_DenseView(np.array(Z), L, P, np.eye(3) * 0.02**2), 0.99)
    perm = rng.permutation(len(Z))
    shuffled = solve(_DenseView(np.array(Z)[perm], L, P, np.eye(3) * 0.02**2), 0.99)
    assert shuffled == [out[k] for k in perm]


class _PairwiseProblem:
    """The filter's pairs one by one, with the scalar models, as a callback problem."""

    def __init__(self, est, obs, scan):
        self.est, self.obs, self.scan = est, obs, scan
        self.feats = est.map.features
        self.n_observations, self.n_landmarks = len(obs), len(self.feats)
        self._near = pre_gate(est.map, obs)

    def pair(self, i, j):
        o, f, nav = self.obs[i], self.feats[j], self.est.nav
        if not self._near[i, j] or o.kind != f.kind:
            return None
        x, l = nav.state.xv, nav.state.x[f.index : f.index + f.size]
        if f.kind == "object":
            h, H_x, H_l = mdl.point_measurement(x, l, o.R_BS, o.t_BS)
            if nav.fej_yaw:
                H_x = mdl.point_measurement(nav.x_lin(), f.l_first, o.R_BS, o.t_BS)[1]
            return PairLinearization(o.obs.position - h, H_x, H_l, np.asarray(o.obs.covariance))
        m_W, d_W = g.anchored_plucker(l, f.anchor)
        if self.scan.excludes(f.id, o.ends_W, g.closest_point(m_W, d_W), d_W):
            return None
        l_first = f.l_first if self.est.map.fej_lines or nav.fej_yaw else None
        x_lin = nav.x_lin() if nav.fej_yaw else None
        return PairLinearization(*mdl.line_innovation(x, l, o.line, o.R_BS, o.t_BS, l_first, x_lin, f.anchor))

    def covariance(self, a, b):
        ia = np.arange(mdl.NX) if a is None else self.feats[a].cols
        ib = np.arange(mdl.NX) if b is None else self.feats[b].cols
        return self.est.nav.state.P[np.ix_(ia, ib)]


def _mapped_filter(seed=2):
    sim = simulate_circling(seed=seed, duration_s=40.0)
    est = EkfEstimator(sim.metadata, SemslamConfig())
    sim.run([est])
    return est, sim.observations[max(sim.observations)]


def test_scan_linearisation_equals_the_pairwise_problem():
    est, obs = _mapped_filter()
    assert len(est.map) > 5
    est.map.begin()
    prepared = est.map.prepared(obs)
    _, mapped = est.map.objects()
    scan = Scan(est.book, est.assoc, mapped, mapped)
    pairs = ScanPairs(est.map, prepared, 0.999, scan)
    prob = _PairwiseProblem(est, prepared, scan)
    assert len(pairs.obs) > 0
    for k, (i, j) in enumerate(zip(pairs.obs, pairs.feat)):
        p = prob.pair(int(i), int(j))
        assert p is not None
        np.testing.assert_allclose(pairs.nu[k], p.innovation, atol=1e-12)
        np.testing.assert_allclose(pairs.H_x[k], p.H_x, atol=1e-12)
        np.testing.assert_allclose(pairs.H_l[k], p.H_l, atol=1e-12)
        assert pairs.nis[k] == pytest.approx(individual_nis(prob, int(i), int(j)), rel=1e-9)
    # every pair the pairwise problem accepts within the gate is in the scan's (the extent checks of
    # pipes are made only within it)
    gate = {3: chi2.ppf(0.999, 3), 4: chi2.ppf(0.999, 4)}
    pairwise = {
        (i, j)
        for i in range(len(prepared))
        for j in range(prob.n_landmarks)
        if prob.pair(i, j) is not None and individual_nis(prob, i, j) < gate[len(prob.pair(i, j).innovation)]
    }
    assert pairwise == {(int(i), int(j)) for i, j in zip(pairs.obs, pairs.feat)}
    assert all(pairs.nis[k] < gate[len(pairs.nu[k])] for k in range(len(pairs.obs)))
    # the association the map building runs on them: the reference's on the pairwise problem
    found, _ = est.map.candidates([o.obs for o in prepared], 0.999, scan)
    strict = found.subset(found.passing(0.99))
    assert jcbb(strict, est.map.joint(strict), 0.99) == solve(prob, 0.99, joint="direct")


def test_matching_bound_cuts_competing_observations():
    """Ten observations all compatible with the same three landmarks: the branches that cannot pair
    more than three are cut by the matching bound (the count of observations with a free candidate
    alone lets the search expand ~700 nodes here), with the reference's result."""
    rng = np.random.default_rng(3)
    L = np.array([[0.0, 0.0, 0.0], [0.02, 0.0, 0.0], [0.0, 0.02, 0.0]])
    Z = [L[k % 3] + rng.normal(0, 0.01, 3) for k in range(10)]
    P = np.diag([0.05**2] * 3 + [0.02**2] * 9)
    prob = _DenseView(np.array(Z), L, P, np.eye(3) * 0.02**2)
    stats = {}
    out = solve(prob, 0.99, stats=stats)
    assert out == solve(prob, 0.99, joint="direct")
    assert sum(j is not None for j in out) == 3
    assert stats["nodes"] < 20 and not stats["capped"]


def test_batch_line_observation_models():
    P = RNG.normal(size=(9, 3)) + [0, 0, 3]
    Q = P + RNG.normal(size=(9, 3)) * 0.4
    C = np.array([(lambda A: A @ A.T * 1e-4)(RNG.normal(size=(6, 6))) for _ in range(9)])
    m, d, U, rho, cov = bt.line_observation_models(P, Q, C)
    for k in range(9):
        ref = mdl.LineObservationModel.from_endpoints(P[k], Q[k], C[k])
        for a, b in zip((m[k], d[k], U[k], rho[k], cov[k]), (ref.m, ref.d, ref.U, ref.rho, ref.cov)):
            np.testing.assert_allclose(a, b, atol=1e-12, rtol=1e-10)
