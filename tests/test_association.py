"""The one JCBB (semslam.mapping.association) against hand-built problems and brute-force enumeration."""

import itertools

import numpy as np
import pytest
from scipy.stats import chi2

from semslam.mapping.association import DenseJoint, PairLinearization, jcbb
from tests.support.association import candidates, individual_nis, joint_nis, solve


class PointProblem:
    """Observations z_i = l_j - x + noise of 3-D point landmarks from a vehicle position x.

    The vehicle block is its position (3), each landmark block its position (3); P is the
    joint covariance (vehicle first).
    """

    def __init__(self, x_est, landmarks, P, observations, R, kinds=None, obs_kinds=None):
        self.x = np.asarray(x_est, float)
        self.L = np.asarray(landmarks, float).reshape(-1, 3)
        self.P = np.asarray(P, float)
        self.Z = np.asarray(observations, float).reshape(-1, 3)
        self.R = np.asarray(R, float)
        self.kinds = kinds
        self.obs_kinds = obs_kinds
        self.n_observations = len(self.Z)
        self.n_landmarks = len(self.L)

    def pair(self, i, j):
        if self.kinds is not None and self.kinds[j] != self.obs_kinds[i]:
            return None
        return PairLinearization(self.Z[i] - (self.L[j] - self.x), -np.eye(3), np.eye(3), self.R)

    def covariance(self, a, b):
        ia = slice(0, 3) if a is None else slice(3 + 3 * a, 6 + 3 * a)
        ib = slice(0, 3) if b is None else slice(3 + 3 * b, 6 + 3 * b)
        return self.P[ia, ib]


def _joint_cov(n_lm, sigma_x, sigma_l):
    return np.diag([sigma_x**2] * 3 + [sigma_l**2] * (3 * n_lm))


def test_correlation_resolves_what_individual_gates_cannot():
    # Landmarks 0 and 1 are 1 m apart along x; landmark 2 is isolated. The vehicle is 0.5 m off
    # along x. Observation 0 (of landmark 1) is equally close to landmarks 0 and 1 individually;
    # only the common vehicle error, shared with observation 1 (of landmark 2), tells them apart.
    L = [[0, 0, 0], [1, 0, 0], [6, 0, 0]]
    x_true, x_est = np.array([0.5, 0, 0]), np.zeros(3)
    Z = [np.array(L[1]) - x_true, np.array(L[2]) - x_true]
    R = np.eye(3) * 0.01**2
    prob = PointProblem(x_est, L, _joint_cov(3, 0.5, 0.001), Z, R)
    assert individual_nis(prob, 0, 0) == pytest.approx(individual_nis(prob, 0, 1))
    assert solve(prob) == [1, 2]


def test_one_to_one_and_new_landmark():
    L = [[0, 0, 0], [3, 0, 0]]
    Z = [[0.01, 0, 0], [-0.01, 0.0, 0], [10, 10, 0]]  # two observations of landmark 0, one of nothing
    prob = PointProblem(np.zeros(3), L, _joint_cov(2, 0.01, 0.01), Z, np.eye(3) * 0.01**2)
    out = solve(prob)
    assert out.count(0) == 1 and out[2] is None and 1 not in out


def test_kinds_never_pair_across():
    L = [[0, 0, 0]]
    prob = PointProblem(np.zeros(3), L, _joint_cov(1, 0.01, 0.01), [[0, 0, 0]], np.eye(3) * 1e-4, ["pipe"], ["object"])
    assert solve(prob) == [None]


def _brute_force(prob, confidence):
    """Best one-to-one hypothesis by enumeration: most pairings (then smallest joint NIS)."""
    n, m = prob.n_observations, prob.n_landmarks
    best = (0, 0.0, [None] * n)
    for assign in itertools.product([None, *range(m)], repeat=n):
        js = [j for j in assign if j is not None]
        if len(js) != len(set(js)):
            continue
        pairs = [(i, j) for i, j in enumerate(assign) if j is not None]
        if not pairs:
            continue
        if any(individual_nis(prob, i, j) >= chi2.ppf(confidence, 3) for i, j in pairs):
            continue
        # Every prefix of the hypothesis must be jointly compatible too (JCBB's search order).
        ok = all(joint_nis(prob, pairs[:k]) < chi2.ppf(confidence, 3 * k) for k in range(1, len(pairs) + 1))
        if not ok:
            continue
        nis = joint_nis(prob, pairs)
        if len(pairs) > best[0] or (len(pairs) == best[0] and nis < best[1]):
            best = (len(pairs), nis, list(assign))
    return best


@pytest.mark.parametrize("seed", range(12))
def test_matches_brute_force_on_random_cluttered_scenes(seed):
    rng = np.random.default_rng(seed)
    m = 5
    L = rng.uniform(-1, 1, (m, 3))
    x_true = rng.normal(0, 0.2, 3)
    seen = rng.choice(m, 4, replace=False)
    Z = [L[j] - x_true + rng.normal(0, 0.02, 3) for j in seen]
    Z.append(rng.uniform(-1, 1, 3))  # clutter
    P = _joint_cov(m, 0.2, 0.02)
    prob = PointProblem(np.zeros(3), L, P, Z, np.eye(3) * 0.02**2)
    out = solve(prob, 0.99)
    n_best, nis_best, _ = _brute_force(prob, 0.99)
    pairs = [(i, j) for i, j in enumerate(out) if j is not None]
    assert len(pairs) == n_best
    assert len({j for _, j in pairs}) == len(pairs)
    assert joint_nis(prob, pairs) < chi2.ppf(0.99, 3 * len(pairs))


def test_optional_candidate_pre_gate_limits_the_pairs_tested():
    L = [[0, 0, 0], [0.05, 0, 0], [3, 0, 0]]
    prob = PointProblem(np.zeros(3), L, _joint_cov(3, 0.05, 0.01), [[0.05, 0, 0]], np.eye(3) * 0.01**2)
    tested = []
    original = prob.pair
    prob.pair = lambda i, j: tested.append(j) or original(i, j)
    assert solve(prob) == [1]
    prob.candidate_landmarks = lambda i: [0, 2]  # a pre-gate that (wrongly) left out landmark 1
    tested.clear()
    assert solve(prob) == [0] and 1 not in tested


class UncorrelatedPointProblem(PointProblem):
    """PointProblem whose joint covariance has no vehicle–landmark or landmark–landmark terms (the
    graph's case: the low-rank joint applies)."""


@pytest.mark.parametrize("seed", range(6))
def test_low_rank_joint_nis_equals_the_direct_one(seed):
    from semslam.mapping.association import LowRankJoint

    rng = np.random.default_rng(seed)
    m = 6
    L = rng.uniform(-1, 1, (m, 3))
    P = np.diag(np.r_[rng.uniform(0.01, 0.3, 3) ** 2, rng.uniform(0.005, 0.05, 3 * m) ** 2])
    A = rng.normal(size=(3, 3))
    P[:3, :3] = A @ A.T * 0.01 + np.eye(3) * 1e-4  # a full vehicle block
    Z = L + rng.normal(0, 0.05, (m, 3))
    prob = UncorrelatedPointProblem(np.zeros(3), L, P, Z, np.eye(3) * 0.02**2)
    found, _ = candidates(prob)
    joint = LowRankJoint(found, P[:3, :3], lambda j: P[3 + 3 * j : 6 + 3 * j, 3 + 3 * j : 6 + 3 * j])
    node = joint.root()
    pairs = []
    for i in rng.permutation(m):
        i = j = int(i)
        node = joint.extend(node, found.pair(i, j), np.inf)
        pairs.append((i, j))
        assert node.nis == pytest.approx(joint_nis(prob, pairs), rel=1e-9)


@pytest.mark.parametrize("seed", range(8))
def test_low_rank_path_finds_the_same_hypothesis(seed):
    rng = np.random.default_rng(100 + seed)
    m = 6
    L = rng.uniform(-1, 1, (m, 3))
    x_true = rng.normal(0, 0.2, 3)
    Z = [L[j] - x_true + rng.normal(0, 0.02, 3) for j in rng.choice(m, 5, replace=False)]
    Z.append(rng.uniform(-1, 1, 3))
    P = _joint_cov(m, 0.2, 0.02)
    general = PointProblem(np.zeros(3), L, P, Z, np.eye(3) * 0.02**2)
    fast = UncorrelatedPointProblem(np.zeros(3), L, P, Z, np.eye(3) * 0.02**2)
    assert solve(fast, joint="low_rank") == solve(general, joint="dense") == solve(general, joint="direct")


def test_many_landmarks_and_numpy_candidate_indices():
    """Landmark sets are bit masks: more than 64 landmarks, candidates given as numpy integers."""
    m = 100
    L = np.column_stack([np.arange(m) * 1.0, np.zeros(m), np.zeros(m)])
    Z = [L[j] + [0.001, 0, 0] for j in (3, 70, 99)]
    prob = UncorrelatedPointProblem(np.zeros(3), L, _joint_cov(m, 0.01, 0.01), Z, np.eye(3) * 0.01**2)
    # a few candidates each, beyond bit 64 too (every landmark a candidate costs 300² cross blocks)
    prob.candidate_landmarks = lambda i: np.array([0, 3, 64, 70, 71, 98, 99], dtype=np.int64)
    assert solve(prob, joint="low_rank") == [3, 70, 99]
    found, S = candidates(prob)
    assert jcbb(found, DenseJoint(found, S)) == [3, 70, 99]
