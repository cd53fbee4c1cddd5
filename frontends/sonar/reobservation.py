"""Re-observation of a known structure: the structure registered by ICP on one patch's points (from
its current estimate, independent data each time) and, if the registration passes its checks,
expressed in the current sonar frame as a ``StructureObservation``."""

from __future__ import annotations

import time

import numpy as np

from frontends.sonar.config import StructureRegistrationConfig
from frontends.sonar.known import KnownStructure
from frontends.sonar.patches import Patch, inv
from frontends.sonar.registration import ModelData, icp
from semslam.observations import StructureObservation


class StructureReobservation:
    """Registers known structures on single patches.

    ``rejected`` is the front-end's counter of rejections by reason (shared with its other stages),
    ``timing`` its CPU-time counters; ``log`` says why each re-observation was not emitted:
    (model, patch, reason, ...)."""

    def __init__(self, config: StructureRegistrationConfig, rejected: dict[str, int], timing: dict[str, float]):
        self.config = config
        self.rejected = rejected
        self.timing = timing
        self.log: list[tuple] = []

    def observe(
        self,
        patch: Patch,
        ks: KnownStructure,
        md: ModelData,
        T_WA: np.ndarray,
        T_WM: np.ndarray,
        T_WB_now: np.ndarray,
        T_BS: np.ndarray,
        stamp: int,
        sensor: str,
    ) -> StructureObservation | None:
        """``ks`` (model data ``md``, current estimate ``T_WM``) registered on ``patch`` placed at
        ``T_WA``, in the frame of the sonar now (the vehicle at ``T_WB_now``, the sonar at ``T_BS`` on it); None when the patch sees too little of
        it or the registration fails the checks (points, fitness, median, jump, σ)."""
        rc = self.config
        R = md.model.footprint_radius + 0.5
        T_AM0 = inv(T_WA) @ T_WM
        c = T_AM0[:3, 3]
        near = np.hypot(patch.points[:, 0] - c[0], patch.points[:, 1] - c[1]) <= R
        if near.sum() < rc.min_points:
            self.log.append((ks.model, patch.id, "few points near", int(near.sum())))
            return None
        t0 = time.process_time()
        reg = icp(md, patch.points[near].astype(float), T_AM0, rc, distances=rc.icp_distances_m[-1:])
        self.timing["registration_s"] += time.process_time() - t0
        self.timing["reobservations"] += 1
        d = inv(T_AM0) @ reg.T
        jump = np.linalg.norm(d[:3, 3])
        turn = abs(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))
        sig_t = np.sqrt(np.linalg.eigvalsh(reg.cov[3:, 3:]).max())
        checks = {
            "points": reg.n_structure < rc.min_points,
            "fitness": reg.fitness < rc.min_fitness,
            "median": reg.median_m > rc.max_median_m,
            "jump": jump > rc.max_jump_m or turn > np.radians(rc.max_turn_deg),
            "sigma": sig_t > rc.max_sigma_m,
        }
        why = next((k for k, failed in checks.items() if failed), None)
        if why is not None:
            self.rejected[f"structure_observation_{why}"] += 1
            self.log.append(
                (ks.model, patch.id, why, reg.n_structure, reg.fitness, reg.median_m, jump, np.degrees(turn), sig_t)
            )
            return None
        T_SM = inv(T_WB_now @ T_BS) @ T_WA @ reg.T
        carry = rc.carry_sigma_per_m * float(np.linalg.norm(T_WB_now[:3, 3] - T_WA[:3, 3]))
        cov = reg.cov.copy()
        cov[3:, 3:] += np.eye(3) * carry**2
        ks.n_observations += 1
        ks.history.append((stamp, patch.id, T_SM, cov, float(reg.median_m)))
        return StructureObservation(stamp, sensor, model=ks.model, pose=T_SM, covariance=cov)
