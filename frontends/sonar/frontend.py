"""The sonar front-end: multibeam swaths in; relative-pose constraints (swath registration), CAD
structures (6-DoF) and pipelines out; at the end a world model, figures and the sonar metrics.

Online, as the swaths arrive (each placed with the graph's current estimate through the view):

* every ``patches.length_m`` of track the pending swaths become a :class:`Patch`, rigid in the frame
  of its middle swath (its anchor; :func:`.patches.make_patch`);
* every ``swath_registration.window_patches`` patches, the window they form is registered on the
  older overlapping patches of the neighbouring line (:class:`.window_registration.WindowRegistration`)
  → ``OdometryObservation`` between the two anchors;
* every ``pipes.every_patches`` patches, the latest ``pipes.window_patches`` patches are searched for
  pipelines → ``LineObservation``s;
* every ``recognition.every_patches`` patches, the newly covered area is searched for the CAD
  models (:mod:`.descriptor`, largest first) and each find registered (4-D + ICP): a new structure;
* every patch that covers a known structure is registered on it by ICP (independent data each
  time; :class:`.reobservation.StructureReobservation`) → ``StructureObservation``; when a structure is first recognised, the patches of the pass
  closed shortly before are registered too and emitted one per swath (each at its own keyframe:
  the graph needs ``association.min_observations`` consistent observations at distinct keyframes).

Every observation is expressed in the current sonar frame with the estimate's relative motion from
the patch's anchor (a few seconds of DVL/AHRS at most), its covariance grown accordingly.
"""

from __future__ import annotations

import time
from collections import defaultdict
from typing import ClassVar

import numpy as np

from frontends.sonar.config import SonarConfig
from frontends.sonar.grid import ElevationMap, GridSpec, estimate_ground
from frontends.sonar.known import KnownStructure
from frontends.sonar.patches import Patch, inv, make_patch, overlap_area, transform
from frontends.sonar.pipes import PipeSegment, detect_pipes
from frontends.sonar.recognition import Recogniser
from frontends.sonar.reobservation import StructureReobservation
from frontends.sonar.window_registration import WindowRegistration
from semslam.errors import ConfigError, validated
from semslam.estimation import EstimateView
from semslam.mission.measurements import SonarSwath
from semslam.mission.mission import MissionMetadata
from semslam.observations import LineObservation, Observation, StructureObservation
from semslam.registry import Frontend, FrontendSummary


class SonarFrontend(Frontend):
    """Multibeam sonar front-end (``frontends.sonar`` section validated by :class:`SonarConfig`)."""

    config_model: ClassVar[type] = SonarConfig  # its section of the configuration, frontends.<name>
    name: ClassVar[str] = "sonar"
    consumes: ClassVar[tuple[type, ...]] = (SonarSwath,)

    def __init__(self, metadata: MissionMetadata, config: dict | None = None):
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
        self._odometer = 0.0  # track since the first placed swath (m)
        self._patch_odometer: dict[int, float] = {}  # the odometer when each patch closed
        self._last_pos: np.ndarray | None = None
        self.patches: list[Patch] = []
        self.structures: list[KnownStructure] = []
        self.rejected: dict[str, int] = defaultdict(int)  # rejections by reason, every stage
        self.pipe_observations = 0
        self.timing: dict[str, float] = defaultdict(float)
        self.windows = WindowRegistration(
            self.config.swath_registration, np.radians(self.config.patches.max_turn_deg), self.rejected
        )
        self.reobservation = StructureReobservation(self.config.registration, self.rejected, self.timing)
        self.n_points = 0
        self._queue: list[tuple[Patch, KnownStructure]] = []
        self._window_start = 0
        self._pipes_at = 0  # patches there were at the last pipe detection
        self._recog_from = 0
        self._failed: list[tuple[str, np.ndarray, int]] = []  # (model, centre, points) of failed registrations
        self._pose_cache: dict[int, np.ndarray | None] = {}
        self._landmarks = None
        self._view = None
        self.final: dict | None = None

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

    @property
    def swath_registrations(self) -> list[dict]:
        """Every accepted window registration (see :class:`WindowRegistration`)."""
        return self.windows.accepted

    def _T_BS(self, sensor: str) -> np.ndarray:
        """The sonar's mount, from the mission's metadata (an undeclared sensor is an error)."""
        return np.asarray(self.metadata.extrinsic(sensor), float)

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
    def process(self, measurement: SonarSwath, view: EstimateView | None = None) -> list[Observation]:
        self._begin(view)
        cfg = self.config
        m = measurement
        r = np.asarray(m.ranges)
        keep = np.isfinite(r) & (r >= cfg.map.min_range_m) & (r <= cfg.map.max_range_m)
        pts = m.points()[keep].astype(np.float32)
        self.n_points += len(pts)
        T = self._pose(m.stamp)
        if T is None:
            return []  # before the estimator's first pose: nothing to place the swath with
        self._swaths.append((m.stamp, m.sensor, pts, T))
        if self._last_pos is not None:
            step = float(np.linalg.norm(T[:3, 3] - self._last_pos))
            self._track += step
            self._odometer += step
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
        patch = make_patch(
            len(self.patches),
            stamps,
            [s[2] for s in sw],
            [self._pose(int(s)) for s in stamps],
            [self._T_BS(s[1]) for s in sw],
            self.config.recognition.map_cell_m,
        )
        if patch is None:
            return []
        self.patches.append(patch)
        self._patch_odometer[patch.id] = self._odometer
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
                out += self.windows.register(window, pts_W, self.patches, self.place, m.sensor)
                self.timing["swath_registration_s"] += time.process_time() - t0
        pc = cfg.pipes
        if pc.enabled and len(self.patches) - self._pipes_at >= pc.every_patches:
            t0 = time.process_time()
            self._pipes_at = len(self.patches)
            used = self.patches[max(0, self._pipes_at - pc.window_patches) :]
            pts_P = np.concatenate([p.world(self.place(p)) for p in used])
            out += self._pipes(pts_P, m, reuse=max(1.0, len(used) / pc.every_patches))
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
            ks = KnownStructure(det.model, det.registration.T.copy(), det, m.stamp, seen_track_m=self._odometer)
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
        """The structure registered on one patch, in the current sonar frame; None when the patch does
        not cover it, cannot be placed, or the registration fails its checks."""
        if not self._covers(patch, ks):
            return None
        T_WA = self.place(patch)
        T_now = self._pose(m.stamp)
        if T_WA is None or T_now is None:
            return None
        md = self.recogniser.model_data[ks.model]
        at = self._patch_odometer.get(patch.id, self._odometer)
        obs = self.reobservation.observe(
            patch,
            ks,
            md,
            T_WA,
            self._current_T(ks),
            T_now,
            self._T_BS(m.sensor),
            m.stamp,
            m.sensor,
            gap_m=abs(at - ks.seen_track_m),
        )
        if obs is not None:
            ks.seen_track_m = max(ks.seen_track_m, at)
        return obs

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

    def finish(self, view: EstimateView | None = None) -> FrontendSummary:
        from frontends.sonar.summary import summarise

        self._begin(view)
        if len(self._swaths) >= 2:
            self._close_patch(None)
        return summarise(self)
