"""Data association by Joint Compatibility Branch and Bound (Neira & Tardós, 2001).

Shared by the graph back-end and the EKF, so it knows nothing of either: the caller describes the
problem through :class:`AssociationProblem` (innovations, Jacobians, and covariance blocks of its
state), and :func:`jcbb` returns, for each observation, the landmark it pairs with, or None.

For a hypothesis H = {(i, j_i)}, the joint innovation ν_H stacks the pair innovations and
S_H = J P Jᵀ + R with J = [H_x | H_l] over the vehicle block and the paired landmark blocks.
H is jointly compatible when ν_Hᵀ S_H⁻¹ ν_H < χ²(Σ d_i, confidence). The branch and bound keeps
the hypothesis with the most pairings (among hypotheses of equal size reached before the bound
prunes, the smaller joint NIS); observations are searched most certain first. The joint NIS is grown one
pair at a time by a Schur-complement update, so a node costs O(k²d) rather than a fresh inverse.

When the problem declares ``uncorrelated_landmarks`` (no vehicle–landmark and no landmark–landmark
covariance, as in the graph back-end, which gates with single-variable marginals), S_H is a block
diagonal D plus the low-rank vehicle term U P Uᵀ, and by the Woodbury identity
    ν_Hᵀ S_H⁻¹ ν_H = Σ_i ν_iᵀ D_i⁻¹ ν_i − bᵀ (I + P M)⁻¹ P b,
    b = Σ_i U_iᵀ D_i⁻¹ ν_i,   M = Σ_i U_iᵀ D_i⁻¹ U_i,
so a node only adds a scalar, a vector and a matrix of the vehicle block's size: its cost no
longer grows with the depth of the hypothesis.
"""

from __future__ import annotations

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


class AssociationProblem(Protocol):
    n_observations: int
    n_landmarks: int

    def pair(self, i: int, j: int) -> PairLinearization | None:
        """None when observation i cannot be landmark j (other kind, incompatible class, ...)."""

    def covariance(self, a: int | None, b: int | None) -> np.ndarray:
        """Cross-covariance block: None = the vehicle block, an int = landmark j."""

    # Optional: ``candidate_landmarks(i) -> Iterable[int]``, the landmarks worth testing for observation i
    # (e.g. from a cheap Euclidean pre-gate). Without it every landmark is tested, at ~50 µs a pair.


class _Blocks:
    """Memoised covariance blocks and pair linearisations of one problem."""

    def __init__(self, problem: AssociationProblem):
        self.problem = problem
        self._cov: dict[tuple, np.ndarray] = {}

    def cov(self, a, b) -> np.ndarray:
        key = (a, b)
        if key not in self._cov:
            rev = (b, a)
            if rev in self._cov:
                self._cov[key] = self._cov[rev].T
            else:
                self._cov[key] = np.asarray(self.problem.covariance(a, b), dtype=float)
        return self._cov[key]

    def cross(self, pa: PairLinearization, ja: int, pb: PairLinearization, jb: int) -> np.ndarray:
        """Covariance between the predicted measurements of two pairs (without R)."""
        s = pa.H_x @ self.cov(None, None) @ pb.H_x.T
        s = s + pa.H_x @ self.cov(None, jb) @ pb.H_l.T
        s = s + pa.H_l @ self.cov(ja, None) @ pb.H_x.T
        s = s + pa.H_l @ self.cov(ja, jb) @ pb.H_l.T
        return s


def individual_nis(problem: AssociationProblem, i: int, j: int) -> float:
    """Mahalanobis distance² of observation i against landmark j (inf if they cannot pair)."""
    p = problem.pair(i, j)
    if p is None:
        return float("inf")
    blocks = _Blocks(problem)
    S = blocks.cross(p, j, p, j) + p.R
    return _nis(p.innovation, S)


def joint_nis(problem: AssociationProblem, pairs: list[tuple[int, int]]) -> float:
    """Joint Mahalanobis distance² of a hypothesis [(i, j), ...], computed directly (no Schur update)."""
    if not pairs:
        return 0.0
    blocks = _Blocks(problem)
    lins = [(j, problem.pair(i, j)) for i, j in pairs]
    if any(p is None for _, p in lins):
        return float("inf")
    nu = np.concatenate([np.asarray(p.innovation, dtype=float) for _, p in lins])
    S = np.block([[blocks.cross(pa, ja, pb, jb) for jb, pb in lins] for ja, pa in lins])
    S = S + _block_diag([p.R for _, p in lins])
    return _nis(nu, S)


def _block_diag(mats: list[np.ndarray]) -> np.ndarray:
    n = sum(m.shape[0] for m in mats)
    out = np.zeros((n, n))
    k = 0
    for m in mats:
        d = m.shape[0]
        out[k : k + d, k : k + d] = m
        k += d
    return out


def _nis(nu: np.ndarray, S: np.ndarray) -> float:
    try:
        return float(nu @ np.linalg.solve(S, nu))
    except np.linalg.LinAlgError:
        return float("inf")


@lru_cache(maxsize=1024)
def _chi2_quantile(confidence: float, dof: int) -> float:
    return float(chi2.ppf(confidence, dof))


class _Chi2Table:
    """χ² quantiles by degrees of freedom, computed once each (scipy's ppf costs ~50 µs a call)."""

    def __init__(self, confidence: float):
        self.confidence = confidence

    def __call__(self, dof: int) -> float:
        return _chi2_quantile(self.confidence, dof)


@dataclass
class _Node:
    """A hypothesis on the search path: its pairs and the pieces for the Schur update."""

    pairs: list  # [(i, j, PairLinearization)]
    nu: np.ndarray  # stacked innovation
    S_inv: np.ndarray  # inverse of the joint innovation covariance
    nis: float
    dof: int


class _SchurJoint:
    """Joint NIS grown by Schur complements: any correlation structure, O(k²d) a node."""

    def __init__(self, blocks: _Blocks):
        self.blocks = blocks
        self._cross: dict[tuple[int, int, int, int], np.ndarray] = {}

    def root(self) -> _Node:
        return _Node([], np.zeros(0), np.zeros((0, 0)), 0.0, 0)

    def _pair_cross(self, ia, ja, pa, i, j, p) -> np.ndarray:
        # The same pair-pair blocks recur across sibling hypotheses: compute each once.
        key = (ia, ja, i, j)
        if key not in self._cross:
            self._cross[key] = self.blocks.cross(pa, ja, p, j)
        return self._cross[key]

    def extend(self, node: _Node, i: int, j: int, p: PairLinearization) -> _Node | None:
        nu_new = np.asarray(p.innovation, dtype=float)
        C = self.blocks.cross(p, j, p, j) + p.R
        if not node.pairs:
            try:
                S_inv = np.linalg.inv(C)
            except np.linalg.LinAlgError:
                return None
            nis = float(nu_new @ S_inv @ nu_new)
            return _Node([(i, j, p)], nu_new, S_inv, nis, len(nu_new))
        B = np.vstack([self._pair_cross(ia, ja, pa, i, j, p) for (ia, ja, pa) in node.pairs])  # (D, d_new)
        K = node.S_inv @ B
        schur = C - B.T @ K
        try:
            schur_inv = np.linalg.inv(schur)
        except np.linalg.LinAlgError:
            return None
        r = nu_new - B.T @ (node.S_inv @ node.nu)
        nis = node.nis + float(r @ schur_inv @ r)
        D, d = len(node.nu), len(nu_new)
        S_inv = np.empty((D + d, D + d))
        S_inv[:D, :D] = node.S_inv + K @ schur_inv @ K.T
        S_inv[:D, D:] = -K @ schur_inv
        S_inv[D:, :D] = S_inv[:D, D:].T
        S_inv[D:, D:] = schur_inv
        return _Node(node.pairs + [(i, j, p)], np.concatenate([node.nu, nu_new]), S_inv, nis, node.dof + d)


@dataclass
class _LowRankNode:
    """A hypothesis for uncorrelated landmarks: the Woodbury sums (see the module docstring)."""

    pairs: list  # [(i, j, PairLinearization)]
    a: float  # Σ ν_iᵀ D_i⁻¹ ν_i
    b: np.ndarray  # Σ U_iᵀ D_i⁻¹ ν_i
    M: np.ndarray  # Σ U_iᵀ D_i⁻¹ U_i
    nis: float
    dof: int


class _LowRankJoint:
    """Joint NIS for uncorrelated landmarks: O(n_x³) a node whatever the hypothesis' depth."""

    def __init__(self, blocks: _Blocks):
        self.blocks = blocks
        self.P = blocks.cov(None, None)
        self.n_x = self.P.shape[0]
        self._terms: dict[tuple[int, int], tuple[float, np.ndarray, np.ndarray] | None] = {}

    def root(self) -> _LowRankNode:
        return _LowRankNode([], 0.0, np.zeros(self.n_x), np.zeros((self.n_x, self.n_x)), 0.0, 0)

    def _term(self, i: int, j: int, p: PairLinearization):
        key = (i, j)
        if key not in self._terms:
            D = p.H_l @ self.blocks.cov(j, j) @ p.H_l.T + p.R
            nu = np.asarray(p.innovation, dtype=float)
            try:
                W = np.linalg.solve(D, np.column_stack([nu, p.H_x]))  # D⁻¹ [ν | U]
            except np.linalg.LinAlgError:
                self._terms[key] = None
                return None
            self._terms[key] = (float(nu @ W[:, 0]), p.H_x.T @ W[:, 0], p.H_x.T @ W[:, 1:])
        return self._terms[key]

    def extend(self, node: _LowRankNode, i: int, j: int, p: PairLinearization) -> _LowRankNode | None:
        t = self._term(i, j, p)
        if t is None:
            return None
        a, b, M = node.a + t[0], node.b + t[1], node.M + t[2]
        Pb = self.P @ b
        try:
            y = np.linalg.solve(np.eye(self.n_x) + self.P @ M, Pb)
        except np.linalg.LinAlgError:
            return None
        nis = a - float(b @ y)
        return _LowRankNode(node.pairs + [(i, j, p)], a, b, M, nis, node.dof + len(p.innovation))


def cannot_beat_best(masks: list[int], start: int, used: int, npairs: int, best: int) -> bool:
    """Branch-and-bound test shared by the JCBB searches: can no extension of a node with ``npairs``
    pairs, at search position ``start``, pair more observations than ``best``?

    ``masks[o]`` is the set of landmarks observation o is individually compatible with, as a bit
    mask (Python ints: any width); ``used`` the landmarks paired on the current path. First the
    cheap count of observations that still have an unused candidate, then the exact bound: the
    maximum bipartite matching of the remaining observations to distinct unused landmarks (Kuhn's
    augmenting paths), tighter where observations compete for a landmark."""
    free = ~used
    if npairs + sum(1 for o in range(start, len(masks)) if masks[o] & free) <= best:
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


def jcbb(problem: AssociationProblem, confidence: float = 0.99, max_hypotheses: int = 20_000) -> list[int | None]:
    """Joint Compatibility Branch and Bound.

    Returns, for each observation, the index of the landmark it pairs with, or None (a new
    landmark or a spurious observation). Pairings are one-to-one. Individual compatibility
    χ²(d, confidence) gates the candidates first; joint compatibility χ²(Σd, confidence) the
    hypotheses. ``max_hypotheses`` bounds the nodes expanded; the best hypothesis found so far is
    returned when it is reached.
    """
    n, m = problem.n_observations, problem.n_landmarks
    if n == 0 or m == 0:
        return [None] * n
    blocks = _Blocks(problem)
    gate = _Chi2Table(confidence)
    joint = _LowRankJoint(blocks) if getattr(problem, "uncorrelated_landmarks", False) else _SchurJoint(blocks)

    # Individual compatibility, candidates sorted by NIS so that good hypotheses come first.
    candidates: list[list[tuple[float, int, PairLinearization]]] = []
    candidates_of = getattr(problem, "candidate_landmarks", None)
    for i in range(n):
        row = []
        for j in candidates_of(i) if candidates_of is not None else range(m):
            j = int(j)  # Python ints: landmark sets are bit masks of any width
            p = problem.pair(i, j)
            if p is None:
                continue
            nu = np.asarray(p.innovation, dtype=float)
            S = blocks.cross(p, j, p, j) + p.R
            d2 = _nis(nu, S)
            if d2 < gate(len(nu)):
                row.append((d2, j, p))
        candidates.append(sorted(row, key=lambda t: t[0]))

    # Search the observations most certain first (smallest best NIS): every node must be jointly
    # compatible, so the order decides which of two conflicting observations stays out, and the
    # well-predicted ones should not be the ones dropped (a front-end's output order is arbitrary).
    order = sorted((i for i in range(n) if candidates[i]), key=lambda i: candidates[i][0][0])
    cand = [candidates[i] for i in order]
    masks = [sum(1 << j for _, j, _ in row) for row in cand]  # landmark sets as bit masks
    n_search = len(order)

    best_pairs: list = []
    best_nis = np.inf
    expanded = 0
    used = 0  # bit mask of the landmarks paired on the current path

    def cannot_beat(npairs: int, k: int) -> bool:
        return cannot_beat_best(masks, k, used, npairs, len(best_pairs))

    def search(node, k: int):
        nonlocal best_pairs, best_nis, expanded, used
        npairs = len(node.pairs)
        if k == n_search:
            if npairs > len(best_pairs) or (npairs == len(best_pairs) and npairs > 0 and node.nis < best_nis):
                best_pairs, best_nis = list(node.pairs), node.nis
            return
        # Bound: a branch that cannot reach more pairings than the best is not worth expanding.
        if expanded >= max_hypotheses or (best_pairs and cannot_beat(npairs, k)):
            return
        i = order[k]
        for _, j, p in cand[k]:
            if used >> j & 1:
                continue
            expanded += 1
            child = joint.extend(node, i, j, p)
            if child is None or child.nis >= gate(child.dof):
                continue
            used |= 1 << j
            search(child, k + 1)
            used &= ~(1 << j)
        # Star branch: observation i unpaired, worth it only if it can still beat the best.
        if not best_pairs or not cannot_beat(npairs, k + 1):
            search(node, k + 1)

    search(joint.root(), 0)
    result: list[int | None] = [None] * n
    for i, j, _ in best_pairs:
        result[i] = j
    return result
