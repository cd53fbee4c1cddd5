"""Re-observation of a known structure: the structure registered by ICP on one patch's points (from
its current estimate, independent data each time) and, if the registration passes its checks,
expressed in the current sonar frame as a ``StructureObservation``.

After a long gap (the track since the structure's last accepted view, times ``carry_sigma_per_m``,
the estimated motion's σ per metre, exceeds ``max_jump_m``, the reach the ICP from the prior is
allowed), the vehicle's pose relative to the structure is uncertain by more than that reach: an ICP
started from the prior placed by the drifted pose, allowed to move at most ``max_jump_m``, may settle
on a wrong-place fit next to the prior and so confirm the drift. Such a view is searched instead:
the coarse ICP (``icp_distances_m[0]``) from every north/east start, spaced by that distance (its
reach), within the recognition's search range (``shift_range_m``, ``shift_range_frac`` of the
footprint radius) around the prior, the prior's attitude kept; each distinct place it reaches (more
than ``tukey_k_m`` apart) refined by the view's own ICP, kept only where it ends within that range (beyond it
no start looked for a rival place); the best fit (fitness, then median) is the view,
with the usual checks but for the jump (its turn still at most ``max_turn_deg``), and every other fit
within ``ambiguity_margin`` of its fitness that lies elsewhere grows its translation covariance by
that offset (the search's ambiguity), so that two places that fit alike give no view
(``max_sigma_m``) and a view that slides along the structure says so."""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from frontends.sonar.config import StructureRegistrationConfig
from frontends.sonar.known import KnownStructure
from frontends.sonar.patches import Patch, inv
from frontends.sonar.registration import ModelData, Registration, icp
from semslam.observations import StructureObservation


def _turn(d: np.ndarray) -> float:
    return abs(float(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1))))


def _failed_check(reg: Registration, rc: StructureRegistrationConfig, jumped: bool) -> tuple[str | None, float]:
    """The first check ``reg`` fails (points, fitness, median, jump, σ; None: it passes) and its largest
    translation σ; ``jumped``: it moved or turned beyond what a view may."""
    sig_t = float(np.sqrt(np.linalg.eigvalsh(reg.cov[3:, 3:]).max()))
    checks = {
        "points": reg.n_structure < rc.min_points,
        "fitness": reg.fitness < rc.min_fitness,
        "median": reg.median_m > rc.max_median_m,
        "jump": jumped,
        "sigma": sig_t > rc.max_sigma_m,
    }
    return next((k for k, failed in checks.items() if failed), None), sig_t


class StructureReobservation:
    """Registers known structures on single patches.

    ``rejected`` is the front-end's counter of rejections by reason (shared with its other stages),
    ``timing`` its CPU-time counters (and counts: ``reobservations``, ``reobservations_searched`` …);
    ``log`` says why each re-observation was not emitted: (model, patch, reason, ...)."""

    def __init__(self, config: StructureRegistrationConfig, rejected: dict[str, int], timing: dict[str, float]):
        self.config = config
        self.rejected = rejected
        self.timing = timing
        self.log: list[tuple] = []

    def _fit(self, patch: Patch, md: ModelData, T_start: np.ndarray) -> tuple[Registration | None, str | None, tuple]:
        """The ICP of ``patch``'s points near the model placed at ``T_start`` (anchor frame), and the
        first check it fails (points, fitness, median, jump, σ; None: it passes), with what the log keeps."""
        rc = self.config
        c = T_start[:3, 3]
        near = np.hypot(patch.points[:, 0] - c[0], patch.points[:, 1] - c[1]) <= md.model.footprint_radius + 0.5
        if near.sum() < rc.min_points:
            return None, "few points near", (int(near.sum()),)
        t0 = time.process_time()
        reg = icp(md, patch.points[near].astype(float), T_start, rc, distances=rc.icp_distances_m[-1:])
        self.timing["registration_s"] += time.process_time() - t0
        self.timing["reobservations"] += 1
        d = inv(T_start) @ reg.T
        jump = np.linalg.norm(d[:3, 3])
        turn = _turn(d)
        why, sig_t = _failed_check(reg, rc, jumped=jump > rc.max_jump_m or turn > np.radians(rc.max_turn_deg))
        return reg, why, (reg.n_structure, reg.fitness, reg.median_m, jump, np.degrees(turn), sig_t)

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
    ) -> StructureObservation | None:
        """``ks`` (model data ``md``, current estimate ``T_WM``) registered on ``patch`` placed at
        ``T_WA``, in the frame of the sonar now (the vehicle at ``T_WB_now``, the sonar at ``T_BS`` on it); None when the patch sees too little of
        it or the registration fails the checks (points, fitness, median, jump, σ).

        ``gap_m``: track since the structure's last accepted view; when ``carry_sigma_per_m`` × it
        exceeds ``max_jump_m`` (and ``gap_search``), the view is searched (see the module)."""
        rc = self.config
        T_AM0 = inv(T_WA) @ T_WM
        reg, why, info = self._fit(patch, md, T_AM0)
        if reg is not None and rc.gap_search and rc.carry_sigma_per_m * gap_m > rc.max_jump_m:
            reg, why, info = self._searched(patch, ks, md, T_AM0, reg, why, gap_m)
        if why is not None:
            if reg is not None:
                self.rejected[f"structure_observation_{why}"] += 1
            self.log.append((ks.model, patch.id, why, *info))
            return None
        return self._emit(patch, ks, reg, T_WA, T_WB_now, T_BS, stamp, sensor)

    def _searched(
        self,
        patch: Patch,
        ks: KnownStructure,
        md: ModelData,
        T_AM0: np.ndarray,
        local: Registration,
        local_why: str | None,
        gap_m: float,
    ) -> tuple[Registration, str | None, tuple]:
        """A view after a long gap, searched (see the module). ``local`` (the ICP from the prior, failing
        today's checks for ``local_why``, passing them for None) is counted only:
        ``structure_observation_gap_local_passed`` where it would have been emitted and no view is,
        ``reobservations_searched_moved`` where the view lies more than ``tukey_k_m`` from it."""
        rc = self.config
        c = T_AM0[:3, 3]
        rng = max(rc.shift_range_m, rc.shift_range_frac * md.model.footprint_radius)
        step = rc.icp_distances_m[0]  # the coarse ICP's reach
        g = np.arange(-np.floor(rng / step), np.floor(rng / step) + 1) * step
        starts = [(a, b) for a in g for b in g if np.hypot(a, b) <= rng + 1e-9]
        near = np.hypot(patch.points[:, 0] - c[0], patch.points[:, 1] - c[1]) <= md.model.footprint_radius + 0.5 + rng
        pts = patch.points[near].astype(float)
        t0 = time.process_time()

        # coarse ICP from every start; the distinct places it reaches refined as the view's ICP is
        def usable(r: Registration) -> bool:  # enough of the structure, turned no more than a view may be
            return r.n_structure >= rc.min_points and _turn(inv(T_AM0) @ r.T) <= np.radians(rc.max_turn_deg)

        places: list[np.ndarray] = []
        for a, b in starts:
            T0 = T_AM0.copy()
            T0[0, 3] += a
            T0[1, 3] += b
            r = icp(md, pts, T0, rc, distances=rc.icp_distances_m[:1])
            if usable(r) and all(np.linalg.norm(r.T[:3, 3] - q[:3, 3]) > rc.tukey_k_m for q in places):
                places.append(r.T)
        fits = []
        for T1 in places:
            r = icp(md, pts, T1, rc, distances=rc.icp_distances_m[-1:])
            # a fit beyond the searched range lies where no start looked for a rival place: its uniqueness is unknown
            inside = np.hypot(*(r.T[:2, 3] - c[:2])) <= rng
            if inside and usable(r):
                fits.append(r)
        self.timing["registration_s"] += time.process_time() - t0
        self.timing["reobservations_searched"] += 1
        if not fits:
            if local_why is None:  # today's checks would have emitted the ICP from the prior
                self.rejected["structure_observation_gap_local_passed"] += 1
            return local, "gap", (gap_m, local_why, "no fit", len(starts))
        best = max(fits, key=lambda r: (r.fitness, -r.median_m))
        # the search's ambiguity: every other place that fits about as well
        d = [r.T[:3, 3] - best.T[:3, 3] for r in fits if r.fitness >= best.fitness - rc.ambiguity_margin]
        far = max(d, key=np.linalg.norm)
        cov = best.cov.copy()
        cov[3:, 3:] += np.outer(far, far)
        reg = dataclasses.replace(best, cov=cov, cost_4d=None)
        # the search moves the view on purpose (no jump check); usable() already asked for the points
        why, sig_t = _failed_check(reg, rc, jumped=False)
        moved = float(np.linalg.norm(reg.T[:3, 3] - local.T[:3, 3]))
        info = (gap_m, local_why, local.fitness, reg.fitness, reg.median_m, float(np.linalg.norm(far)), sig_t, moved)
        if why is not None:
            if local_why is None:
                self.rejected["structure_observation_gap_local_passed"] += 1
            return reg, "gap", (why, *info)
        if local_why is None:
            self.timing["reobservations_searched_local_passed"] += 1
            if moved > rc.tukey_k_m:
                self.timing["reobservations_searched_moved"] += 1
        self.log.append((ks.model, patch.id, "searched", *info))
        return reg, None, info

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
