"""The graph back-end's data-association problem for :func:`semslam.backend.association.jcbb`.

Vehicle block: the current keyframe pose X (6, tangent (ω, v)). Landmark blocks: point (3),
line θ (4), structure pose (6). Covariances are iSAM2 marginals of single variables: the
pose–landmark and landmark–landmark cross terms are taken as zero (computing them would need a
joint marginal over the candidates at every scan). Both correlations are positive in practice
(landmarks seen from the same poses), so dropping them overstates the innovation covariance:
the gates get a little looser, never tighter.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from factors.landmarks import line_observation_covariance, line_residual, point_residual, structure_residual
from semslam.backend.association import PairLinearization
from semslam.backend.landmarks import Landmark
from semslam.observations import LineObservation, PointObservation, StructureObservation


@dataclass
class Candidate:
    landmark: Landmark
    covariance: np.ndarray


class GraphAssociationProblem:
    """Observations of one batch against pre-gated candidate landmarks."""

    uncorrelated_landmarks = True  # single-variable marginals: JCBB may use its low-rank joint NIS

    def __init__(
        self,
        pose: gtsam.Pose3,
        pose_cov: np.ndarray,
        observations: list,
        T_BS: list[np.ndarray],
        candidates: list[Candidate],
        pipe_extent_gap_m: float,
        allowed: np.ndarray,
    ):
        self.pose = pose
        self.pose_cov = pose_cov
        self.observations = observations
        self.T_BS = T_BS
        self.candidates = candidates
        self.gap = pipe_extent_gap_m
        self.allowed = allowed  # (n_obs, n_cand) bool: the Euclidean pre-gate
        self.n_observations = len(observations)
        self.n_landmarks = len(candidates)
        self._cache: dict[tuple[int, int], PairLinearization | None] = {}

    def pair(self, i: int, j: int) -> PairLinearization | None:
        key = (i, j)
        if key not in self._cache:
            self._cache[key] = self._pair(i, j) if self.allowed[i, j] else None
        return self._cache[key]

    def _pair(self, i: int, j: int) -> PairLinearization | None:
        z, lm, T_BS = self.observations[i], self.candidates[j].landmark, self.T_BS[i]
        if isinstance(z, PointObservation) and lm.kind == "object":
            r, H_x, H_l = point_residual(self.pose, lm.estimate, T_BS, z.position, jac=True)
            return PairLinearization(-r, H_x, H_l, z.covariance)
        if isinstance(z, LineObservation) and lm.kind == "pipe":
            theta = lm.estimate
            # The segment must overlap what has been seen of the pipe (collinear pipes on either
            # side of a valve share one infinite line).
            T_WS = self.pose.compose(gtsam.Pose3(T_BS))
            s = lm.anchor.to_line_frame(theta, np.vstack([T_WS.transformFrom(z.p), T_WS.transformFrom(z.q)]))[:, 2]
            lo, hi = lm.extent
            if s.max() < lo - self.gap or s.min() > hi + self.gap:
                return None
            r, H_x, H_l = line_residual(self.pose, theta, lm.anchor, T_BS, z.p, z.q, jac=True)
            R = line_observation_covariance(self.pose, theta, lm.anchor, T_BS, z.covariance)
            return PairLinearization(-r, H_x, H_l, R)
        if isinstance(z, StructureObservation) and lm.kind == "structure" and z.model == lm.model:
            r, H_x, H_l = structure_residual(self.pose, lm.estimate, T_BS, z.pose, jac=True)
            return PairLinearization(-r, H_x, H_l, z.covariance)
        return None

    def covariance(self, a: int | None, b: int | None) -> np.ndarray:
        if a is None and b is None:
            return self.pose_cov
        if a is None or b is None:
            n = self.candidates[b if a is None else a].covariance.shape[0]
            return np.zeros((6, n)) if a is None else np.zeros((n, 6))
        if a == b:
            return self.candidates[a].covariance
        return np.zeros((self.candidates[a].covariance.shape[0], self.candidates[b].covariance.shape[0]))
