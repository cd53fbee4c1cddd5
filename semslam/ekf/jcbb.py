"""Joint Compatibility Branch and Bound (Neira & Tardós 2001) on a dense joint innovation covariance.

The same search, node for node, as :func:`semslam.backend.association.jcbb` (with ``by_nis``, in
the order that one uses: observations most certain first, by increasing best individual NIS;
without it, in the given order): candidates by increasing individual NIS, individual compatibility
χ²(d) first, joint compatibility χ²(Σd) of every hypothesis on the path, one-to-one, the most pairings win (a branch that cannot
reach more pairings than the best found is cut, so among equally many pairings the first found
wins). It is for a caller that can give the covariance of *all* candidate pairs at once: the filter
computes S = J P Jᵀ + R for every candidate pair in one product, so a node of the search is a
Schur-complement step on slices of that matrix, with no per-pair callbacks; and a child's joint NIS
is computed before its inverse covariance is built (rejected children never build it).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import chi2

from semslam.backend.association import cannot_beat_best
from semslam.ekf.filter import inv_small


class Chi2Gate:
    """χ² quantiles by degrees of freedom, computed once each per confidence (scipy's ppf is slow)."""

    _tables: dict[float, list[float]] = {}

    def __init__(self, confidence: float):
        self.confidence = float(confidence)
        self._t = self._tables.setdefault(self.confidence, [])

    def __call__(self, dof: int) -> float:
        t = self._t
        if dof >= len(t):
            t.extend(float(chi2.ppf(self.confidence, k)) for k in range(len(t), max(dof + 1, 2 * len(t), 64)))
        return t[dof]


class _Node:
    __slots__ = ("pairs", "rows", "w", "S_inv", "nis", "dof")

    def __init__(self, pairs, rows, w, S_inv, nis, dof):
        self.pairs = pairs  # [(obs, landmark, pair index)]
        self.rows = rows  # row indices of the stacked innovation in S_all
        self.w = w  # S_H⁻¹ ν_H
        self.S_inv = S_inv
        self.nis = nis
        self.dof = dof


def jcbb_dense(
    n_obs: int,
    pair_obs: np.ndarray,
    pair_lm: np.ndarray,
    pair_rows: list[np.ndarray],
    nu: np.ndarray,
    S_all: np.ndarray,
    confidence: float = 0.99,
    max_hypotheses: int = 20_000,
    individual_nis: np.ndarray | None = None,
    stats: dict | None = None,
    seed_after: int = 300,
    by_nis: bool = False,
) -> list[int | None]:
    """JCBB over candidate pairs k = (pair_obs[k], pair_lm[k]) whose innovations are ν[pair_rows[k]]
    with joint covariance S_all (every pair's rows, R on each pair's own diagonal block).

    Returns, for each of the ``n_obs`` observations, the landmark it pairs with, or None.
    ``individual_nis`` (one per pair) saves recomputing the individual NIS when the caller has it.
    ``stats``, when given, receives the number of nodes expanded (``"nodes"``), whether the search
    was cut by ``max_hypotheses`` (``"capped"``) and whether it was seeded (``"seeded"``).

    ``by_nis``: search the observations in order of increasing individual NIS (best candidate), not in
    the given order. Every node of the search must be jointly compatible (Neira & Tardós test each
    hypothesis as it grows), so the order decides which of two conflicting observations stays out:
    most certain first keeps the well-predicted ones and leaves the doubtful ones for the end of the
    branch, where dropping them is cheap (a front-end's output order is arbitrary).

    A search that has not finished after ``seed_after`` nodes is started again with a greedy jointly
    compatible hypothesis as the best so far (see below). It still returns a hypothesis with the
    most pairings, but among equally many ones not necessarily the one the plain search finds first.
    """
    result: list[int | None] = [None] * n_obs
    K = len(pair_obs)
    if n_obs == 0 or K == 0:
        return result
    gate = Chi2Gate(confidence)
    if individual_nis is None:
        individual_nis = np.array([float(nu[r] @ np.linalg.solve(S_all[np.ix_(r, r)], nu[r])) for r in pair_rows])
    # Individual compatibility; candidates of each observation by increasing NIS.
    cands: list[list[tuple[float, int, int]]] = [[] for _ in range(n_obs)]
    for k in range(K):
        d2 = float(individual_nis[k])
        if d2 < gate(len(pair_rows[k])):
            cands[int(pair_obs[k])].append((d2, int(pair_lm[k]), k))
    for c in cands:
        c.sort(key=lambda t: t[0])
    # Only observations with a candidate take part (the others are never paired).
    order = [i for i in range(n_obs) if cands[i]]
    if by_nis:
        order.sort(key=lambda i: cands[i][0][0])
    if not order:
        return result
    C = [cands[i] for i in order]
    m = len(order)
    masks = [sum(1 << j for _, j, _ in c) for c in C]
    blocks = [S_all[np.ix_(r, r)] for r in pair_rows]

    best_pairs: list = []
    best_nis = math.inf
    expanded = 0
    limit = min(max_hypotheses, seed_after)
    used = 0  # bit mask of the landmarks used on the current path

    def cannot_beat(npairs: int, i: int) -> bool:
        """No extension of a node with ``npairs`` pairs at observation i beats the best found."""
        return cannot_beat_best(masks, i, used, npairs, len(best_pairs))

    def child_nis(node: _Node, k: int):
        """(nis, pieces) of the node extended with pair k, without building its inverse."""
        r = pair_rows[k]
        nu_k = nu[r]
        Ck = blocks[k]
        if not node.pairs:
            Si = inv_small(Ck)
            return float(nu_k @ Si @ nu_k), (None, Si, nu_k)
        B = S_all[np.ix_(node.rows, r)]  # (D, d)
        KB = node.S_inv @ B
        schur = Ck - B.T @ KB
        try:
            Si = inv_small(schur)
        except np.linalg.LinAlgError:
            return math.inf, None
        res = nu_k - B.T @ node.w
        return node.nis + float(res @ Si @ res), (KB, Si, res)

    def build(node: _Node, i: int, j: int, k: int, nis: float, pieces) -> _Node:
        KB, Si, res = pieces
        r = pair_rows[k]
        if KB is None:
            return _Node([(i, j, k)], np.asarray(r), Si @ res, Si, nis, len(r))
        D, d = len(node.rows), len(r)
        S_inv = np.empty((D + d, D + d))
        KS = KB @ Si
        S_inv[:D, :D] = node.S_inv + KS @ KB.T
        S_inv[:D, D:] = -KS
        S_inv[D:, :D] = -KS.T
        S_inv[D:, D:] = Si
        Sr = Si @ res
        w = np.concatenate([node.w - KB @ Sr, Sr])
        return _Node(node.pairs + [(i, j, k)], np.concatenate([node.rows, r]), w, S_inv, nis, node.dof + d)

    def search(node: _Node, i: int) -> None:
        nonlocal best_pairs, best_nis, expanded, used
        npairs = len(node.pairs)
        if i == m:
            if npairs > len(best_pairs) or (npairs == len(best_pairs) and npairs > 0 and node.nis < best_nis):
                best_pairs, best_nis = list(node.pairs), node.nis
            return
        if expanded >= limit:
            return
        if best_pairs and cannot_beat(npairs, i):
            return
        for _, j, k in C[i]:
            if used >> j & 1:
                continue
            expanded += 1
            nis, pieces = child_nis(node, k)
            if not nis < gate(node.dof + len(pair_rows[k])):
                continue
            child = build(node, order[i], j, k, nis, pieces)
            used |= 1 << j
            search(child, i + 1)
            used &= ~(1 << j)
        # Star branch: observation i unpaired, worth it only if it can still beat the best.
        if not cannot_beat(npairs, i + 1):
            search(node, i + 1)

    def seed() -> tuple[list, float]:
        """A jointly compatible hypothesis built greedily (pairs by increasing individual NIS), then
        kept prefix-compatible in observation order (a leaf the search itself could reach)."""
        node = root
        taken_obs: set[int] = set()
        taken_lm: set[int] = set()
        chosen = []
        for _, li, j, k in sorted((d2, li, j, k) for li, c in enumerate(C) for d2, j, k in c):
            if li in taken_obs or j in taken_lm:
                continue
            nis, pieces = child_nis(node, k)
            if nis < gate(node.dof + len(pair_rows[k])):
                node = build(node, order[li], j, k, nis, pieces)
                taken_obs.add(li)
                taken_lm.add(j)
                chosen.append((li, j, k))
        node = root
        for li, j, k in sorted(chosen):
            nis, pieces = child_nis(node, k)
            if nis < gate(node.dof + len(pair_rows[k])):
                node = build(node, order[li], j, k, nis, pieces)
        return node.pairs, node.nis

    root = _Node([], np.zeros(0, int), np.zeros(0), np.zeros((0, 0)), 0.0, 0)
    search(root, 0)
    seeded = False
    if expanded >= limit and limit < max_hypotheses:
        # A hard search (a pairing early in the order that only later observations contradict):
        # start again from a greedy hypothesis as the best, so that every branch that cannot beat
        # it is cut from the start.
        seeded = True
        pairs, nis = seed()
        if len(pairs) > len(best_pairs):
            best_pairs, best_nis = list(pairs), nis
        limit = max_hypotheses
        search(root, 0)
    if stats is not None:
        stats["nodes"] = expanded
        stats["capped"] = expanded >= max_hypotheses
        stats["seeded"] = seeded
    for i, j, _ in best_pairs:
        result[i] = j
    return result
