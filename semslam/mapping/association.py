"""Data association by Joint Compatibility Branch and Bound (Neira & Tardós 2001): one search for every
estimator, with the joint innovation covariance behind one interface.

The estimator linearises the observations of a scan against its landmarks and hands over the
individually compatible pairs (:class:`Candidates`: innovation, Jacobians over the vehicle block and
the landmark's block, noise, individual NIS) and how the joint NIS of a hypothesis grows
(:class:`JointCovariance`):

- :class:`DenseJoint`: the estimator gives the joint covariance of every candidate's innovation,
  S = J P Jᵀ + R (the EKF: one product over its full covariance); a node of the search is a
  Schur-complement step on slices of it, and a child's joint NIS is known before its inverse
  covariance is built (rejected children never build it);
- :class:`LowRankJoint`: landmarks uncorrelated with each other and with the vehicle (the graph, which
  gates with each landmark's own covariance): S_H is block diagonal D plus the low-rank vehicle term
  U P Uᵀ, and by the Woodbury identity
      ν_Hᵀ S_H⁻¹ ν_H = Σ_i ν_iᵀ D_i⁻¹ ν_i − bᵀ (I + P M)⁻¹ P b,
      b = Σ_i U_iᵀ D_i⁻¹ ν_i,   M = Σ_i U_iᵀ D_i⁻¹ U_i,
  so a node adds a scalar, a vector and a matrix of the vehicle block's size: its cost does not grow
  with the depth of the hypothesis.

The search (:func:`jcbb`): a hypothesis H = {(i, j_i)} is jointly compatible when
ν_Hᵀ S_H⁻¹ ν_H < χ²(Σ d_i, confidence), and every hypothesis on the search path must be. Pairings are
one-to-one; the hypothesis with the most pairings wins (among equally many reached before the bound
prunes, the smaller joint NIS). Observations are searched most certain first (by their best individual
NIS): the order decides which of two conflicting observations stays out, and the well-predicted ones
should not be the ones dropped (a front-end's output order is arbitrary). A branch that cannot pair
more observations than the best found is cut, by the maximum matching of the remaining observations
to unused landmarks. A search still running after ``seed_after`` nodes is started again with a
greedy jointly compatible hypothesis as the best so far, so that every branch that cannot beat it is
cut from the start.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Protocol

import numpy as np
from scipy.stats import chi2


@dataclass
class PairLinearization:
    """Linearisation of observation i against landmark j."""

    innovation: np.ndarray  # (d,) z_i - h_i(x, l_j)
    H_x: np.ndarray  # (d, n_x) Jacobian wrt the vehicle block
    H_l: np.ndarray  # (d, n_lj) Jacobian wrt landmark j's block
    R: np.ndarray  # (d, d) observation noise in the innovation's coordinates


@lru_cache(maxsize=4096)
def chi2_gate(confidence: float, dof: int) -> float:
    """The χ² quantile of ``dof`` degrees of freedom at ``confidence`` (scipy's ppf costs ~0.1 ms: cached)."""
    return float(chi2.ppf(confidence, dof))


def inv_small(S: np.ndarray) -> np.ndarray:
    """Inverse of a small symmetric positive-definite matrix (closed form up to 3×3 from its upper
    triangle: numpy's per-call cost dominates at this size)."""
    d = S.shape[0]
    if d == 1:
        return np.array([[1.0 / S[0, 0]]])
    if d == 3:
        (a, b, c), (_, e, f), (_, _, i) = S.tolist()
        A, B, C = e * i - f * f, c * f - b * i, b * f - c * e
        det = a * A + b * B + c * C
        if det > 0.0:
            E, F, I = a * i - c * c, b * c - a * f, a * e - b * b
            r = 1.0 / det
            return np.array([[A * r, B * r, C * r], [B * r, E * r, F * r], [C * r, F * r, I * r]])
    return np.linalg.inv(S)


def nis(nu: np.ndarray, S: np.ndarray) -> float:
    """νᵀ S⁻¹ ν (inf when S is singular)."""
    try:
        return float(nu @ np.linalg.solve(S, nu))
    except np.linalg.LinAlgError:
        return math.inf


@dataclass
class Candidates:
    """The pairs of one scan that may be associated: pair k is observation ``obs[k]`` and landmark
    ``lm[k]`` (the estimator's indices), its linearisation ``lin[k]`` and its individual NIS ``nis[k]``."""

    n_obs: int
    obs: np.ndarray  # (K,) int
    lm: np.ndarray  # (K,) int
    lin: list[PairLinearization]
    nis: np.ndarray  # (K,)

    @classmethod
    def empty(cls, n_obs: int) -> Candidates:
        return cls(n_obs, np.zeros(0, int), np.zeros(0, int), [], np.zeros(0))

    def dof(self, k: int) -> int:
        return len(self.lin[k].innovation)

    def passing(self, confidence: float) -> np.ndarray:
        """Indices of the pairs individually compatible at ``confidence``."""
        return np.array([k for k in range(len(self.obs)) if self.nis[k] < chi2_gate(confidence, self.dof(k))], int)

    def subset(self, ks: np.ndarray) -> Candidates:
        return Candidates(self.n_obs, self.obs[ks], self.lm[ks], [self.lin[k] for k in ks], self.nis[ks])

    def best(self, i: int) -> int | None:
        """The pair of observation i with the smallest individual NIS, or None."""
        ks = np.flatnonzero(self.obs == i)
        return int(ks[np.argmin(self.nis[ks])]) if len(ks) else None

    def pair(self, i: int, j: int) -> int | None:
        """The index of the pair (observation i, landmark j), or None."""
        ks = np.flatnonzero((self.obs == i) & (self.lm == j))
        return int(ks[0]) if len(ks) else None


def uncorrelated_candidates(
    n_obs: int,
    pairs: list[tuple[int, int, PairLinearization]],
    vehicle_cov: np.ndarray,
    landmark_cov,
    confidence: float,
) -> Candidates:
    """The ``pairs`` (i, j, linearisation) individually compatible at ``confidence`` when landmark j
    (covariance ``landmark_cov(j)``) is uncorrelated with the vehicle (``vehicle_cov``) and the others:
    S = H_x P H_xᵀ + H_l C_j H_lᵀ + R.

    The pairs of one shape (innovation and landmark sizes) are gated at once: stacked products and one
    stacked solve, which numpy evaluates matrix by matrix with the same BLAS / LAPACK calls as one pair
    alone (the same numbers to the bit); the per-call overheads were most of the cost."""
    d2s = np.empty(len(pairs))
    for ks in indices_by_shape([p for _, _, p in pairs]):
        d2s[ks] = _stacked_nis([pairs[k] for k in ks], vehicle_cov, landmark_cov)
    keep = []
    for (i, j, p), d2 in zip(pairs, d2s):
        if d2 < chi2_gate(confidence, len(p.innovation)):
            keep.append((i, j, p, float(d2)))
    return Candidates(
        n_obs,
        np.array([i for i, *_ in keep], int),
        np.array([j for _, j, *_ in keep], int),
        [p for *_, p, _ in keep],
        np.array([d for *_, d in keep], float),
    )


def indices_by_shape(lins) -> list[list[int]]:
    """The indices of the linearisations ``lins`` grouped by their H_l's shape (in first-seen order): the
    pairs one stacked product or solve can take together."""
    shapes: dict[tuple[int, int], list[int]] = {}
    for k, lin in enumerate(lins):
        shapes.setdefault(lin.H_l.shape, []).append(k)
    return list(shapes.values())


def _stacked_nis(pairs: list[tuple[int, int, PairLinearization]], vehicle_cov: np.ndarray, landmark_cov) -> list[float]:
    """:func:`nis` of each pair's innovation with S = H_x P H_xᵀ + H_l C_j H_lᵀ + R, for pairs of one
    shape; a singular S (its solve fails the stack) is taken pair by pair (inf)."""
    H_x = np.array([p.H_x for _, _, p in pairs], float)
    H_l = np.array([p.H_l for _, _, p in pairs], float)
    C = np.array([landmark_cov(j) for _, j, _ in pairs], float)
    nu = np.array([p.innovation for _, _, p in pairs], float)
    S = H_x @ vehicle_cov @ H_x.transpose(0, 2, 1) + H_l @ C @ H_l.transpose(0, 2, 1)
    S += np.array([p.R for _, _, p in pairs], float)
    try:
        x = np.linalg.solve(S, nu[..., None])[..., 0]
    except np.linalg.LinAlgError:
        return [nis(nu[k], S[k]) for k in range(len(pairs))]
    return [float(nu[k] @ x[k]) for k in range(len(pairs))]  # the 1-D dot of one pair (einsum sums otherwise)


@dataclass
class Node:
    """A hypothesis on the search path: its pairs [(observation, landmark, pair index)], joint NIS and dof."""

    pairs: list
    nis: float
    dof: int


class JointCovariance(Protocol):
    """How the joint NIS of a hypothesis grows, pair by pair."""

    def root(self) -> Node: ...

    def extend(self, node: Node, k: int, limit: float) -> Node | None:
        """``node`` with pair k added, if its joint NIS stays below ``limit`` (else None)."""


@dataclass
class _DenseNode(Node):
    rows: np.ndarray  # rows of the stacked innovation in S
    w: np.ndarray  # S_H⁻¹ ν_H
    S_inv: np.ndarray


class DenseJoint:
    """Joint NIS from the full joint covariance S (rows of every candidate's innovation, stacked in
    candidate order): any correlation structure, a Schur-complement step per node."""

    def __init__(self, candidates: Candidates, S: np.ndarray):
        self.cands = candidates
        self.S = S
        self.rows: list[np.ndarray] = []
        r = 0
        for p in candidates.lin:
            self.rows.append(np.arange(r, r + len(p.innovation)))
            r += len(p.innovation)
        self.nu = np.concatenate([np.asarray(p.innovation, float) for p in candidates.lin]) if r else np.zeros(0)
        self.blocks = [S[np.ix_(rr, rr)] for rr in self.rows]

    def root(self) -> _DenseNode:
        return _DenseNode([], 0.0, 0, np.zeros(0, int), np.zeros(0), np.zeros((0, 0)))

    def extend(self, node: _DenseNode, k: int, limit: float) -> _DenseNode | None:
        r, nu_k, Ck = self.rows[k], self.nu[self.rows[k]], self.blocks[k]
        i, j = int(self.cands.obs[k]), int(self.cands.lm[k])
        if not node.pairs:
            Si = inv_small(Ck)
            d2 = float(nu_k @ Si @ nu_k)
            if not d2 < limit:
                return None
            return _DenseNode([(i, j, k)], d2, len(r), np.asarray(r), Si @ nu_k, Si)
        B = self.S[np.ix_(node.rows, r)]  # (D, d)
        KB = node.S_inv @ B
        try:
            Si = inv_small(Ck - B.T @ KB)
        except np.linalg.LinAlgError:
            return None
        res = nu_k - B.T @ node.w
        d2 = node.nis + float(res @ Si @ res)
        if not d2 < limit:  # the child's NIS decides before its inverse covariance is built
            return None
        D, d = len(node.rows), len(r)
        S_inv = np.empty((D + d, D + d))
        KS = KB @ Si
        S_inv[:D, :D] = node.S_inv + KS @ KB.T
        S_inv[:D, D:] = -KS
        S_inv[D:, :D] = -KS.T
        S_inv[D:, D:] = Si
        Sr = Si @ res
        w = np.concatenate([node.w - KB @ Sr, Sr])
        return _DenseNode(node.pairs + [(i, j, k)], d2, node.dof + d, np.concatenate([node.rows, r]), w, S_inv)


@dataclass
class _LowRankNode(Node):
    a: float  # Σ ν_iᵀ D_i⁻¹ ν_i
    b: np.ndarray  # Σ U_iᵀ D_i⁻¹ ν_i
    M: np.ndarray  # Σ U_iᵀ D_i⁻¹ U_i


class LowRankJoint:
    """Joint NIS for landmarks uncorrelated with the vehicle and each other (covariance
    ``landmark_cov(j)``): O(n_x³) a node whatever the hypothesis' depth."""

    def __init__(self, candidates: Candidates, vehicle_cov: np.ndarray, landmark_cov):
        self.cands = candidates
        self.P = vehicle_cov
        self.n_x = vehicle_cov.shape[0]
        self._eye = np.eye(self.n_x)
        self.landmark_cov = landmark_cov
        self._terms: dict[int, tuple[float, np.ndarray, np.ndarray] | None] = {}

    def root(self) -> _LowRankNode:
        return _LowRankNode([], 0.0, 0, 0.0, np.zeros(self.n_x), np.zeros((self.n_x, self.n_x)))

    def _stack_terms(self) -> None:
        """Every pair's term at once, the pairs of one shape stacked (see :func:`uncorrelated_candidates`:
        the same numbers as pair by pair); a shape whose stack holds a singular D stays pair by pair."""
        for ks in indices_by_shape(self.cands.lin):
            lins = [self.cands.lin[k] for k in ks]
            H_x = np.array([p.H_x for p in lins], float)
            H_l = np.array([p.H_l for p in lins], float)
            C = np.array([self.landmark_cov(int(self.cands.lm[k])) for k in ks], float)
            D = H_l @ C @ H_l.transpose(0, 2, 1) + np.array([p.R for p in lins], float)
            nu = np.array([p.innovation for p in lins], float)
            try:
                W = np.linalg.solve(D, np.concatenate([nu[:, :, None], H_x], axis=2))  # D⁻¹ [ν | U]
            except np.linalg.LinAlgError:
                continue
            for n, (k, p) in enumerate(zip(ks, lins)):  # the products as for one pair (a vector's is not a stack's)
                self._terms[k] = (float(nu[n] @ W[n, :, 0]), p.H_x.T @ W[n, :, 0], p.H_x.T @ W[n, :, 1:])

    def _term(self, k: int):
        if not self._terms and len(self.cands.lin) > 1:
            self._stack_terms()
        if k not in self._terms:
            p = self.cands.lin[k]
            D = p.H_l @ self.landmark_cov(int(self.cands.lm[k])) @ p.H_l.T + p.R
            nu = np.asarray(p.innovation, dtype=float)
            try:
                W = np.linalg.solve(D, np.column_stack([nu, p.H_x]))  # D⁻¹ [ν | U]
                self._terms[k] = (float(nu @ W[:, 0]), p.H_x.T @ W[:, 0], p.H_x.T @ W[:, 1:])
            except np.linalg.LinAlgError:
                self._terms[k] = None
        return self._terms[k]

    def extend(self, node: _LowRankNode, k: int, limit: float) -> _LowRankNode | None:
        t = self._term(k)
        if t is None:
            return None
        a, b, M = node.a + t[0], node.b + t[1], node.M + t[2]
        try:
            y = np.linalg.solve(self._eye + self.P @ M, self.P @ b)
        except np.linalg.LinAlgError:
            return None
        d2 = a - float(b @ y)
        if not d2 < limit:
            return None
        i, j = int(self.cands.obs[k]), int(self.cands.lm[k])
        return _LowRankNode(node.pairs + [(i, j, k)], d2, node.dof + self.cands.dof(k), a, b, M)


def cannot_beat_best(masks: list[int], start: int, used: int, npairs: int, best: int) -> bool:
    """Branch-and-bound test: can no extension of a node with ``npairs`` pairs, at search position
    ``start``, pair more observations than ``best``?

    ``masks[o]`` is the set of landmarks observation o is individually compatible with, as a bit
    mask (Python ints: any width); ``used`` the landmarks paired on the current path. First the
    cheap count of observations that still have an unused candidate, then the exact bound: the
    maximum bipartite matching of the remaining observations to distinct unused landmarks (Kuhn's
    augmenting paths), tighter where observations compete for a landmark."""
    free = ~used
    rest = masks[start:]
    if npairs + sum(1 for mask in rest if mask & free) <= best:
        return True
    owner: dict[int, int] = {}

    def augment(o: int, seen: list[int]) -> bool:
        options = masks[o] & free & ~seen[0]
        while options:
            low = options & -options
            options ^= low
            if seen[0] & low:  # visited by a deeper augmenting path meanwhile
                continue
            seen[0] |= low
            j = low.bit_length() - 1
            if j not in owner or augment(owner[j], seen):
                owner[j] = o
                return True
        return False

    return npairs + sum(1 for o in range(start, len(masks)) if masks[o] & free and augment(o, [0])) <= best


def jcbb(
    candidates: Candidates,
    joint: JointCovariance,
    confidence: float = 0.99,
    max_hypotheses: int = 20_000,
    seed_after: int = 300,
    stats: dict | None = None,
) -> list[int | None]:
    """Joint Compatibility Branch and Bound over ``candidates`` (see the module).

    Returns, for each of the scan's observations, the landmark it pairs with, or None (a new landmark
    or a spurious observation). ``max_hypotheses`` bounds the nodes expanded (the best hypothesis found
    by then is returned). ``stats``, when given, receives the number of nodes expanded (``"nodes"``),
    whether the search was cut by ``max_hypotheses`` (``"capped"``) and whether it was seeded
    (``"seeded"``)."""
    n_obs = candidates.n_obs
    result: list[int | None] = [None] * n_obs
    # Individual compatibility; the candidates of each observation by increasing NIS.
    cands: list[list[tuple[float, int, int]]] = [[] for _ in range(n_obs)]
    for k in range(len(candidates.obs)):
        d2 = float(candidates.nis[k])
        if d2 < chi2_gate(confidence, candidates.dof(k)):
            cands[int(candidates.obs[k])].append((d2, int(candidates.lm[k]), k))
    for c in cands:
        c.sort(key=lambda t: t[0])
    order = sorted((i for i in range(n_obs) if cands[i]), key=lambda i: cands[i][0][0])
    if not order:
        return result
    C = [cands[i] for i in order]
    m = len(order)
    masks = [sum(1 << j for _, j, _ in c) for c in C]  # landmark sets as bit masks

    best_pairs: list = []
    best_nis = math.inf
    expanded = 0
    limit = min(max_hypotheses, seed_after)
    used = 0  # bit mask of the landmarks paired on the current path

    def gate(node: Node, k: int) -> float:
        return chi2_gate(confidence, node.dof + candidates.dof(k))

    def search(node: Node, i: int) -> None:
        nonlocal best_pairs, best_nis, expanded, used
        npairs = len(node.pairs)
        if i == m:
            if npairs > len(best_pairs) or (npairs == len(best_pairs) and npairs > 0 and node.nis < best_nis):
                best_pairs, best_nis = list(node.pairs), node.nis
            return
        if expanded >= limit:
            return
        if best_pairs and cannot_beat_best(masks, i, used, npairs, len(best_pairs)):
            return
        for _, j, k in C[i]:
            if used >> j & 1:
                continue
            expanded += 1
            child = joint.extend(node, k, gate(node, k))
            if child is None:
                continue
            used |= 1 << j
            search(child, i + 1)
            used &= ~(1 << j)
        # Star branch: observation i unpaired, worth it only if it can still beat the best.
        if not cannot_beat_best(masks, i + 1, used, npairs, len(best_pairs)):
            search(node, i + 1)

    def seed() -> Node:
        """A jointly compatible hypothesis built greedily (pairs by increasing individual NIS), then
        kept prefix-compatible in the search order (a leaf the search itself could reach)."""
        node = root
        taken_obs: set[int] = set()
        taken_lm: set[int] = set()
        chosen = []
        for _, li, j, k in sorted((d2, li, j, k) for li, c in enumerate(C) for d2, j, k in c):
            if li in taken_obs or j in taken_lm:
                continue
            child = joint.extend(node, k, gate(node, k))
            if child is not None:
                node = child
                taken_obs.add(li)
                taken_lm.add(j)
                chosen.append((li, k))
        node = root
        for _, k in sorted(chosen):
            child = joint.extend(node, k, gate(node, k))
            node = child if child is not None else node
        return node

    root = joint.root()
    search(root, 0)
    seeded = False
    if expanded >= limit and limit < max_hypotheses:
        seeded = True
        node = seed()
        if len(node.pairs) > len(best_pairs):
            best_pairs, best_nis = list(node.pairs), node.nis
        limit = max_hypotheses
        search(root, 0)
    if stats is not None:
        stats["nodes"] = expanded
        stats["capped"] = expanded >= max_hypotheses
        stats["seeded"] = seeded
    for i, j, _ in best_pairs:
        result[i] = j
    return result
