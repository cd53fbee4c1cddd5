"""Re-observation of a known structure: the structure registered by ICP on one patch's points (from
its current estimate, independent data each time) and, if the registration passes its checks,
expressed in the current sonar frame as a ``StructureObservation``.

After a long gap (the track since the structure's last accepted view, times ``carry_sigma_per_m``,
the estimated motion's σ per metre, exceeds ``max_jump_m``, the reach the ICP from the prior is
allowed), the vehicle's pose relative to the structure is uncertain by more than that reach: an ICP
started from the prior placed by the drifted pose, allowed to move at most ``max_jump_m``, may settle
on a wrong-place fit next to the prior and so confirm the drift. Such a view is registered afresh
instead (the recognition's 4-D search around the prior, then ICP) and emitted only when that fit
passes a new structure's test (``new_min_fitness``, not ambiguous end for end, ``max_unexplained``):
the prior no longer places the structure better than a recognition's search does."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from frontends.sonar.config import StructureRegistrationConfig
from frontends.sonar.known import KnownStructure
from frontends.sonar.patches import Patch, inv, transform
from frontends.sonar.registration import ModelData, Registration, icp
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
        gap_m: float = 0.0,
        search: Callable[[np.ndarray, np.ndarray], Registration | None] | None = None,
    ) -> StructureObservation | None:
        """``ks`` (model data ``md``, current estimate ``T_WM``) registered on ``patch`` placed at
        ``T_WA``, in the frame of the sonar now (the vehicle at ``T_WB_now``, the sonar at ``T_BS`` on it); None when the patch sees too little of
        it or the registration fails the checks (points, fitness, median, jump, σ).

        ``gap_m``: track since the structure's last accepted view; when ``carry_sigma_per_m`` × it
        exceeds ``max_jump_m`` and ``search`` is given (points in {W} as placed, centre north/east →
        a registration that passed a new structure's test, or None), the view is the searched fit,
        checked for points, turn and σ, or nothing (reason ``gap``)."""
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
        if rc.gap_search and search is not None and rc.carry_sigma_per_m * gap_m > rc.max_jump_m:
            reg, why = self._searched(patch, ks, md, T_WA, T_AM0, reg, why, gap_m, search)
            if reg is None:
                return None
            d = inv(T_AM0) @ reg.T
            jump = np.linalg.norm(d[:3, 3])
            turn = abs(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))
            sig_t = np.sqrt(np.linalg.eigvalsh(reg.cov[3:, 3:]).max())
        if why is not None:
            self.rejected[f"structure_observation_{why}"] += 1
            self.log.append(
                (ks.model, patch.id, why, reg.n_structure, reg.fitness, reg.median_m, jump, np.degrees(turn), sig_t)
            )
            return None
        return self._emit(patch, ks, reg, T_WA, T_WB_now, T_BS, stamp, sensor)

    def _searched(
        self,
        patch: Patch,
        ks: KnownStructure,
        md: ModelData,
        T_WA: np.ndarray,
        T_AM0: np.ndarray,
        local: Registration,
        local_why: str | None,
        gap_m: float,
        search: Callable[[np.ndarray, np.ndarray], Registration | None],
    ) -> tuple[Registration | None, str | None]:
        """A view after a long gap: the structure registered afresh on the patch (``search``, around
        the prior's centre, on the points within the footprint + 2 m as the final fit's re-registration
        takes them), in the anchor's frame; (None, reason) when nothing passes. ``local`` (the ICP from
        the prior, failing today's checks for ``local_why``, or passing them for None) is only counted."""
        rc = self.config
        c = T_AM0[:3, 3]
        wide = np.hypot(patch.points[:, 0] - c[0], patch.points[:, 1] - c[1]) <= md.model.footprint_radius + 2.0
        t0 = time.process_time()
        found = search(transform(T_WA, patch.points[wide].astype(float)), (T_WA @ T_AM0)[:2, 3])
        self.timing["registration_s"] += time.process_time() - t0
        self.timing["reobservations_searched"] += 1
        if found is None:
            self.rejected["structure_observation_gap"] += 1
            if local_why is None:  # today's checks would have emitted the ICP from the prior
                self.rejected["structure_observation_gap_local_passed"] += 1
            self.log.append((ks.model, patch.id, "gap", gap_m, local_why, local.fitness, local.median_m))
            return None, "gap"
        reg = Registration(
            inv(T_WA) @ found.T,
            found.median_m,
            found.fitness,
            found.n_structure,
            found.cov,
            found.sigma,
            found.coverage,
            found.cost_4d,
            found.unexplained,
        )
        moved = float(np.linalg.norm(reg.T[:3, 3] - local.T[:3, 3]))
        self.log.append((ks.model, patch.id, "searched", gap_m, local_why, local.fitness, reg.fitness, moved))
        turn = abs(np.arccos(np.clip((np.trace((inv(T_AM0) @ reg.T)[:3, :3]) - 1) / 2, -1, 1)))
        sig_t = np.sqrt(np.linalg.eigvalsh(reg.cov[3:, 3:]).max())
        why = None
        if reg.n_structure < rc.min_points:
            why = "points"
        elif turn > np.radians(rc.max_turn_deg):
            why = "jump"
        elif sig_t > rc.max_sigma_m:
            why = "sigma"
        if why is None and local_why is None:
            # today's checks would have emitted the ICP from the prior: counted where it lay elsewhere
            self.timing["reobservations_searched_local_passed"] += 1
            if moved > rc.tukey_k_m:
                self.timing["reobservations_searched_moved"] += 1
        return reg, why

    def _emit(
        self,
        patch: Patch,
        ks: KnownStructure,
        reg: Registration,
        T_WA: np.ndarray,
        T_WB_now: np.ndarray,
        T_BS: np.ndarray,
        stamp: int,
        sensor: str,
    ) -> StructureObservation:
        rc = self.config
        T_SM = inv(T_WB_now @ T_BS) @ T_WA @ reg.T
        carry = rc.carry_sigma_per_m * float(np.linalg.norm(T_WB_now[:3, 3] - T_WA[:3, 3]))
        cov = reg.cov.copy()
        cov[3:, 3:] += np.eye(3) * carry**2
        ks.n_observations += 1
        ks.history.append((stamp, patch.id, T_SM, cov, float(reg.median_m)))
        return StructureObservation(stamp, sensor, model=ks.model, pose=T_SM, covariance=cov)
