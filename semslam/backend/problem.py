"""The graph back-end's data-association problem: the pairs it offers :func:`semslam.mapping.association.jcbb`.

Vehicle block: the current keyframe pose X (6, tangent (ω, v)). Landmark blocks: point (3),
line θ (4), structure pose (6). A landmark's covariance is its own (its views' information, see
:mod:`semslam.backend.landmarks`): the pose–landmark and landmark–landmark cross terms are taken as
zero. Both correlations are positive in practice (landmarks seen from the same poses), so dropping
them overstates the innovation covariance: the gates get a little looser, never tighter.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gtsam
import numpy as np

from factors.geometry import skew_batch
from factors.landmarks import (
    line_frame,
    line_observation_covariance,
    line_residual_at,
    point_residual_at,
    structure_residual,
)
from semslam.mapping.association import PairLinearization
from semslam.mapping.builder import Scan
from semslam.observations import LineObservation, PointObservation, StructureObservation


@dataclass
class Candidate:
    landmark: Any  # a semslam.backend.landmarks.Landmark (its kind, key, estimate, anchor, model)
    covariance: np.ndarray


class GraphAssociationProblem:
    """Observations of one batch against pre-gated candidate landmarks (``allowed``: the pairs the
    pre-gates keep); ``scan``: the batch's rules (:meth:`excluded_all`: a pipe pair is ruled out where
    ``scan.excludes``)."""

    def __init__(
        self,
        pose: gtsam.Pose3,
        observations: list,
        T_BS: list[np.ndarray],
        candidates: list[Candidate],
        allowed: np.ndarray,
        scan: Scan,
    ):
        self.pose = pose
        self.observations = observations
        self.T_BS = T_BS
        self.candidates = candidates
        self.allowed = allowed
        self.scan = scan
        self._cache: dict[tuple[int, int], PairLinearization | None] = {}
        self._R, self._t = pose.rotation().matrix(), pose.translation()
        self._frames: dict[int, tuple] = {}
        self._segments: dict[int, tuple] = {}

    def _line_frame(self, j: int):
        """R_L, J_r columns and direction of pipe candidate j (once per problem)."""
        if j not in self._frames:
            lm = self.candidates[j].landmark
            RL, Jr2 = line_frame(lm.anchor, lm.estimate)
            self._frames[j] = (RL, Jr2, RL[:, 2])
        return self._frames[j]

    def _segment(self, i: int):
        """Endpoints of line observation i in {B} (2×3) and in {W} (once per problem)."""
        if i not in self._segments:
            z, T_BS = self.observations[i], self.T_BS[i]
            e_B = np.stack([T_BS[:3, :3] @ z.p + T_BS[:3, 3], T_BS[:3, :3] @ z.q + T_BS[:3, 3]])
            self._segments[i] = (e_B, self._t + e_B @ self._R.T)
        return self._segments[i]

    def pair(self, i: int, j: int) -> PairLinearization | None:
        key = (i, j)
        if key not in self._cache:
            self._cache[key] = self._pair(i, j) if self.allowed[i, j] else None
        return self._cache[key]

    def pairs(self) -> list[tuple[int, int, PairLinearization | None]]:
        """Every allowed pair (i, j, its linearisation or None), observation by observation and the
        candidates in order: what :meth:`pair` gives, the object and pipe pairs linearised all at once
        (stacked products: the same formulas, numbers equal to rounding)."""
        ii, jj = np.nonzero(self.allowed)  # row-major: observation by observation, candidates in order
        out: list = [None] * len(ii)
        points, lines = [], []
        for n, (i, j) in enumerate(zip(ii.tolist(), jj.tolist())):
            z, kind = self.observations[i], self.candidates[j].landmark.kind
            if kind == "object" and isinstance(z, PointObservation):
                points.append((n, i, j))
            elif kind == "pipe" and isinstance(z, LineObservation):
                lines.append((n, i, j))
            else:
                out[n] = (i, j, self.pair(i, j))
        for rows, linearise in ((points, self._point_pairs), (lines, self._line_pairs)):
            if rows:
                for (n, i, j), lin in zip(rows, linearise([i for _, i, _ in rows], [j for _, _, j in rows])):
                    self._cache[(i, j)] = lin
                    out[n] = (i, j, lin)
        return out

    def _point_pairs(self, obs: list[int], cands: list[int]) -> list[PairLinearization]:
        """:func:`point_residual_at` of the object pairs (observation obs[k], candidate cands[k]), stacked."""
        R, t = self._R, self._t
        T = np.array([self.T_BS[i] for i in obs], float)
        R_SB = T[:, :3, :3].transpose(0, 2, 1)
        L = np.array([np.asarray(self.candidates[j].landmark.estimate, float) for j in cands])
        l_B = (L - t) @ R  # R_WBᵀ (l − t), row by row
        r = (R_SB @ (l_B - T[:, :3, 3])[:, :, None])[:, :, 0] - np.array([self.observations[i].position for i in obs])
        H_x = np.empty((len(obs), 3, 6))
        H_x[:, :, :3] = R_SB @ skew_batch(l_B)
        H_x[:, :, 3:] = -R_SB
        H_l = R_SB @ R.T
        return [PairLinearization(-r[k], H_x[k], H_l[k], self.observations[i].covariance) for k, i in enumerate(obs)]

    def _line_pairs(self, obs: list[int], cands: list[int]) -> list[PairLinearization]:
        """:func:`line_residual_at` and :func:`line_observation_covariance` of the pipe pairs, stacked."""
        K = len(obs)
        frames = [self._line_frame(j) for j in cands]
        segments = [self._segment(i) for i in obs]
        RL = np.array([f[0] for f in frames])
        Jr2 = np.array([f[1] for f in frames])
        lms = [self.candidates[j].landmark for j in cands]
        c0 = np.array([lm.anchor.c0 for lm in lms], float)
        ab = np.array([np.asarray(lm.estimate, float)[2:4] for lm in lms])
        e_B = np.array([s[0] for s in segments])  # (K, 2, 3)
        e_W = np.array([s[1] for s in segments])
        e_L = (e_W - c0[:, None, :]) @ RL  # rows: R_Lᵀ (e_W − c0)
        r = (e_L[:, :, :2] - ab[:, None, :]).reshape(K, 4)
        A = RL.transpose(0, 2, 1) @ self._R
        H_x = np.zeros((K, 4, 6))
        H_l = np.zeros((K, 4, 4))
        for e in range(2):
            H_x[:, 2 * e : 2 * e + 2, :3] = -(A @ skew_batch(e_B[:, e]))[:, :2]
            H_x[:, 2 * e : 2 * e + 2, 3:] = A[:, :2]
            H_l[:, 2 * e : 2 * e + 2, :2] = (skew_batch(e_L[:, e]) @ Jr2)[:, :2]
            H_l[:, 2 * e : 2 * e + 2, 2:] = -np.eye(2)
        M = (A @ np.array([self.T_BS[i][:3, :3] for i in obs], float))[:, :2]  # R_Lᵀ R_WB R_BS, x and y rows
        J = np.zeros((K, 4, 6))
        J[:, :2, :3] = M
        J[:, 2:, 3:] = M
        cov = J @ np.array([self.observations[i].covariance for i in obs], float) @ J.transpose(0, 2, 1)
        return [PairLinearization(-r[k], H_x[k], H_l[k], cov[k]) for k in range(K)]

    def _pair(self, i: int, j: int) -> PairLinearization | None:
        z, lm, T_BS = self.observations[i], self.candidates[j].landmark, self.T_BS[i]
        if isinstance(z, PointObservation) and lm.kind == "object":
            r, H_x, H_l = point_residual_at(self._R, self._t, lm.estimate, T_BS, z.position, jac=True)
            return PairLinearization(-r, H_x, H_l, z.covariance)
        if isinstance(z, LineObservation) and lm.kind == "pipe":
            theta = lm.estimate
            RL, Jr2, _ = self._line_frame(j)
            e_B, _ = self._segment(i)
            r, H_x, H_l = line_residual_at(self._R, self._t, RL, Jr2, lm.anchor.c0, theta[2:4], e_B, jac=True)
            R = line_observation_covariance(self.pose, theta, lm.anchor, T_BS, z.covariance, RL=RL)
            return PairLinearization(-r, H_x, H_l, R)
        if isinstance(z, StructureObservation) and lm.kind == "structure" and z.model == lm.model:
            r, H_x, H_l = structure_residual(self.pose, lm.estimate, T_BS, z.pose, jac=True)
            return PairLinearization(-r, H_x, H_l, z.covariance)
        return None

    def excluded_all(self, obs: np.ndarray, cands: np.ndarray) -> np.ndarray:
        """Whether the rules of the scan rule out each pair (obs[k], cands[k]): a pipe segment must overlap what
        has been seen of the pipe (collinear pipes on either side of a valve share one infinite line), and no
        in-line part (valve, socket) may lie between them: that is the next pipe. Asked only of the pairs that
        pass the χ² gate; all pairs at once (:meth:`Scan.excludes_all`)."""
        pipe_pairs = [
            k
            for k, (i, j) in enumerate(zip(obs.tolist(), cands.tolist()))
            if isinstance(self.observations[i], LineObservation) and self.candidates[j].landmark.kind == "pipe"
        ]
        out = np.zeros(len(obs), bool)
        if pipe_pairs:
            lms = [self.candidates[int(cands[k])].landmark for k in pipe_pairs]
            out[pipe_pairs] = self.scan.excludes_all(
                [lm.id for lm in lms],
                np.array([self._segment(int(obs[k]))[1] for k in pipe_pairs]),
                np.array([lm.line()[0] for lm in lms]),
                np.array([self._line_frame(int(cands[k]))[2] for k in pipe_pairs]),
            )
        return out

    def landmark_covariance(self, j: int) -> np.ndarray:
        """Candidate j's gating covariance (uncorrelated with the pose and the other candidates)."""
        return self.candidates[j].covariance


def possible_pairs(
    pose: gtsam.Pose3,
    pose_cov: np.ndarray,
    observations: list,
    T_BS: list[np.ndarray],
    candidates: list[Candidate],
    gate: dict[int, float],
) -> np.ndarray:
    """(n_obs, n_cand) mask of the pairs that *could* pass the individual χ² gate, for all pairs
    at once in numpy, so that the exact gate (one linearisation each) only runs on these.

    A necessary condition: d² = νᵀS⁻¹ν ≥ |ν|² / λ_max(S) ≥ |ν|² / tr(S), with tr(S) bounded
    above by sums of traces — for a block [A | B] of a Jacobian over a covariance with blocks
    (C_a, C_b), tr(J C Jᵀ) ≤ (‖A‖₂ √tr C_a + ‖B‖₂ √tr C_b)² (Cauchy–Schwarz on the cross term).
    The pose block's rotation lever arm is the point's distance to the body origin; a line's
    angular lever arm is the endpoint's distance to the line's anchor c0 (‖J_r‖₂ ≤ 1). Only
    conservative: a pair it keeps may still fail the exact gate. ``gate``: dof → χ² quantile.
    """
    n, m = len(observations), len(candidates)
    allowed = np.zeros((n, m), bool)
    if n == 0 or m == 0:
        return allowed
    R, t = pose.rotation().matrix(), pose.translation()
    s_rot = float(np.sqrt(max(np.trace(pose_cov[:3, :3]), 0.0)))
    s_tr = float(np.sqrt(max(np.trace(pose_cov[3:, 3:]), 0.0)))
    kinds = np.array([c.landmark.kind for c in candidates])

    def body(i, x_S):
        return T_BS[i][:3, :3] @ x_S + T_BS[i][:3, 3]

    # Objects: ν is the world distance of the observed point to the landmark (rotations keep norms).
    oi = [i for i, z in enumerate(observations) if isinstance(z, PointObservation)]
    oj = np.flatnonzero(kinds == "object")
    if oi and len(oj):
        e_B = np.array([body(i, observations[i].position) for i in oi])
        w = t + e_B @ R.T
        tr_obs = np.array([np.trace(observations[i].covariance) for i in oi])
        pose_term = (np.linalg.norm(e_B, axis=1) * s_rot + s_tr) ** 2
        L = np.array([np.asarray(candidates[j].landmark.estimate, float) for j in oj])
        tr_lm = np.array([np.trace(candidates[j].covariance) for j in oj])
        nu2 = ((w[:, None, :] - L[None, :, :]) ** 2).sum(axis=2)
        bound = (pose_term + tr_obs)[:, None] + tr_lm[None, :]
        allowed[np.ix_(oi, oj)] = nu2 <= gate[3] * bound

    # Pipes: ν stacks the perpendicular offsets of both observed endpoints from the line.
    li = [i for i, z in enumerate(observations) if isinstance(z, LineObservation)]
    lj = np.flatnonzero(kinds == "pipe")
    if li and len(lj):
        e_B = np.array([[body(i, observations[i].p), body(i, observations[i].q)] for i in li])  # (a, 2, 3)
        e_W = t + e_B @ R.T
        tr_obs = np.array([np.trace(observations[i].covariance) for i in li])
        pose_term = ((np.linalg.norm(e_B, axis=2) * s_rot + s_tr) ** 2).sum(axis=1)
        lms = [candidates[j].landmark for j in lj]
        c = np.array([lm.anchor.point(lm.estimate) for lm in lms])  # (b, 3)
        d = np.array([lm.anchor.direction(lm.estimate) for lm in lms])
        c0 = np.array([lm.anchor.c0 for lm in lms])
        C = [candidates[j].covariance for j in lj]
        s_ang = np.sqrt(np.maximum([Cj[0, 0] + Cj[1, 1] for Cj in C], 0.0))
        s_ab = np.sqrt(np.maximum([Cj[2, 2] + Cj[3, 3] for Cj in C], 0.0))
        r = e_W[:, None, :, :] - c[None, :, None, :]  # (a, b, 2, 3)
        along = (r * d[None, :, None, :]).sum(axis=3, keepdims=True)
        nu2 = ((r - along * d[None, :, None, :]) ** 2).sum(axis=(2, 3))
        arm = np.linalg.norm(e_W[:, None, :, :] - c0[None, :, None, :], axis=3)  # (a, b, 2)
        lm_term = ((arm * s_ang[None, :, None] + s_ab[None, :, None]) ** 2).sum(axis=2)
        bound = (pose_term + tr_obs)[:, None] + lm_term
        allowed[np.ix_(li, lj)] = nu2 <= gate[4] * bound

    # Structures: few; the exact gate decides (same model only).
    for i, z in enumerate(observations):
        if isinstance(z, StructureObservation):
            allowed[i] = [c.landmark.kind == "structure" and c.landmark.model == z.model for c in candidates]
    return allowed
