"""Association problems written pair by pair, and the references JCBB is checked against.

A *callback problem* has ``n_observations``, ``n_landmarks``, ``pair(i, j)`` (a PairLinearization or
None) and ``covariance(a, b)`` (the cross-covariance block of the vehicle, ``None``, or landmark j).
"""

from __future__ import annotations

import numpy as np

from semslam.mapping.association import Candidates, DenseJoint, LowRankJoint, Node, jcbb


def _cross(prob, pa, ja, pb, jb) -> np.ndarray:
    """Covariance between the predicted measurements of two pairs (without R)."""
    s = pa.H_x @ prob.covariance(None, None) @ pb.H_x.T
    s = s + pa.H_x @ prob.covariance(None, jb) @ pb.H_l.T
    s = s + pa.H_l @ prob.covariance(ja, None) @ pb.H_x.T
    return s + pa.H_l @ prob.covariance(ja, jb) @ pb.H_l.T


def individual_nis(prob, i: int, j: int) -> float:
    """Mahalanobis distance² of observation i against landmark j (inf if they cannot pair)."""
    return joint_nis(prob, [(i, j)])


def joint_nis(prob, pairs: list[tuple[int, int]]) -> float:
    """Joint Mahalanobis distance² of a hypothesis [(i, j), ...], solved directly."""
    if not pairs:
        return 0.0
    lins = [(j, prob.pair(i, j)) for i, j in pairs]
    if any(p is None for _, p in lins):
        return float("inf")
    nu = np.concatenate([np.asarray(p.innovation, float) for _, p in lins])
    S = np.block([[_cross(prob, pa, ja, pb, jb) for jb, pb in lins] for ja, pa in lins])
    n = 0
    for _, p in lins:
        d = len(p.innovation)
        S[n : n + d, n : n + d] += p.R
        n += d
    return float(nu @ np.linalg.solve(S, nu))


def candidates(prob) -> tuple[Candidates, np.ndarray]:
    """Every pair of a callback problem (those ``pair`` does not refuse) with its individual NIS, and
    the joint covariance of all their innovations, stacked in candidate order."""
    obs, lm, lins = [], [], []
    candidates_of = getattr(prob, "candidate_landmarks", None)
    for i in range(prob.n_observations):
        for j in candidates_of(i) if candidates_of is not None else range(prob.n_landmarks):
            p = prob.pair(i, int(j))
            if p is not None:
                obs.append(i), lm.append(int(j)), lins.append(p)
    sizes = [len(p.innovation) for p in lins]
    at = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
    S = np.zeros((at[-1], at[-1]))
    for a, (pa, ja) in enumerate(zip(lins, lm)):
        for b, (pb, jb) in enumerate(zip(lins, lm)):
            S[at[a] : at[a + 1], at[b] : at[b + 1]] = _cross(prob, pa, ja, pb, jb) + (pa.R if a == b else 0.0)
    nis = [
        float(p.innovation @ np.linalg.solve(S[at[k] : at[k + 1], at[k] : at[k + 1]], p.innovation))
        for k, p in enumerate(lins)
    ]
    found = Candidates(prob.n_observations, np.array(obs, int), np.array(lm, int), lins, np.array(nis, float))
    return found, S


class DirectJoint:
    """The reference joint covariance: every node's joint NIS solved afresh from S (no Schur step)."""

    def __init__(self, found: Candidates, S: np.ndarray):
        self.found, self.S = found, S
        at = np.concatenate([[0], np.cumsum([len(p.innovation) for p in found.lin])]).astype(int)
        self.rows = [np.arange(at[k], at[k + 1]) for k in range(len(found.lin))]
        self.nu = np.concatenate([p.innovation for p in found.lin]) if found.lin else np.zeros(0)

    def root(self) -> Node:
        return Node([], 0.0, 0)

    def extend(self, node: Node, k: int, limit: float) -> Node | None:
        pairs = node.pairs + [(int(self.found.obs[k]), int(self.found.lm[k]), k)]
        r = np.concatenate([self.rows[kk] for *_, kk in pairs])
        d2 = float(self.nu[r] @ np.linalg.solve(self.S[np.ix_(r, r)], self.nu[r]))
        return Node(pairs, d2, len(r)) if d2 < limit else None


def solve(prob, confidence: float = 0.99, joint: str = "dense", **kwargs) -> list[int | None]:
    """The one JCBB on a callback problem, with the ``dense``, ``direct`` (reference) or ``low_rank``
    (landmarks uncorrelated: the problem's cross blocks must be zero) joint covariance."""
    found, S = candidates(prob)
    if joint == "dense":
        model = DenseJoint(found, S)
    elif joint == "direct":
        model = DirectJoint(found, S)
    else:
        model = LowRankJoint(found, prob.covariance(None, None), lambda j: prob.covariance(j, j))
    return jcbb(found, model, confidence, **kwargs)
