"""The sonar front-end: multibeam swaths in; relative-pose constraints (swath registration), CAD
structures (6-DoF) and pipelines out; at the end a world model, figures and the sonar metrics.

Online, as the swaths arrive (each placed with the graph's current estimate through the view):

* every ``patches.length_m`` of track the pending swaths become a :class:`Patch`, rigid in the frame
  of its middle swath (its anchor);
* every ``swath_registration.window_patches`` patches, the window they form is registered on the
  older overlapping patches of the neighbouring line (:mod:`.swath_registration`) →
  ``OdometryObservation`` between the two anchors; the same window is searched for pipelines →
  ``LineObservation``s;
* every ``recognition.every_patches`` patches, the newly covered area is searched for the CAD
  models (:mod:`.descriptor`, largest first) and each find registered (4-D + ICP): a new structure;
* every patch that covers a known structure is registered on it by ICP (independent data each
  time) → ``StructureObservation``; when a structure is first recognised, the patches of the pass
  closed shortly before are registered too and emitted one per swath (each at its own keyframe:
  the graph needs ``association.min_observations`` consistent observations at distinct keyframes).

Every observation is expressed in the current sonar frame with the estimate's relative motion from
the patch's anchor (a few seconds of DVL/AHRS at most), its covariance grown accordingly.
"""

from __future__ import annotations

import time
from collections import defaultdict
from typing import Any, ClassVar

import numpy as np

from frontends.sonar.config import SonarConfig
from frontends.sonar.grid import ElevationMap, GridSpec, estimate_ground
from frontends.sonar.known import KnownStructure
from frontends.sonar.patches import Patch, inv, overlap_area, top_points, transform, yaw_of
from frontends.sonar.pipes import PipeSegment, detect_pipes
from frontends.sonar.recognition import Recogniser
from frontends.sonar.registration import icp
from frontends.sonar.swath_registration import register
from semslam.errors import ConfigError, validated
from semslam.mission.measurements import SonarSwath
from semslam.observations import LineObservation, Observation, OdometryObservation, StructureObservation
from semslam.registry import FrontendSummary


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


class SonarFrontend:
    """Multibeam sonar front-end (``frontends.sonar`` section validated by :class:`SonarConfig`)."""

    config_model: ClassVar[type] = SonarConfig  # its section of the configuration, frontends.<name>
    name: ClassVar[str] = "sonar"
    consumes: ClassVar[tuple[type, ...]] = (SonarSwath,)

    def __init__(self, metadata: Any, config: dict | None = None):
        self.config = validated(SonarConfig, config, "frontends.sonar")
        from semslam.models.structures import structure_library

        lib = structure_library()
        names = self.config.recognition.models or tuple(lib)
        unknown = [n for n in names if n not in lib]
        if unknown:
            raise ConfigError(
                f"frontends.sonar.recognition.models: unknown structure model(s) {', '.join(unknown)} "
                f"(known: {', '.join(sorted(lib))})"
            )
        self.metadata = metadata
        self.library = {n: lib[n] for n in names}
        self._recogniser: Recogniser | None = None
        self._swaths: list[tuple[int, str, np.ndarray, np.ndarray | None]] = []
        self._track = 0.0
        self._last_pos: np.ndarray | None = None
        self.patches: list[Patch] = []
        self.structures: list[KnownStructure] = []
        self.swath_registrations: list[dict] = []
        self.rejected: dict[str, int] = defaultdict(int)
        self.pipe_observations = 0
        self.timing: dict[str, float] = defaultdict(float)
        self.n_points = 0
        self._queue: list[tuple[Patch, KnownStructure]] = []
        self._window_start = 0
        self._recog_from = 0
        self._failed: list[tuple[str, np.ndarray, int]] = []  # (model, centre, points) of failed registrations
        self._pose_cache: dict[int, np.ndarray | None] = {}
        self._landmarks = None
        self._view = None
        self._rng = np.random.default_rng(self.config.swath_registration.seed)
        self._sensor = None
        self.final: dict | None = None
        self.rejection_log: list = []  # why re-observations were not emitted (model, patch, reason, ...)
        self.swath_log: list = []  # (window anchor patch, reference patch, outcome) of every registration tried

    # ------------------------------------------------------------------------------------------
    @property
    def recogniser(self) -> Recogniser:
        if self._recogniser is None:
            t0 = time.process_time()
            self._recogniser = Recogniser(
                list(self.library.values()), self.config.recognition, self.config.registration
            )
            self.timing["templates_s"] += time.process_time() - t0
        return self._recogniser

    def _T_BS(self, sensor: str) -> np.ndarray:
        info = getattr(self.metadata, "sensors", {}).get(sensor) if self.metadata is not None else None
        return np.asarray(info.T_BS, float) if info is not None else np.eye(4)

    def _pose(self, stamp: int) -> np.ndarray | None:
        """T_WB at ``stamp`` from the view, cached for the current call."""
        if stamp not in self._pose_cache:
            T = self._view.pose_at(stamp) if self._view is not None else None
            if T is not None and hasattr(T, "matrix"):
                T = T.matrix()
            self._pose_cache[stamp] = None if T is None else np.asarray(T, float)
        return self._pose_cache[stamp]

    def place(self, patch: Patch) -> np.ndarray | None:
        """T_W,anchor of a patch with the current estimate."""
        return self._pose(patch.anchor_stamp)

    def _begin(self, view) -> None:
        self._view = view
        self._pose_cache = {}
        self._landmarks = None

    def _landmark_structures(self):
        if self._landmarks is None:
            try:
                lms = self._view.landmarks() if self._view is not None else []
            except Exception:  # a view without a map
                lms = []
            self._landmarks = [l for l in lms if l.kind == "structure" and l.pose is not None]
        return self._landmarks

    def _current_T(self, ks: KnownStructure) -> np.ndarray:
        """The graph's estimate of the structure once it is a landmark, else the front-end's own."""
        best, best_d = None, 1.5
        for lm in self._landmark_structures():
            if lm.model != ks.model:
                continue
            if ks.landmark_id is not None and lm.id == ks.landmark_id:
                best = lm
                break
            d = float(np.linalg.norm(np.asarray(lm.pose)[:3, 3] - ks.T_WM[:3, 3]))
            if d < best_d:
                best, best_d = lm, d
        if best is not None:
            ks.landmark_id = best.id
            ks.T_WM = np.asarray(best.pose, float)
        return ks.T_WM

    # ------------------------------------------------------------------------------------------
    def process(self, measurement: SonarSwath, view=None) -> list[Observation]:
        self._begin(view)
        cfg = self.config
        m = measurement
        self._sensor = m.sensor
        r = np.asarray(m.ranges)
        keep = np.isfinite(r) & (r >= cfg.map.min_range_m) & (r <= cfg.map.max_range_m)
        pts = m.points()[keep].astype(np.float32)
        self.n_points += len(pts)
        T = self._pose(m.stamp)
        if T is None:
            return []  # before the estimator's first pose: nothing to place the swath with
        self._swaths.append((m.stamp, m.sensor, pts, T))
        if self._last_pos is not None:
            self._track += float(np.linalg.norm(T[:3, 3] - self._last_pos))
        self._last_pos = T[:3, 3].copy()
        out: list[Observation] = []
        if self._track >= cfg.patches.length_m or len(self._swaths) >= cfg.patches.max_swaths:
            out += self._close_patch(m)
        if self._queue:
            busy = {o.model for o in out if isinstance(o, StructureObservation)}
            for k, (patch, ks) in enumerate(self._queue):
                if ks.model in busy:
                    continue
                self._queue.pop(k)
                obs = self._reobserve(patch, ks, m)
                if obs is not None:
                    out.append(obs)
                break
        return out

    # ------------------------------------------------------------------------------------------
    def _close_patch(self, m: SonarSwath | None) -> list[Observation]:
        sw, self._swaths = self._swaths, []
        self._track = 0.0
        if len(sw) < 2:
            return []
        stamps = np.array([s[0] for s in sw], np.int64)
        poses = [self._pose(int(s)) for s in stamps]
        keep = [k for k, T in enumerate(poses) if T is not None]
        if len(keep) < 2:
            return []
        a = keep[len(keep) // 2]
        T_WA = poses[a]
        A_inv = inv(T_WA)
        pts, idx = [], []
        yaws = []
        pos = []
        for k in keep:
            T_AS = A_inv @ poses[k] @ self._T_BS(sw[k][1])
            pts.append(transform(T_AS, sw[k][2]).astype(np.float32))
            idx.append(np.full(len(sw[k][2]), k, np.int32))
            yaws.append(yaw_of(poses[k]))
            pos.append(poses[k][:3, 3])
        P = np.concatenate(pts) if pts else np.zeros((0, 3), np.float32)
        yaws = np.unwrap(np.array(yaws))
        track = float(np.linalg.norm(np.diff(np.array(pos), axis=0), axis=1).sum())
        patch = Patch(
            len(self.patches),
            stamps,
            int(stamps[a]),
            P,
            np.concatenate(idx),
            T_WA.copy(),
            float(yaws.max() - yaws.min()),
            track,
        )
        if len(P):
            W = transform(T_WA, P)
            patch.lo, patch.hi = W[:, :2].min(0), W[:, :2].max(0)
            patch.top = top_points(P, self.config.recognition.map_cell_m)
        self.patches.append(patch)
        if m is None:
            return []
        out: list[Observation] = []
        cfg = self.config
        new: list[KnownStructure] = []
        if cfg.recognition.enabled and len(self.patches) - self._recog_from >= cfg.recognition.every_patches:
            new = self._recognise(m)
        for ks in self.structures:
            obs = self._reobserve(patch, ks, m)
            if obs is not None:
                out.append(obs)
        for ks in new:  # the pass's earlier patches, emitted one per swath from now on
            recent = [
                p
                for p in self.patches[:-1]
                if (m.stamp - p.anchor_stamp) * 1e-9 <= cfg.registration.recent_s and self._covers(p, ks)
            ]
            self._queue += [(p, ks) for p in reversed(recent)]
        W = cfg.swath_registration.window_patches
        if len(self.patches) - self._window_start >= W:
            window = self.patches[self._window_start : self._window_start + W]
            self._window_start += W
            pts_W = np.concatenate([p.world(self.place(p)) for p in window])
            if cfg.swath_registration.enabled:
                t0 = time.process_time()
                out += self._register_window(window, pts_W, m)
                self.timing["swath_registration_s"] += time.process_time() - t0
            if cfg.pipes.enabled:
                t0 = time.process_time()
                end = self._window_start
                extra = self.patches[max(0, end - cfg.pipes.window_patches) : end - W]
                pts_P = np.concatenate([pts_W] + [p.world(self.place(p)) for p in extra]) if extra else pts_W
                out += self._pipes(pts_P, m, reuse=max(1.0, (len(extra) + W) / W))
                self.timing["pipes_s"] += time.process_time() - t0
        return out

    def _covers(self, patch: Patch, ks: KnownStructure) -> bool:
        R = self.library[ks.model].footprint_radius
        c = ks.centre
        return bool(np.all(patch.lo - R <= c) and np.all(c <= patch.hi + R))

    # ------------------------------------------------------------------------------------------
    # recognition and structure observations

    def _recognise(self, m: SonarSwath) -> list[KnownStructure]:
        t0 = time.process_time()
        rec = self.recogniser
        recent = self.patches[self._recog_from :]
        self._recog_from = len(self.patches)
        recent = [p for p in recent if len(p.points)]
        if not recent:
            return []
        lo = np.min([p.lo for p in recent], axis=0)
        hi = np.max([p.hi for p in recent], axis=0)
        R = rec.max_radius
        lo_c, hi_c = lo - R, hi + R  # candidate centres whose disc meets the new data
        data = [p for p in self.patches if overlap_area(p.lo, p.hi, lo_c - R - 0.5, hi_c + R + 0.5) > 0]
        pts = np.concatenate([transform(self.place(p), p.top) for p in data])
        removed = [
            (self._current_T(ks)[:2, 3], self.library[ks.model].footprint_radius + 0.3) for ks in self.structures
        ]

        # candidates whose registration failed before are tried again only once their disc holds
        # a quarter more data (a structure first seen in part)
        def n_near(c, r):
            return int((np.hypot(pts[:, 0] - c[0], pts[:, 1] - c[1]) <= r).sum())

        still = [n_near(c, self.library[name].footprint_radius) < 1.25 * n for name, c, n in self._failed]
        self._failed = [f for f, keep in zip(self._failed, still) if keep]
        skip = [(name, c) for name, c, _ in self._failed]
        n_rej = len(rec.rejected)
        dets = rec.recognise(
            pts, lo_c, hi_c, removed, ground_kw=self._ground_kw(), full_points=self._points_near, skip=skip
        )
        for d in rec.rejected[n_rej:]:
            self._failed.append((d.model, d.centre, n_near(d.centre, self.library[d.model].footprint_radius)))
        new = []
        for det in dets:
            ks = KnownStructure(det.model, det.registration.T.copy(), det, m.stamp)
            self.structures.append(ks)
            new.append(ks)
            self.timing["registration_s"] += det.timing.get("registration_s", 0.0)
        self.timing["recognition_s"] += (
            time.process_time() - t0 - sum(d.timing.get("registration_s", 0.0) for d in dets)
        )
        self.timing["recognition_runs"] += 1
        return new

    def _points_near(self, centre, radius: float) -> np.ndarray:
        """Every point within ``radius`` of ``centre`` (north, east), patches placed with the current estimate."""
        lo, hi = np.asarray(centre) - radius, np.asarray(centre) + radius
        out = []
        for p in self.patches:
            if overlap_area(p.lo, p.hi, lo, hi) > 0:
                W = p.world(self.place(p))
                out.append(W[np.hypot(W[:, 0] - centre[0], W[:, 1] - centre[1]) <= radius])
        return np.concatenate(out) if out else np.zeros((0, 3))

    def _ground_kw(self) -> dict:
        c = self.config.map
        return dict(
            block_m=c.ground_block_m, window_m=c.ground_window_m, smooth_m=c.ground_smooth_m, band_m=c.ground_band_m
        )

    def _reobserve(self, patch: Patch, ks: KnownStructure, m: SonarSwath) -> StructureObservation | None:
        """Register the structure on one patch's points (ICP from its current estimate) and express
        it in the current sonar frame; None when the patch sees too little of it or fails the checks."""
        rc = self.config.registration
        if not self._covers(patch, ks):
            return None
        T_WA = self.place(patch)
        T_now = self._pose(m.stamp)
        if T_WA is None or T_now is None:
            return None
        T_WM = self._current_T(ks)
        md = self.recogniser.model_data[ks.model]
        R = md.model.footprint_radius + 0.5
        T_AM0 = inv(T_WA) @ T_WM
        c = T_AM0[:3, 3]
        near = np.hypot(patch.points[:, 0] - c[0], patch.points[:, 1] - c[1]) <= R
        if near.sum() < rc.min_points:
            self.rejection_log.append((ks.model, patch.id, "few points near", int(near.sum())))
            return None
        t0 = time.process_time()
        reg = icp(md, patch.points[near].astype(float), T_AM0, rc, distances=rc.icp_distances_m[-1:])
        self.timing["registration_s"] += time.process_time() - t0
        self.timing["reobservations"] += 1
        d = inv(T_AM0) @ reg.T
        jump = np.linalg.norm(d[:3, 3])
        turn = abs(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))
        sig_t = np.sqrt(np.linalg.eigvalsh(reg.cov[3:, 3:]).max())
        if (
            reg.n_structure < rc.min_points
            or reg.fitness < rc.min_fitness
            or reg.median_m > rc.max_median_m
            or jump > rc.max_jump_m
            or turn > np.radians(rc.max_turn_deg)
            or sig_t > rc.max_sigma_m
        ):
            why = (
                "points"
                if reg.n_structure < rc.min_points
                else "fitness"
                if reg.fitness < rc.min_fitness
                else "median"
                if reg.median_m > rc.max_median_m
                else "jump"
                if jump > rc.max_jump_m or turn > np.radians(rc.max_turn_deg)
                else "sigma"
            )
            self.rejected[f"structure_observation_{why}"] += 1
            self.rejection_log.append(
                (ks.model, patch.id, why, reg.n_structure, reg.fitness, reg.median_m, jump, np.degrees(turn), sig_t)
            )
            return None
        T_SW = inv(T_now @ self._T_BS(m.sensor))
        T_SM = T_SW @ T_WA @ reg.T
        carry = rc.carry_sigma_per_m * float(np.linalg.norm(T_now[:3, 3] - T_WA[:3, 3]))
        cov = reg.cov.copy()
        cov[3:, 3:] += np.eye(3) * carry**2
        ks.n_observations += 1
        ks.history.append((m.stamp, patch.id, T_SM, cov, float(reg.median_m)))
        return StructureObservation(m.stamp, m.sensor, model=ks.model, pose=T_SM, covariance=cov)

    # ------------------------------------------------------------------------------------------
    # swath registration

    def _register_window(self, window: list[Patch], pts_W: np.ndarray, m: SonarSwath) -> list[Observation]:
        cfg = self.config.swath_registration
        if any(p.heading_change > np.radians(self.config.patches.max_turn_deg) for p in window):
            self.rejected["swath_turn"] += 1
            return []
        j = window[len(window) // 2]
        lo, hi = pts_W[:, :2].min(0), pts_W[:, :2].max(0)
        best, best_a = None, 0.0
        for p in self.patches:
            if (j.anchor_stamp - p.anchor_stamp) * 1e-9 < cfg.min_age_s:
                break  # patches are in time order
            if p.heading_change > np.radians(self.config.patches.max_turn_deg):
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
            for q in self.patches[max(best.id - 3, 0) : best.id + 4]
            if q.heading_change <= np.radians(self.config.patches.max_turn_deg)
            and abs(_wrap(yaw_of(q.T_nav) - yaw_ref)) < np.radians(20)
            and (j.anchor_stamp - q.anchor_stamp) * 1e-9 >= cfg.min_age_s
        ]
        ref_pts = np.concatenate([q.world(self.place(q)) for q in group])
        spec = GridSpec.around(lo, hi, cfg.cell_m, pad=cfg.max_shift_m + 0.2)
        ref = ElevationMap.from_points(ref_pts, spec=spec).fill_small_holes()
        why: dict = {}
        res = register(pts_W, ref, cfg, self._rng, why)
        if res is None:
            for k in why:
                self.rejected[f"swath_{k}"] += 1
            self.swath_log.append((j.id, best.id, ",".join(why)))
            return []
        self.swath_log.append((j.id, best.id, "ok"))
        T_i = self._pose(best.anchor_stamp)
        T_j = self._pose(j.anchor_stamp)
        T_j2 = T_j.copy()
        T_j2[:3, 3] += np.array([res.shift[0], res.shift[1], res.depth])
        rel = inv(T_i) @ T_j2
        R_j = T_j[:3, :3]
        cov = np.zeros((6, 6))
        cov[:3, :3] = np.eye(3) * cfg.rotation_sigma_rad**2
        cov[3:, 3:] = R_j.T @ res.cov @ R_j
        self.swath_registrations.append(
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
            OdometryObservation(
                j.anchor_stamp, m.sensor, stamp_from=best.anchor_stamp, relative_pose=rel, covariance=cov
            )
        ]

    # ------------------------------------------------------------------------------------------
    # pipelines

    def _structure_mask(self, spec: GridSpec, margin: float) -> np.ndarray:
        N, E = spec.centres()
        mask = np.zeros(spec.shape, bool)
        for ks in self.structures:
            c = self._current_T(ks)[:2, 3]
            R = self.library[ks.model].footprint_radius + margin
            mask |= np.hypot(N[:, None] - c[0], E[None, :] - c[1]) <= R
        return mask

    def detect_pipes(self, pts_W: np.ndarray) -> list[PipeSegment]:
        """Pipe segments on the elevation map of ``pts_W`` ({W}) with the known structures removed."""
        pc = self.config.pipes
        em = ElevationMap.from_points(pts_W, pc.cell_m)
        ground = estimate_ground(em.depth, pc.cell_m, **self._ground_kw())
        segs = detect_pipes(
            em, ground, pc, self._structure_mask(em.spec, pc.structure_margin_m), np.random.default_rng(pc.seed)
        )
        for s in segs:
            s.connected = self._connections(s)
        return segs

    def _connections(self, seg: PipeSegment) -> tuple[str, ...]:
        """Known structures with a hub of about the segment's radius near one of its ends."""
        out = []
        for ks in self.structures:
            model = self.library[ks.model]
            T = self._current_T(ks)
            for hub, (hub_p, _) in zip(model.hubs, model.hubs_in(T)):
                if abs(hub.pipe_radius - seg.radius) > 0.5 * hub.pipe_radius:
                    continue
                if min(np.linalg.norm(e[:2] - hub_p[:2]) for e in (seg.p, seg.q)) <= self.config.pipes.hub_distance_m:
                    out.append(ks.model)
        return tuple(dict.fromkeys(out))

    def _pipes(self, pts_W: np.ndarray, m: SonarSwath, reuse: float = 1.0) -> list[Observation]:
        """Pipe observations on ``pts_W``; ``reuse``: how many observations each cell goes into
        (overlapping windows), by which the covariance is inflated."""
        pc = self.config.pipes
        T_now = self._pose(m.stamp)
        if T_now is None or len(pts_W) < 100:
            return []
        segs = self.detect_pipes(pts_W)
        T_SW = inv(T_now @ self._T_BS(m.sensor))
        out = []
        for s in segs:
            d = s.q - s.p
            d = d / max(np.linalg.norm(d), 1e-9)
            c1 = reuse * ((np.eye(3) - np.outer(d, d)) * pc.lateral_sigma_m**2 + np.outer(d, d) * pc.along_sigma_m**2)
            R = T_SW[:3, :3]
            cS = R @ c1 @ R.T
            cov = np.zeros((6, 6))
            cov[:3, :3] = cS
            cov[3:, 3:] = cS
            out.append(
                LineObservation(
                    m.stamp,
                    m.sensor,
                    p=transform(T_SW, s.p[None])[0],
                    q=transform(T_SW, s.q[None])[0],
                    covariance=cov,
                    radius=s.radius,
                    connected_models=s.connected,
                )
            )
        self.pipe_observations += len(out)
        return out

    # ------------------------------------------------------------------------------------------
    # end of mission

    def finish(self, view=None) -> FrontendSummary:
        from frontends.sonar.summary import summarise

        self._begin(view)
        if len(self._swaths) >= 2:
            self._close_patch(None)
        return summarise(self)
