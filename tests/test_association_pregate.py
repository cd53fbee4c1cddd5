"""The graph's vectorised pre-gate (``possible_pairs``) is conservative: it never rejects a pair
that the exact individual χ² gate would accept, and it does reject far-off pairs."""

import gtsam
import numpy as np
import pytest
from scipy.stats import chi2

from factors.landmarks import LineAnchor
from semslam.backend.landmarks import Landmark
from semslam.backend.problem import Candidate, GraphAssociationProblem, possible_pairs
from semslam.config import AssociationConfig
from semslam.mapping.association import uncorrelated_candidates
from semslam.mapping.book import LandmarkBook
from semslam.mapping.builder import Scan
from semslam.observations import LineObservation, PointObservation

GATES = {d: float(chi2.ppf(0.99, d)) for d in (3, 4)}
BOOK = LandmarkBook()  # what was seen of the pipes: 10 m of their lines


def random_spd(rng, n, scale):
    A = rng.normal(size=(n, n))
    return A @ A.T * scale**2 / n + np.eye(n) * 1e-6


def scene(rng):
    pose = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 0.5, 3)), rng.normal(0, 2, 3))
    pose_cov = random_spd(rng, 6, rng.uniform(0.005, 0.05))
    T_BS = np.eye(4)
    T_BS[:3, :3] = gtsam.Rot3.Expmap(rng.normal(0, 0.5, 3)).matrix()
    T_BS[:3, 3] = rng.normal(0, 0.3, 3)
    T_WS = pose.compose(gtsam.Pose3(T_BS))
    cands, obs = [], []
    for k in range(6):  # objects: observations near their landmark, at various offsets
        l = T_WS.transformFrom(rng.normal(0, 1.5, 3) + [0, 0, 3])
        lm = Landmark(k, "object", gtsam.symbol_shorthand.L(k), estimate=l, covariance=random_spd(rng, 3, 0.02))
        cands.append(Candidate(lm, lm.covariance))
        z = T_WS.transformTo(l + rng.normal(0, rng.choice([0.01, 0.05, 0.2]), 3))
        obs.append(PointObservation(0, "s", position=z, covariance=random_spd(rng, 3, 0.02)))
    for k in range(6):  # pipes
        p = T_WS.transformFrom(rng.normal(0, 1.5, 3) + [0, 0, 3])
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        anchor = LineAnchor.from_points(p, p + d)
        theta = rng.normal(0, 0.05, 4)
        c, u = anchor.point(theta), anchor.direction(theta)
        BOOK.extent(10 + k).add(np.array([c - 5 * u, c + 5 * u]), 0.01)
        lm = Landmark(
            10 + k,
            "pipe",
            gtsam.symbol_shorthand.P(k),
            anchor=anchor,
            estimate=theta,
            covariance=random_spd(rng, 4, 0.02),
        )
        cands.append(Candidate(lm, lm.covariance))
        off = rng.normal(0, rng.choice([0.01, 0.05, 0.2]), 3)
        a, b = c + off + rng.uniform(-1, 0) * u, c + off + rng.uniform(0.2, 1) * u
        obs.append(
            LineObservation(0, "s", p=T_WS.transformTo(a), q=T_WS.transformTo(b), covariance=random_spd(rng, 6, 0.02))
        )
    return pose, pose_cov, obs, [T_BS] * len(obs), cands


@pytest.mark.parametrize("seed", range(10))
def test_never_rejects_an_individually_compatible_pair(seed):
    rng = np.random.default_rng(seed)
    pose, pose_cov, obs, T_BS, cands = scene(rng)
    mask = possible_pairs(pose, pose_cov, obs, T_BS, cands, GATES)
    everything = np.ones_like(mask)
    scan = Scan(BOOK, AssociationConfig(pipe_extent_gap_m=10.0), np.zeros((0, 3)), np.zeros((0, 3)))
    problem = GraphAssociationProblem(pose, obs, T_BS, cands, everything, scan)
    pairs = [(i, j, problem.pair(i, j)) for i in range(len(obs)) for j in range(len(cands))]
    found = uncorrelated_candidates(
        len(obs), [t for t in pairs if t[2] is not None], pose_cov, problem.landmark_covariance, 0.99
    )
    assert len(found.obs) > 0  # individually compatible at the exact gate
    for i, j in zip(found.obs, found.lm):
        assert mask[i, j], (i, j)


def test_rejects_far_pairs_and_other_kinds():
    rng = np.random.default_rng(0)
    pose, pose_cov, obs, T_BS, cands = scene(rng)
    mask = possible_pairs(pose, np.eye(6) * 1e-6, obs, T_BS, cands, GATES)
    kinds_obs = np.array([isinstance(z, PointObservation) for z in obs])
    kinds_lm = np.array([c.landmark.kind == "object" for c in cands])
    assert not mask[np.ix_(kinds_obs, ~kinds_lm)].any() and not mask[np.ix_(~kinds_obs, kinds_lm)].any()
    # landmarks metres apart with centimetre covariances: most cross pairs are ruled out
    assert mask.sum() < 0.3 * mask.size
