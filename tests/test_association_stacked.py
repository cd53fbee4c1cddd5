"""The graph's gates and information, computed for the pairs of one shape at once (stacked products and
solves), give the numbers of one pair alone to the bit: the association's decisions and the landmarks'
information must not move by a rounding."""

import numpy as np

from semslam.backend.landmarks import _information, _informations
from semslam.mapping.association import Candidates, LowRankJoint, PairLinearization, nis, uncorrelated_candidates


def _spd(rng, n):
    A = rng.normal(size=(n, n))
    return A @ A.T + 0.1 * np.eye(n)


def _pairs(seed=0, n=24):
    """Linearisations of points (3), lines (4) and structures (6), with non-contiguous Jacobians (as
    the problem's slices hand them over), and a landmark covariance each."""
    rng = np.random.default_rng(seed)
    lins, covs = [], []
    for k in range(n):
        d = (3, 4, 6)[k % 3]
        lins.append(
            PairLinearization(rng.normal(size=d), rng.normal(size=(6, d)).T, rng.normal(size=(d, d)).T, _spd(rng, d))
        )
        covs.append(_spd(rng, d))
    return lins, covs, _spd(rng, 6), _spd(rng, 6)


def test_stacked_gate_is_the_pair_by_pair_gate_to_the_bit():
    lins, covs, P, _ = _pairs()
    covs[4] = np.zeros((4, 4))  # a singular S in the lines' stack: that stack goes pair by pair
    lins[4] = PairLinearization(lins[4].innovation, np.zeros((4, 6)), np.zeros((4, 4)), np.zeros((4, 4)))
    pairs = [(k % 5, k, lin) for k, lin in enumerate(lins)]
    found = uncorrelated_candidates(5, pairs, P, lambda j: covs[j], 1.0 - 1e-12)
    expected = [
        nis(np.asarray(lin.innovation, float), lin.H_x @ P @ lin.H_x.T + lin.H_l @ covs[k] @ lin.H_l.T + lin.R)
        for k, lin in enumerate(lins)
    ]
    assert np.isinf(expected[4])
    kept = [k for k in range(len(lins)) if k != 4]
    assert found.lm.tolist() == kept
    assert found.nis.tolist() == [expected[k] for k in kept]  # exact equality, not approximate


def test_stacked_information_is_the_pair_by_pair_information_to_the_bit():
    lins, _, P, P_gate = _pairs(1)
    out = _informations(lins, P, P_gate)
    for lin, (info, gate_info) in zip(lins, out):
        assert np.array_equal(info, _information(lin.H_x, lin.H_l, lin.R, P))
        assert np.array_equal(gate_info, _information(lin.H_x, lin.H_l, lin.R, P_gate))


def test_stacked_joint_terms_are_the_pair_by_pair_terms_to_the_bit():
    lins, covs, P, _ = _pairs(2)
    cands = Candidates(len(lins), np.arange(len(lins)), np.arange(len(lins)), lins, np.zeros(len(lins)))
    stacked = LowRankJoint(cands, P, lambda j: covs[j])
    one = LowRankJoint(cands, P, lambda j: covs[j])
    for k in range(len(lins)):
        one._terms = {-1: None}  # not empty: the term of k alone, as before the stacking
        a, b = stacked._term(k), one._term(k)
        assert a[0] == b[0] and np.array_equal(a[1], b[1]) and np.array_equal(a[2], b[2])
