"""Window registration: a window of new patches registered on the older overlapping patches of the
neighbouring line (:mod:`.swath_registration`), giving the relative pose of the two anchors as an
``OdometryObservation``. Holds what the registrations tried and accepted, for the metrics and for
diagnosis."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from frontends.sonar.config import SwathRegistrationConfig
from frontends.sonar.grid import ElevationMap, GridSpec
from frontends.sonar.patches import Patch, inv, overlap_area, yaw_of
from frontends.sonar.swath_registration import register
from semslam.observations import OdometryObservation

#: patches of the reference group may differ from the best reference patch's heading by this much
SAME_LINE_YAW_RAD = np.radians(20)


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


class WindowRegistration:
    """Registers windows of patches on the older patches of the neighbouring line.

    ``rejected`` is the front-end's counter of rejections by reason (shared with its other stages);
    ``accepted`` lists every accepted registration (shift, covariance, the anchors' poses as placed);
    ``log`` every one tried: (window anchor patch, reference patch, outcome)."""

    def __init__(self, config: SwathRegistrationConfig, max_turn_rad: float, rejected: dict[str, int]):
        self.config = config
        self.max_turn_rad = max_turn_rad
        self.rejected = rejected
        self.accepted: list[dict] = []
        self.log: list[tuple[int, int, str]] = []
        self._rng = np.random.default_rng(config.seed)

    def register(
        self,
        window: list[Patch],
        pts_W: np.ndarray,
        patches: list[Patch],
        place: Callable[[Patch], np.ndarray],
        sensor: str,
    ) -> list[OdometryObservation]:
        """The window (its points ``pts_W`` in {W}) against the older ``patches``, each placed by
        ``place`` (the current estimate of its anchor): one observation between the reference patch's
        anchor and the window's middle anchor, or none."""
        cfg = self.config
        if any(p.heading_change > self.max_turn_rad for p in window):
            self.rejected["swath_turn"] += 1
            return []
        j = window[len(window) // 2]
        lo, hi = pts_W[:, :2].min(0), pts_W[:, :2].max(0)
        best, best_a = None, 0.0
        for p in patches:
            if (j.anchor_stamp - p.anchor_stamp) * 1e-9 < cfg.min_age_s:
                break  # patches are in time order
            if p.heading_change > self.max_turn_rad:
                continue
            a = overlap_area(p.lo, p.hi, lo, hi)
            if a > best_a:
                best, best_a = p, a
        if best is None:
            self.rejected["swath_no_reference"] += 1
            return []
        yaw_ref = yaw_of(best.T_nav)
        group = [
            q
            for q in patches[max(best.id - 3, 0) : best.id + 4]
            if q.heading_change <= self.max_turn_rad
            and abs(_wrap(yaw_of(q.T_nav) - yaw_ref)) < SAME_LINE_YAW_RAD
            and (j.anchor_stamp - q.anchor_stamp) * 1e-9 >= cfg.min_age_s
        ]
        ref_pts = np.concatenate([q.world(place(q)) for q in group])
        spec = GridSpec.around(lo, hi, cfg.cell_m, pad=cfg.max_shift_m + 0.2)
        ref = ElevationMap.from_points(ref_pts, spec=spec).fill_small_holes()
        why: dict = {}
        res = register(pts_W, ref, cfg, self._rng, why)
        if res is None:
            for k in why:
                self.rejected[f"swath_{k}"] += 1
            self.log.append((j.id, best.id, ",".join(why)))
            return []
        self.log.append((j.id, best.id, "ok"))
        T_i = place(best)
        T_j = place(j)
        T_j2 = T_j.copy()
        T_j2[:3, 3] += np.array([res.shift[0], res.shift[1], res.depth])
        rel = inv(T_i) @ T_j2
        R_j = T_j[:3, :3]
        cov = np.zeros((6, 6))
        cov[:3, :3] = np.eye(3) * cfg.rotation_sigma_rad**2
        cov[3:, 3:] = R_j.T @ res.cov @ R_j
        self.accepted.append(
            {
                "stamp_from": best.anchor_stamp,
                "stamp": j.anchor_stamp,
                "patch_from": best.id,
                "patch": j.id,
                "shift": res.shift.tolist(),
                "raw_shift": res.raw_shift.tolist(),
                "depth": res.depth,
                "cov_W": res.cov.tolist(),
                "sigma": res.sigma,
                "informative": res.informative,
                "n_points": res.n_points,
                "cost_before": res.cost_before,
                "cost_after": res.cost_after,
                "relative_pose": rel.tolist(),
                "covariance": cov.tolist(),
                "T_from": T_i.tolist(),
                "T_to": T_j.tolist(),
            }
        )
        return [
            OdometryObservation(j.anchor_stamp, sensor, stamp_from=best.anchor_stamp, relative_pose=rel, covariance=cov)
        ]
