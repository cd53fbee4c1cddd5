"""The graph back-end: iSAM2 online (and Levenberg–Marquardt batch) smoothing over keyframes with
navigation factors between them and object / pipe / structure landmarks.

State (see factors.navigation): per keyframe k, X(k) = T_WB (Pose3) and V(k) = body velocity.
Keyframes are created at every observation batch and at least every
``GraphConfig.keyframe_max_interval_s``. Between consecutive keyframes: the preintegrated
DVL/AHRS displacement (with the velocity motion model across dropouts) and, over intervals with no
DVL at all, the velocity random walk. At each keyframe: the AHRS attitude, the depth and the latest
DVL velocity. Landmarks: object points L(id), pipe lines P(id) (4-vector, anchored chart),
structures S(id) (Pose3), with robust kernels, data association by JCBB against the current
estimate, and initialisation after ``association.min_observations`` consistent observations.
Online, iSAM2 holds a window of ``GraphConfig.window_s`` seconds (see :mod:`semslam.backend.window`);
the batch re-optimisation spans the whole mission.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import gtsam
import numpy as np
from scipy.optimize import linear_sum_assignment

from factors.geometry import pose_point_jacobian
from factors.landmarks import (
    LineAnchor,
    line_factor,
    line_observation_covariance,
    line_residual,
    point_factor,
    point_residual,
    robust_kernel,
    structure_factor,
    structure_residual,
)
from semslam.backend.keyframes import Keyframes
from semslam.backend.landmarks import Landmark, ObservationRecord, Track
from semslam.backend.problem import Candidate, GraphAssociationProblem, possible_pairs
from semslam.backend.result import final_values, keyframe_trajectory, online_trajectory
from semslam.backend.session import IsamSession
from semslam.backend.window import SlidingWindow, value_of
from semslam.config import GraphConfig, SemslamConfig
from semslam.estimation import EstimatorResult, LandmarkEstimate, Trajectory
from semslam.mapping.association import LowRankJoint, PairLinearization, chi2_gate, jcbb, uncorrelated_candidates
from semslam.mapping.book import LandmarkBook
from semslam.mapping.extent import PipeExtent, along_sigma
from semslam.mapping.pipes import merge_collinear, object_between, point_segment_distance, segment_matches_line
from semslam.mission.measurements import Measurement
from semslam.mission.mission import MissionMetadata
from semslam.observations import LineObservation, OdometryObservation, PointObservation, StructureObservation

X = gtsam.symbol_shorthand.X
V = gtsam.symbol_shorthand.V
B = gtsam.symbol_shorthand.B  # AHRS heading bias (1-vector), when modelled
KEY_OF_KIND = {
    "object": gtsam.symbol_shorthand.L,
    "pipe": gtsam.symbol_shorthand.P,
    "structure": gtsam.symbol_shorthand.S,
}
KIND_OF_OBS = {PointObservation: "object", LineObservation: "pipe", StructureObservation: "structure"}


class GraphView:
    """Read-only view of the graph estimate handed to front-ends."""

    def __init__(self, est: GraphEstimator):
        self._est = est

    def pose_at(self, stamp: int) -> np.ndarray | None:
        p = self._est.keyframes.pose_at(stamp)
        return None if p is None else p.matrix()

    def landmarks(self) -> Sequence[LandmarkEstimate]:
        return self._est.landmark_estimates(covariance=False)


class GraphEstimator:
    """iSAM2 graph estimator (name ``graph``) implementing :class:`semslam.estimation.Estimator`."""

    name = "graph"

    def __init__(self, metadata: MissionMetadata, config: SemslamConfig | None = None, batch: bool | None = None):
        config = config or SemslamConfig()
        self.cfg: GraphConfig = config.graph
        self.batch = self.cfg.batch if batch is None else bool(batch)
        self.assoc = config.association
        self.metadata = metadata
        self.diagnostics: list[str] = []
        self.session = IsamSession(self.cfg.relinearize_threshold, self.cfg.relinearize_skip, self.diagnostics)
        self.window = SlidingWindow(self.cfg.window_s, self.diagnostics)
        self.keyframes = Keyframes(metadata, config, self.session, self.window)
        self.robust = robust_kernel(self.cfg.robust_kernel, self.cfg.robust_k)
        self.landmarks: dict[int, Landmark] = {}
        self.book = LandmarkBook()  # views, class evidence and connectivity of the landmarks
        self.tracks: list[Track] = []
        self._next_id = 0
        self.update_times: list[float] = []
        self.update_n_landmarks: list[int] = []
        self.update_kinds: list[str] = []
        self._ambiguous: set[int] = set()
        self._current_obs: list = []
        self._volume: dict[int, list[tuple[int, float]]] = {}  # landmark id → [(stamp, log det cov)]
        # Bounding sphere (centre, radius) of every landmark, refreshed with its estimate.
        self._sphere_row: dict[int, int] = {}
        self._sphere_ids: list[int] = []
        self._sphere_c = np.zeros((0, 3))
        self._sphere_r = np.zeros(0)
        self._sphere_obj = np.zeros(0, bool)  # the row is an object landmark (its centre is its point)

    # ------------------------------------------------------------------ protocol
    def view(self) -> GraphView:
        return GraphView(self)

    def process_measurement(self, measurement: Measurement) -> None:
        due = self.keyframes.add(measurement)
        if due == "first":
            self._timed(lambda: self.keyframes.first(measurement.stamp), "keyframe")
        elif due == "next":
            self._timed(lambda: self._keyframe(measurement.stamp), "keyframe")

    def process_observations(self, stamp: int, observations: Sequence) -> None:
        if not observations:
            return
        if not self.keyframes.stamps:
            self.diagnostics.append(f"{stamp}: {len(observations)} observations before the first keyframe, ignored")
            return
        self._timed(lambda: self._observations(stamp, list(observations)), "observations")

    # ------------------------------------------------------------------ keyframes
    def _timed(self, fn, kind: str) -> None:
        t0 = time.perf_counter()
        fn()
        self.update_times.append(time.perf_counter() - t0)
        self.update_n_landmarks.append(len(self.landmarks))
        self.update_kinds.append(kind)

    def _reactivate(self, lm: Landmark, priors: list, values: gtsam.Values) -> None:
        """A marginalised landmark seen again re-enters the window: its frozen estimate, with the
        covariance of its own views (pose uncertainty folded in) as a prior. Its correlation with
        the window's poses was lost when it left; the views' covariance is the conservative choice."""
        lm.active = True
        self.window.returns += 1
        noise = gtsam.noiseModel.Gaussian.Covariance(lm.information_covariance())
        if lm.kind == "object":
            prior = gtsam.PriorFactorPoint3(lm.key, np.asarray(lm.estimate, float), noise)
        elif lm.kind == "pipe":
            prior = gtsam.PriorFactorVector(lm.key, np.asarray(lm.estimate, float), noise)
        else:
            prior = gtsam.PriorFactorPose3(lm.key, lm.estimate, noise)
        priors.append((prior, lm.id))
        values.insert(lm.key, lm.estimate)

    def _keyframe(self, stamp: int) -> int:
        """A new keyframe, then the window slides if it is due."""
        k = self.keyframes.next(stamp)
        slid = self.window.slide(self.session, self.keyframes.stamps)
        if slid is not None:
            drop, estimate = slid
            for lm in self.landmarks.values():
                if lm.active and lm.key in drop:
                    lm.active, lm.estimate = False, value_of(estimate, lm.key)
                    self._update_sphere(lm)
            self.keyframes.refresh()
        return k

    def _commit(self, factors: list, values: gtsam.Values, priors: list = ()) -> bool:
        """Commit to iSAM2; after a failure the landmarks created in the failed update disappear and
        those that were coming back stay out of the window. False if something was dropped."""
        dropped = self.session.commit(factors, values, self.keyframes.anchor(), priors, self.keyframes.stamps[-1])
        if dropped is None:
            return True
        for lid in dropped:
            lm = self.landmarks.get(lid)
            if lm is not None and not self.session.owns(lid):
                del self.landmarks[lid]
                row = self._sphere_row.pop(lid, None)
                if row is not None:
                    self._sphere_c[row] = np.inf  # never near again
        keep = self.session.window_keys()
        for lm in self.landmarks.values():
            lm.active = lm.key in keep
        return False

    # ------------------------------------------------------------------ observations
    def _sensor_T(self, sensor: str) -> np.ndarray:
        return self.metadata.extrinsic(sensor)

    def _keyframe_for(self, stamp: int) -> int | None:
        stamps = self.keyframes.stamps
        if stamp == stamps[-1]:
            return len(stamps) - 1
        if stamp > stamps[-1]:
            return self._keyframe(stamp)
        return self.keyframes.older(stamp, self.diagnostics)

    def _valid(self, z) -> bool:
        arrays = [
            np.asarray(getattr(z, a))
            for a in ("position", "p", "q", "pose", "covariance", "relative_pose")
            if hasattr(z, a)
        ]
        if not all(np.all(np.isfinite(a)) for a in arrays):
            return False
        if isinstance(z, LineObservation) and np.linalg.norm(z.q - z.p) < 1e-3:
            return False
        return True

    def _observations(self, stamp: int, observations: list) -> None:
        k = self._keyframe_for(stamp)
        if k is None:
            return
        pose, pose_cov = self.keyframes.pose_and_cov(k)
        bad = [z for z in observations if not self._valid(z)]
        if bad:
            self.diagnostics.append(f"{stamp}: {len(bad)} degenerate or non-finite observations dropped")
        observations = [z for z in observations if self._valid(z)]
        odom = [z for z in observations if isinstance(z, OdometryObservation)]
        lines = self._merged_lines(observations, pose)
        obs = [z for z in observations if isinstance(z, (PointObservation, StructureObservation))] + lines
        factors: list[tuple] = [(f, None) for f in self.keyframes.odometry_factors(odom, self.diagnostics)]
        priors: list[tuple] = []
        values = gtsam.Values()
        if obs:
            T_BS = [self._sensor_T(z.sensor) for z in obs]
            self._current_obs = obs
            pairing, lins = self._associate(pose, pose_cov, obs, T_BS)
            for i, z in enumerate(obs):
                if pairing[i] is not None:
                    lm = self.landmarks[pairing[i]]
                    if not lm.active:
                        self._reactivate(lm, priors, values)
                    factors.append((self._landmark_factor(lm, k, z, T_BS[i], pose, lins[i]), lm.id))
                    self._record(lm, stamp, k, z, pose, T_BS[i], pose_cov, lins[i])
            unpaired = [(z, T_BS[i]) for i, z in enumerate(obs) if pairing[i] is None]
            self._extend_tracks(stamp, k, unpaired, pose, pose_cov, factors, values)
        self._purge_tracks(stamp)
        if factors or values.size():
            self._commit(factors, values, priors)
            self.keyframes.refresh()
            self.keyframes.renew_online(k)
            updated = {o for _, o in factors if o is not None}
            self._refresh_landmarks(updated)
            self._merge_twins(updated)

    def _merge_twins(self, ids) -> None:
        """Two object landmarks that have converged on one place (closer than
        ``association.min_separation_m`` and compatible at the association's χ² confidence) are one
        object mapped twice, e.g. from a first track whose views were off: the younger is tied to
        the older by a stiff zero-offset factor and leaves the map, its views and class evidence
        going to the older one."""
        gate = chi2_gate(self.assoc.confidence, 3)
        for lid in sorted(ids):
            a = self.landmarks.get(lid)
            if a is None or a.kind != "object":
                continue
            # Neighbours from the landmarks' cached bounding spheres (an object's is its point):
            # numpy over the map, not a Python loop, as this runs after every update.
            sphere_ids, centres, _ = self._spheres()
            near = np.flatnonzero(
                np.linalg.norm(centres - np.asarray(a.estimate, float), axis=1) < self.assoc.min_separation_m
            )
            for b in [self.landmarks.get(sphere_ids[r]) for r in near]:
                if b is None or b.kind != "object" or b.id == a.id or not b.active:
                    continue
                d = np.asarray(a.estimate, float) - np.asarray(b.estimate, float)
                S = a.information_covariance() + b.information_covariance()
                if d @ np.linalg.solve(S, d) > gate:
                    continue
                keep, drop = (a, b) if a.id < b.id else (b, a)
                tie = gtsam.BetweenFactorPoint3(
                    keep.key, drop.key, np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 1e-3)
                )
                self.book.merge(keep.id, drop.id)
                if drop.information is not None:
                    keep.add_information(drop.information)
                keep.connected |= drop.connected
                del self.landmarks[drop.id]
                row = self._sphere_row.pop(drop.id, None)
                if row is not None:
                    self._sphere_c[row] = np.inf  # never near again
                self._volume.pop(drop.id, None)
                self.diagnostics.append(
                    f"{self.keyframes.stamps[-1]}: objects {keep.id} and {drop.id} converged on one place, merged into {keep.id}"
                )
                self._commit([(tie, keep.id)], gtsam.Values())
                self._refresh_landmarks({keep.id})
                if drop is a:
                    break

    # ------------------------------------------------------------------ association
    def _world_summary(self, z, pose: gtsam.Pose3, T_BS: np.ndarray) -> np.ndarray:
        """A world point standing for the observation (object / segment midpoint / structure origin)."""
        T_WS = pose.compose(gtsam.Pose3(T_BS))
        if isinstance(z, PointObservation):
            return T_WS.transformFrom(z.position)
        if isinstance(z, LineObservation):
            return T_WS.transformFrom(0.5 * (z.p + z.q))
        return T_WS.transformFrom(z.pose[:3, 3])

    def _associate(self, pose, pose_cov, obs, T_BS) -> tuple[list[int | None], list[PairLinearization | None]]:
        """JCBB over the pre-gated landmarks; returns the landmark id of each observation or None,
        and the linearisation of each pairing at (pose, landmark estimate), which the association
        computed and the factor and the landmark's information reuse.

        Unpaired observations individually compatible with a landmark are left unpaired too, but
        flagged: pipes attach to it (two segments of one pipe), others are discarded rather than
        allowed to start a duplicate."""
        self._ambiguous: set[int] = set()
        none = [None] * len(obs)
        if not self.landmarks:
            return none, none
        obs_pts = np.array([self._world_summary(z, pose, T) for z, T in zip(obs, T_BS)])
        # Coarse pre-gate on the cached spheres (O(map) in numpy only, so the cost stays flat).
        ids, centres, radii = self._spheres()
        dist = np.linalg.norm(obs_pts[:, None, :] - centres[None, :, :], axis=2) - radii[None, :]
        near = np.flatnonzero((dist <= self.assoc.pre_gate_m + 1.0).any(axis=0))
        if near.size == 0:
            return none, none
        cand_lms = [self.landmarks[ids[j]] for j in near if ids[j] in self.landmarks]
        self._refresh_landmarks({lm.id for lm in cand_lms}, covariance=True)
        anchor_pts = np.array([_landmark_point(lm) for lm in cand_lms])
        dist = np.linalg.norm(obs_pts[:, None, :] - anchor_pts[None, :, :], axis=2)
        for j, lm in enumerate(cand_lms):
            if lm.kind == "pipe":
                dist[:, j] = point_segment_distance(obs_pts, *_pipe_ends(lm))
        cands = [Candidate(lm, lm.covariance) for lm in cand_lms]
        gates = {d: chi2_gate(self.assoc.confidence, d) for d in (3, 4)}
        allowed = (dist <= self.assoc.pre_gate_m) & possible_pairs(pose, pose_cov, obs, T_BS, cands, gates)
        problem = GraphAssociationProblem(
            pose,
            pose_cov,
            obs,
            T_BS,
            cands,
            self.assoc.pipe_extent_gap_m,
            allowed,
            separators=self._object_points(),
            separator_radius=self.assoc.inline_object_radius_m,
            cutters=self._mapped_object_points(),
        )
        pairs = [(i, int(j), problem.pair(i, int(j))) for i in range(len(obs)) for j in problem.candidate_landmarks(i)]
        cov_of = problem.landmark_covariance
        found = uncorrelated_candidates(
            len(obs), [t for t in pairs if t[2] is not None], pose_cov, cov_of, self.assoc.confidence
        )
        result = jcbb(found, LowRankJoint(found, pose_cov, cov_of), self.assoc.confidence)
        paired = {j for j in result if j is not None}
        out: list[int | None] = []
        lins: list[PairLinearization | None] = []
        for i, j in enumerate(result):
            lins.append(None)
            if j is not None:
                out.append(cand_lms[j].id)
                lins[i] = problem.pair(i, j)
                continue
            # Left unpaired by JCBB: is it compatible with some landmark anyway?
            best = found.best(i)
            if best is not None:
                best_j = int(found.lm[best])
                if isinstance(obs[i], LineObservation) and best_j in paired:
                    out.append(cand_lms[best_j].id)  # a second segment of a pipe already paired
                    lins[i] = found.lin[best]
                    continue
                self._ambiguous.add(i)
            elif self._overlaps_mapped(obs[i], pose, T_BS[i], cand_lms):
                self._ambiguous.add(i)
            out.append(None)
        return out, lins

    # ------------------------------------------------------------------ landmarks
    def _landmark_factor(self, lm: Landmark, k: int, z, T_BS, pose: gtsam.Pose3, lin: PairLinearization | None = None):
        """``lin``: the pairing's linearisation at (pose, lm.estimate), when the association has it."""
        if lm.kind == "object":
            return point_factor(X(k), lm.key, z.position, z.covariance, T_BS, self.robust)
        if lm.kind == "pipe":
            cov4 = (
                lin.R
                if lin is not None
                else line_observation_covariance(pose, lm.estimate, lm.anchor, T_BS, z.covariance)
            )
            return line_factor(X(k), lm.key, lm.anchor, z.p, z.q, cov4, T_BS, self.robust)
        return structure_factor(X(k), lm.key, z.pose, z.covariance, T_BS, self.robust)

    def _record(
        self,
        lm: Landmark,
        stamp: int,
        k: int,
        z,
        pose: gtsam.Pose3,
        T_BS,
        pose_cov: np.ndarray,
        lin: PairLinearization | None = None,
    ) -> None:
        """``lin``: the observation's linearisation at (pose, lm.estimate), when the association has it."""
        self.book.observe(lm.id, stamp, z)
        if lin is not None:
            lm.add_information(_information(lin.H_x, lin.H_l, lin.R, pose_cov))
        else:
            lm.add_information(_observation_information(lm, z, pose, pose_cov, T_BS))
        if lm.kind == "pipe":
            T_WS = pose.compose(gtsam.Pose3(T_BS))
            lm.extent.add(np.vstack([T_WS.transformFrom(z.p), T_WS.transformFrom(z.q)]), along_sigma(z))

    def _extend_tracks(self, stamp, k, unpaired: list, pose, pose_cov, factors, values) -> None:
        """The scan's unpaired observations (z, T_BS) extend tentative landmarks or start new ones;
        a track reaching ``min_observations`` is promoted to the graph. One-to-one, by the
        assignment of least total cost over the scan (Hungarian), not observation by observation:
        in a row of objects 25–35 cm apart, with a missed object and the first seconds' 6 cm of
        pose σ, the greedy choice let each view take its neighbour's track and the shift ran down
        the row (tank, 10 % misses: views of three objects in the wrong tracks)."""
        items = [(z, *self._in_world(z, T_BS, pose, pose_cov)) for z, T_BS in unpaired if not self._is_ambiguous(z)]
        tracks = list(self.tracks)
        objects = self._object_points()  # the separators of collinear pipes, once for the scan
        cost = np.full((len(items), len(tracks)), np.inf)
        for i, (z, w, cov) in enumerate(items):
            for j, tr in enumerate(tracks):
                cost[i, j] = self._track_cost(tr, z, w, cov, k, objects)
        chosen: dict[int, Track] = {}
        if np.isfinite(cost).any():
            # each observation may also start a track, at the price of its gate: two near misses
            # must not beat one good continuation and one new track
            new = np.full((len(items), len(items)), 1e12)
            np.fill_diagonal(new, [self._track_gate(z) for z, _, _ in items])
            rows, cols = linear_sum_assignment(np.hstack([np.where(np.isfinite(cost), cost, 1e12), new]))
            chosen = {r: tracks[c] for r, c in zip(rows, cols) if c < len(tracks) and np.isfinite(cost[r, c])}
        for i, (z, w, cov) in enumerate(items):
            tr = chosen.get(i)
            if tr is None:
                tr = Track(KIND_OF_OBS[type(z)], model=getattr(z, "model", None))
                self.tracks.append(tr)
            tr.records.append(ObservationRecord(stamp, k, z))
            tr.world.append(w)
            if cov is not None:
                tr.world_cov.append(cov)
            tr.last_stamp = stamp
            if len(tr.records) >= self.assoc.min_observations:
                self.tracks.remove(tr)
                self._promote(tr, factors, values, pose_cov)

    def _in_world(self, z, T_BS, pose: gtsam.Pose3, pose_cov: np.ndarray):
        """An observation in {W} with the pose (point: (3,), pipe: (2, 3), structure: 4×4) and, for
        points and structures, its position covariance there (observation and pose)."""
        T_WS = pose.compose(gtsam.Pose3(T_BS))
        R = pose.rotation().matrix()
        if isinstance(z, LineObservation):
            return np.vstack([T_WS.transformFrom(z.p), T_WS.transformFrom(z.q)]), None
        if isinstance(z, PointObservation):
            w, p_S, C_S = T_WS.transformFrom(z.position), z.position, z.covariance
        else:
            w, p_S, C_S = T_WS.compose(gtsam.Pose3(z.pose)).matrix(), z.pose[:3, 3], z.covariance[3:, 3:]
        e_B = T_BS[:3, :3] @ p_S + T_BS[:3, 3]
        J = pose_point_jacobian(R, e_B)
        return w, R @ T_BS[:3, :3] @ C_S @ T_BS[:3, :3].T @ R.T + J @ pose_cov @ J.T

    def _track_gate(self, z) -> float:
        """The largest :meth:`_track_cost` that continues a track."""
        if isinstance(z, LineObservation):
            return self.assoc.merge_distance_m
        return chi2_gate(self.assoc.track_gate_confidence, 3)

    def _track_cost(self, tr: Track, z, w, cov, k: int, objects: np.ndarray) -> float:
        """How well observation z (in {W}: w, cov) continues track tr; inf when it cannot.
        Points and structures: the Mahalanobis distance² within the track gate; pipes: the
        distance of the segment's middle from the track's line, when the paper's collinearity
        criterion holds and no in-line object (``objects``, N×3 in {W}) lies between."""
        kind = KIND_OF_OBS[type(z)]
        if tr.kind != kind or tr.records[-1].keyframe == k:
            return np.inf
        if kind == "pipe":
            c, d = tr.line_fit()
            seen = np.vstack(tr.world)
            s_seen = (seen - c) @ d
            if not segment_matches_line(
                w, c, d, seen, self.assoc.merge_angle_rad, self.assoc.merge_distance_m, self.assoc.pipe_extent_gap_m
            ) or object_between((s_seen.min(), s_seen.max()), w, c, d, objects, self.assoc.inline_object_radius_m):
                return np.inf
            return float(np.linalg.norm(np.cross(w.mean(axis=0) - c, d)))
        if kind == "structure" and tr.model != z.model:
            return np.inf
        mean, mcov = tr.mean_position()
        r = (w if kind == "object" else w[:3, 3]) - mean
        d2 = float(r @ np.linalg.solve(cov + mcov, r))
        return d2 if d2 < self._track_gate(z) else np.inf

    def _overlaps_mapped(self, z, pose: gtsam.Pose3, T_BS: np.ndarray, landmarks: list[Landmark]) -> bool:
        """An observation that failed the χ² gates but lies where a mapped landmark of its kind
        physically is (objects: closer than ``min_separation_m``; pipes: both ends that close to the
        line, nearly parallel, half of it within what was seen of it) is that
        landmark seen badly: it must not start a second one."""
        sep = self.assoc.min_separation_m
        T_WS = pose.compose(gtsam.Pose3(T_BS))
        if isinstance(z, PointObservation):
            w = T_WS.transformFrom(z.position)
            return any(lm.kind == "object" and np.linalg.norm(w - lm.estimate) < sep for lm in landmarks)
        if not isinstance(z, LineObservation):
            return False
        seg = np.vstack([T_WS.transformFrom(z.p), T_WS.transformFrom(z.q)])
        u = (seg[1] - seg[0]) / np.linalg.norm(seg[1] - seg[0])
        objects, mapped = self._object_points(), self._mapped_object_points()
        for lm in landmarks:
            if lm.kind != "pipe":
                continue
            c, d = lm.line()
            r = seg - c
            if np.arccos(min(1.0, abs(float(u @ d)))) > self.assoc.merge_angle_rad:
                continue
            if np.linalg.norm(r - np.outer(r @ d, d), axis=1).max() >= sep:
                continue
            s_ = r @ d
            lo, hi = seen = lm.extent.interval(c, d, mapped, self.assoc.inline_object_radius_m)
            if min(s_.max(), hi) - max(s_.min(), lo) < 0.5 * (s_.max() - s_.min()):
                continue  # mostly beyond what was seen: possibly the next pipe in line
            if not object_between(seen, seg, c, d, objects, self.assoc.inline_object_radius_m):
                return True
        return False

    def _merged_lines(self, observations: list, pose: gtsam.Pose3) -> list[LineObservation]:
        """The batch's pipe segments merged along shared axes, sensor by sensor. Objects of the batch
        and objects already mapped or tracked (placed in the sensor frame with the current pose) keep
        the segments on either side of them apart: a missed in-line valve must not join its two pipes."""
        out: list[LineObservation] = []
        objects_W = self._object_points()
        for sensor in dict.fromkeys(z.sensor for z in observations if isinstance(z, LineObservation)):
            T_SW = pose.compose(gtsam.Pose3(self._sensor_T(sensor))).inverse().matrix()
            seps = [z.position for z in observations if isinstance(z, PointObservation) and z.sensor == sensor]
            seps = np.vstack([np.array(seps).reshape(-1, 3), objects_W @ T_SW[:3, :3].T + T_SW[:3, 3]])
            out += merge_collinear(
                [z for z in observations if isinstance(z, LineObservation) and z.sensor == sensor],
                self.assoc.merge_angle_rad,
                self.assoc.merge_distance_m,
                separators=seps,
                separator_radius=self.assoc.inline_object_radius_m,
            )
        return out

    def _mapped_object_points(self) -> np.ndarray:
        """Mapped objects in {W} (N×3), from the cached spheres (an object's centre is its estimate;
        rows of landmarks that left the map are at infinity), in map order: numpy, not a loop."""
        n = len(self._sphere_ids)
        c = self._sphere_c[:n]
        return c[self._sphere_obj[:n] & np.isfinite(c[:, 0])]

    def _object_points(self) -> np.ndarray:
        """Mapped and tentative objects in {W} (N×3): the in-line parts that separate collinear pipes."""
        mapped = self._mapped_object_points()
        tentative = [tr.world[-1] for tr in self.tracks if tr.kind == "object" and tr.world]
        return np.vstack([mapped, np.array(tentative).reshape(-1, 3)]) if tentative else mapped.copy()

    def _is_ambiguous(self, z) -> bool:
        return any(self._current_obs[i] is z for i in self._ambiguous)

    def _promote(self, tr: Track, factors: list, values: gtsam.Values, pose_cov: np.ndarray) -> None:
        """A track becomes a landmark: initial value from its observations, re-expressed with the
        current keyframe estimates, and one factor per observation."""
        lid = self._next_id
        self._next_id += 1
        key = KEY_OF_KIND[tr.kind](lid)
        lm = Landmark(lid, tr.kind, key, model=tr.model)
        records = [
            r for r in tr.records if r.keyframe >= self.window.first_active
        ]  # views from keyframes that left: dropped
        poses = {r.keyframe: self.keyframes.pose_of(r.keyframe) for r in records}
        Ts = [self._sensor_T(r.observation.sensor) for r in records]
        if tr.kind == "object":
            pts = np.array(
                [
                    poses[r.keyframe].compose(gtsam.Pose3(T)).transformFrom(r.observation.position)
                    for r, T in zip(records, Ts)
                ]
            )
            lm.estimate = pts.mean(axis=0)
            values.insert(key, lm.estimate)
        elif tr.kind == "pipe":
            ends = np.vstack(
                [
                    [
                        poses[r.keyframe].compose(gtsam.Pose3(T)).transformFrom(e)
                        for e in (r.observation.p, r.observation.q)
                    ]
                    for r, T in zip(records, Ts)
                ]
            )
            c = ends.mean(axis=0)
            _, _, vt = np.linalg.svd(ends - c)
            d = vt[0]
            lm.anchor = LineAnchor.from_points(c - d, c + d)
            lm.estimate = np.zeros(4)
            lm.extent = PipeExtent()
            values.insert(key, lm.estimate)
        else:
            r, T = records[-1], Ts[-1]
            lm.estimate = poses[r.keyframe].compose(gtsam.Pose3(T @ r.observation.pose))
            values.insert(key, lm.estimate)
        self.landmarks[lid] = lm
        for r, T in zip(records, Ts):
            factors.append((self._landmark_factor(lm, r.keyframe, r.observation, T, poses[r.keyframe]), lid))
            self._record(lm, r.stamp, r.keyframe, r.observation, poses[r.keyframe], T, pose_cov)
        self._update_sphere(lm)

    def _landmark_value(self, lm: Landmark):
        """A landmark's current estimate: iSAM2's in the window, else the frozen one."""
        return self.session.value(lm.key) if lm.active else lm.estimate

    def _purge_tracks(self, stamp: int) -> None:
        horizon = stamp - int(self.assoc.track_timeout_s * 1e9)
        self.tracks = [t for t in self.tracks if t.last_stamp >= horizon]

    def _spheres(self) -> tuple[list[int], np.ndarray, np.ndarray]:
        n = len(self._sphere_ids)
        return self._sphere_ids, self._sphere_c[:n], self._sphere_r[:n]

    def _update_sphere(self, lm: Landmark) -> None:
        if lm.kind == "pipe":
            a, b = _pipe_ends(lm)
            c, r = 0.5 * (a + b), 0.5 * float(np.linalg.norm(b - a))
        else:
            c, r = _landmark_point(lm), 0.0
        row = self._sphere_row.get(lm.id)
        if row is None:
            row = len(self._sphere_ids)
            if row >= len(self._sphere_r):  # amortised growth
                self._sphere_c = np.vstack([self._sphere_c, np.zeros((max(64, row), 3))])
                self._sphere_r = np.concatenate([self._sphere_r, np.zeros(max(64, row))])
                self._sphere_obj = np.concatenate([self._sphere_obj, np.zeros(max(64, row), bool)])
            self._sphere_row[lm.id] = row
            self._sphere_ids.append(lm.id)
        self._sphere_c[row], self._sphere_r[row], self._sphere_obj[row] = c, r, lm.kind == "object"

    def _refresh_landmarks(self, ids, covariance: bool = False) -> None:
        """Current estimates of the landmarks and, with ``covariance``, their gating covariances.

        A landmark's gating covariance is the inverse of the information its own observations
        carry, each with the pose uncertainty of its keyframe folded into the noise (no iSAM2
        marginal: in a map seen from everywhere those cost up to a fraction of a second each).
        It ignores the pose–landmark correlation, like the association problem does; both make the
        innovation covariance larger, never smaller, than the joint one in practice.
        """
        for lid in ids:
            lm = self.landmarks.get(lid)
            if lm is None:
                continue
            lm.estimate = self._landmark_value(lm)
            self._update_sphere(lm)
            if covariance and lm.cov_stamp is None:
                lm.cov_stamp = self.keyframes.stamps[-1]
                lm.covariance = lm.information_covariance()
                ev = np.linalg.eigvalsh(lm.covariance)
                self._volume.setdefault(lid, []).append(
                    (self.keyframes.stamps[-1], float(np.sum(np.log(np.maximum(ev, 1e-300)))))
                )

    # ------------------------------------------------------------------ views and results
    def landmark_estimates(
        self, covariance: bool = True, values: gtsam.Values | None = None, marginals=None
    ) -> list[LandmarkEstimate]:
        out = []
        covs = self._landmark_marginals(marginals) if covariance else {}
        mapped = self._mapped_object_points()
        for lm in self.landmarks.values():
            est = value_of(values, lm.key) if values is not None else self._landmark_value(lm)
            cov = covs.get(lm.id)
            le = LandmarkEstimate(id=lm.id, kind=lm.kind, n_observations=self.book.n_views(lm.id), model=lm.model)
            if lm.kind == "object":
                le.position, le.covariance = np.asarray(est, float), cov
                le.class_posterior = self.book.class_posterior(lm.id)
            elif lm.kind == "pipe":
                c, d = lm.line(est)
                le.p, le.q = lm.extent.ends(c, d, mapped, self.assoc.inline_object_radius_m)
                le.covariance = cov
            else:
                le.pose, le.covariance = est.matrix(), cov
                le.position = est.translation()
            le.connected = tuple(sorted(lm.connected))
            out.append(le)
        return out

    def _landmark_marginals(self, marginals) -> dict[int, np.ndarray]:
        """Marginal covariance of every landmark, by id."""
        covs = self.session.joint_blocks(marginals, [lm.key for lm in self.landmarks.values()])
        return {lm.id: covs[lm.key] for lm in self.landmarks.values() if lm.key in covs}

    def finish(self) -> EstimatorResult:
        n = len(self.keyframes)
        history: dict = {
            "update_kinds": list(self.update_kinds),
            "n_keyframes": n,
            "window_slides": list(self.window.slides),
            "window_returns": self.window.returns,
        }
        if n == 0:
            self.diagnostics.append("no keyframe: the mission had no AHRS (or no start pose)")
            empty = Trajectory(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 4)))
            return EstimatorResult(self.name, empty, diagnostics=list(self.diagnostics))
        values = final_values(self.session, self.window, self.cfg, self.batch, history)
        marginals = self.session.marginals(values) if self.cfg.covariance_in_result else None
        landmarks = self.landmark_estimates(self.cfg.covariance_in_result, values, marginals)
        self.book.connect(landmarks, self.assoc.merge_distance_m)
        history["landmark_kind"] = {lm.id: lm.kind for lm in self.landmarks.values()}
        history["landmark_volume"] = {
            lid: (np.array([s for s, _ in v], np.int64), np.array([x for _, x in v])) for lid, v in self._volume.items()
        }
        history.update(self.book.history(self.landmarks))
        return EstimatorResult(
            name=self.name,
            trajectory=keyframe_trajectory(self.keyframes.stamps, values, marginals, self.session, self.cfg),
            landmarks=landmarks,
            online_trajectory=online_trajectory(self.keyframes.online),
            update_times_s=np.array(self.update_times),
            update_n_landmarks=np.array(self.update_n_landmarks, int),
            history=history,
            diagnostics=list(self.diagnostics),
        )


# ---------------------------------------------------------------------------------------------


def _observation_information(lm: Landmark, z, pose: gtsam.Pose3, pose_cov: np.ndarray, T_BS: np.ndarray) -> np.ndarray:
    """Information H_lᵀ (R + H_x P H_xᵀ)⁻¹ H_l that one observation carries on the landmark's
    parameters, with the keyframe pose uncertainty P folded into the noise."""
    if lm.kind == "object":
        _, H_x, H_l = point_residual(pose, lm.estimate, T_BS, z.position, jac=True)
        R = z.covariance
    elif lm.kind == "pipe":
        _, H_x, H_l = line_residual(pose, lm.estimate, lm.anchor, T_BS, z.p, z.q, jac=True)
        R = line_observation_covariance(pose, lm.estimate, lm.anchor, T_BS, z.covariance)
    else:
        _, H_x, H_l = structure_residual(pose, lm.estimate, T_BS, z.pose, jac=True)
        R = z.covariance
    return _information(H_x, H_l, R, pose_cov)


def _information(H_x: np.ndarray, H_l: np.ndarray, R: np.ndarray, pose_cov: np.ndarray) -> np.ndarray:
    """H_lᵀ (R + H_x P H_xᵀ)⁻¹ H_l."""
    S = R + H_x @ pose_cov @ H_x.T
    return H_l.T @ np.linalg.solve(S, H_l)


def _landmark_point(lm: Landmark) -> np.ndarray:
    if lm.kind == "object":
        return np.asarray(lm.estimate, float)
    if lm.kind == "pipe":
        return np.mean(_pipe_ends(lm), axis=0)
    return lm.estimate.translation()


def _pipe_ends(lm: Landmark) -> tuple[np.ndarray, np.ndarray]:
    """The extreme ends seen of a pipe, on its current line."""
    c, d = lm.line()
    lo, hi = lm.extent.outer(c, d)
    return c + lo * d, c + hi * d
