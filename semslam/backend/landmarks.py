"""The graph back-end's landmarks: object points L(id), pipe lines P(id) (4-vector, anchored chart) and
structures S(id) (Pose3) as iSAM2 variables with robust factors, and what the shared map building
(:mod:`semslam.mapping.builder`) asks of them: the pairs a batch of observations could make with them,
their update, their initialisation from a tentative landmark, and the merge of one mapped twice.

A landmark's gating covariance is the inverse of the information its own observations carry, each with
the pose uncertainty of its keyframe folded into the noise (no iSAM2 marginal: in a map seen from
everywhere those cost up to a fraction of a second each). It ignores the pose–landmark correlation,
like the association problem does, which makes the innovation covariance larger than the joint one.

That pose uncertainty is taken relative to the map (:class:`GaugeFreeCovariance`): what the vehicle's
pose had accumulated when the first landmark was mapped (a tank mission starts up to ~30 s without DVL
at the surface) moves the whole map with it and is common to the pose and every landmark; folded into
both sides of every gate it made every observation compatible with every landmark within the pre-gate,
hence "ambiguous": the graph mapped 3 of tank seed 1's 11 objects. The absolute information is kept
for the prior of a landmark that re-enters the window.

The views of the tentative landmarks (:meth:`GraphLandmarks.place`) carry the pose's absolute
uncertainty split in two (:func:`semslam.mapping.tracks.split_pose_covariance`): the part of its
drifting components (yaw, north, east, in the world-aligned frame), of which a track counts only what
accumulated between two of its views, and that of its absolutely measured ones (roll, pitch, depth),
independent from view to view. With the whole absolute uncertainty (0.10 m at 4 s, 0.19 m at 16 s
under the start at rest), views of two objects one lattice spacing (0.45 m) apart made one track,
whose views, a factor each at its own keyframe, bent the trajectory onto the wrong object (tank
world 79); taken relative to the map's first view in all six components (stop 36), the depth's
noise cancelled as if it were common and the right object's view failed its track for 3.5 cm of
depth (tank world 10). The tracks also test a scan's continuations jointly, with the drift common to
the scan's views (:class:`semslam.mapping.tracks.TrackSet`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache

import gtsam
import numpy as np

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
from semslam.backend.problem import Candidate, GraphAssociationProblem, possible_pairs
from semslam.backend.session import IsamSession, Owned
from semslam.backend.window import SlidingWindow, X, value_of
from semslam.config import SemslamConfig
from semslam.estimation import LandmarkEstimate, SpillLog
from semslam.mapping.association import (
    Candidates,
    LowRankJoint,
    PairLinearization,
    chi2_gate,
    indices_by_shape,
    inv_small,
    uncorrelated_candidates,
)
from semslam.mapping.book import LandmarkBook
from semslam.mapping.builder import Scan
from semslam.mapping.fittings import port_depths
from semslam.mapping.pipes import point_segment_distance
from semslam.mapping.tracks import Track, split_pose_covariance
from semslam.mission.mission import MissionMetadata
from semslam.observations import LineObservation, Observation, PointObservation

KEY_OF_KIND = {
    "object": gtsam.symbol_shorthand.L,
    "pipe": gtsam.symbol_shorthand.P,
    "structure": gtsam.symbol_shorthand.S,
}
DIM_OF_KIND = {"object": 3, "pipe": 4, "structure": 6}
DRIFTING = (2, 3, 4)  # the world-aligned pose tangent's yaw, north and east: no sensor holds them absolutely


class VolumeLog:
    """Every landmark's uncertainty volume (log det of its covariance) at each refresh, on disk
    (:class:`SpillLog`, 24 bytes a refresh): a survey refreshes its landmarks for hours.
    :meth:`items` gives each landmark's (stamp, log det) pairs, landmarks in the order first logged."""

    def __init__(self):
        self._rows = SpillLog([("lid", "<i8"), ("stamp", "<i8"), ("value", "<f8")])
        self._removed: set[int] = set()

    def append(self, lid: int, stamp: int, value: float) -> None:
        self._rows.append(lid, stamp, value)

    def pop(self, lid: int) -> None:
        """Forget ``lid``'s history (a landmark removed; ids are never given again)."""
        self._removed.add(lid)

    def items(self) -> list[tuple[int, list[tuple[int, float]]]]:
        rows = self._rows.array()
        order = np.argsort(rows["lid"], kind="stable")  # each landmark's rows together, in the order logged
        rows = rows[order]
        ids, first = np.unique(rows["lid"], return_index=True)
        groups = np.split(rows, first[1:])
        out = []
        for k in np.argsort(order[first]):  # the landmarks in the order first logged
            lid = int(ids[k])
            if lid not in self._removed:
                out.append((lid, list(zip(groups[k]["stamp"].tolist(), groups[k]["value"].tolist()))))
        return out


@dataclass
class Landmark:
    """A mapped landmark. ``key`` is its gtsam key; lines carry their fixed chart ``anchor``."""

    id: int
    kind: str  # object | pipe | structure
    key: int
    anchor: LineAnchor | None = None
    model: str | None = None
    estimate: object = None  # Point3 (3,), θ (4,), or gtsam.Pose3
    covariance: np.ndarray | None = None  # gating covariance (see ``information_covariance``)
    cov_stamp: int | None = None  # when ``covariance`` was last computed (None: new information since)
    information: np.ndarray | None = None  # Σ information of its observations on its parameters
    gate_information: np.ndarray | None = None  # the same with the pose uncertainty relative to the map
    active: bool = True  # in the smoother's window; False: marginalised out, ``estimate`` frozen
    # the inverses of ``information`` and ``gate_information`` until either changes (the duplicate
    # test asks for every pair of objects after every scan: ~190 pairs in the tank)
    _inverse: dict = field(default_factory=dict, repr=False)
    _line: tuple | None = field(default=None, repr=False)  # (θ's bytes, (point, direction)): see :meth:`line`
    _ends: tuple | None = field(default=None, repr=False)  # (θ's bytes, extent, its views, ends): :func:`_pipe_ends`

    def add_information(self, info: np.ndarray, gate_info: np.ndarray) -> None:
        self.information = info if self.information is None else self.information + info
        self.gate_information = gate_info if self.gate_information is None else self.gate_information + gate_info
        self.cov_stamp = None
        self._inverse.clear()

    def information_covariance(self, gate: bool = False) -> np.ndarray:
        """Inverse of the accumulated information (``gate``: with the pose relative to the map; a tiny
        ridge keeps it finite). Read-only: shared until the information changes."""
        cov = self._inverse.get(gate)
        if cov is None:
            n = DIM_OF_KIND[self.kind]
            info = self.gate_information if gate else self.information
            cov = np.linalg.inv((np.zeros((n, n)) if info is None else info) + _ridge(n))
            cov.flags.writeable = False
            self._inverse[gate] = cov
        return cov

    def line(self, estimate=None) -> tuple[np.ndarray, np.ndarray]:
        """A pipe's line (point, unit direction) at ``estimate`` (default: its current one). The last
        one is kept by the exact numbers of θ (asked for many times between two updates: the map
        building's pre-gates, pipe rules and duplicate tests). Read-only: shared."""
        theta = self.estimate if estimate is None else estimate
        key = np.asarray(theta, float).tobytes()
        last = self._line
        if last is not None and last[0] == key:
            return last[1]
        c, d = self.anchor.point(theta), self.anchor.direction(theta)
        c.flags.writeable = False
        self._line = (key, (c, d))
        return c, d


class GaugeFreeCovariance:
    """A pose covariance (6×6, GTSAM's body-frame tangent: rotation, translation) relative to the map:
    less what it had when the map was started (:meth:`start`), in the world-aligned frame, clipped to
    stay positive (semi)definite. Before that, the pose's own. Where a later pose is surer than that
    common part (the first DVL velocities after the descent), the common part shrinks to it: never more
    certain relative to the map than absolutely."""

    FLOOR = 1e-10

    def __init__(self):
        self.gauge: np.ndarray | None = None  # world-aligned pose covariance when the map started

    @staticmethod
    def _world(R: np.ndarray) -> np.ndarray:
        return np.kron(np.eye(2), R)

    def start(self, pose: gtsam.Pose3, cov: np.ndarray) -> None:
        if self.gauge is None:
            B = self._world(pose.rotation().matrix())
            self.gauge = B @ cov @ B.T

    def relative(self, pose: gtsam.Pose3, cov: np.ndarray) -> np.ndarray:
        if self.gauge is None:
            return cov
        B = self._world(pose.rotation().matrix())
        d = B @ cov @ B.T - self.gauge
        w, V = np.linalg.eigh(0.5 * (d + d.T))
        if w.min() < 0:  # the pose is surer than the map's common part (the DVL back after the descent)
            self.gauge += (V * np.minimum(w, 0.0)) @ V.T  # the common part shrinks with it
        return B.T @ (V * np.maximum(w, self.FLOOR)) @ V.T @ B


class GraphLandmarks:
    """The graph's landmarks (:class:`semslam.mapping.builder.LandmarkState`). A batch of observations
    runs between :meth:`begin` (its keyframe and pose) and :meth:`settle` (one iSAM2 update with
    every factor of the batch)."""

    def __init__(
        self,
        metadata: MissionMetadata,
        config: SemslamConfig,
        session: IsamSession,
        keyframes: Keyframes,
        window: SlidingWindow,
        book: LandmarkBook,
        diagnostics: list[str],
    ):
        self.metadata = metadata
        self.assoc = config.association
        self.robust = robust_kernel(config.graph.robust_kernel, config.graph.robust_k)
        self.session = session
        self.keyframes = keyframes
        self.window = window
        self.book = book
        self.diagnostics = diagnostics
        self.landmarks: dict[int, Landmark] = {}
        self._next_id = 0
        self.volume = VolumeLog()  # landmark id → (stamp, log det cov) at each refresh
        # Bounding sphere (centre, radius) of every landmark, refreshed with its estimate.
        self._sphere_row: dict[int, int] = {}
        self._sphere_ids: list[int] = []
        self._sphere_c = np.zeros((0, 3))
        self._sphere_r = np.zeros(0)
        self._sphere_obj = np.zeros(0, bool)  # the row is an object landmark (its centre is its point)
        # the batch under way
        self._k = 0
        self._pose = gtsam.Pose3()
        self._pose_cov = np.eye(6)  # relative to the map (gating)
        self._abs_pose_cov = np.eye(6)
        self.gauge = GaugeFreeCovariance()  # started by the first landmark
        self._factors: list[Owned] = []
        self._priors: list[Owned] = []
        self._values = gtsam.Values()

    def __len__(self) -> int:
        return len(self.landmarks)

    # ------------------------------------------------------------------ the batch
    def begin(self, k: int, factors: list[Owned] = ()) -> None:
        """A batch observed at keyframe k; ``factors`` (e.g. odometry) go into its iSAM2 update."""
        self._k = k
        self._pose, self._abs_pose_cov = self.keyframes.pose_and_cov(k)
        self._pose_cov = self.gauge.relative(self._pose, self._abs_pose_cov)
        self._factors = list(factors)
        self._priors = []
        self._values = gtsam.Values()

    def settle(self) -> None:
        """One iSAM2 update with the batch's factors and new variables; the estimates refreshed."""
        if not self._factors and not self._values.size():
            return
        self._commit(self._factors, self._values, self._priors)
        self.keyframes.refresh()
        self.keyframes.renew_online(self._k)
        self.refresh({o for _, o in self._factors if o is not None})
        self._factors, self._priors, self._values = [], [], gtsam.Values()

    def _commit(self, factors: list[Owned], values: gtsam.Values, priors: list[Owned] = ()) -> bool:
        """Commit to iSAM2; after a failure the landmarks created in the failed update disappear and
        those that were coming back stay out of the window. False if something was dropped."""
        stamp = self.keyframes.stamps[-1]
        dropped = self.session.commit(factors, values, self.keyframes.anchor(), priors, stamp)
        if dropped is None:
            return True
        for lid in dropped:
            if lid in self.landmarks and not self.session.owns(lid):
                self._remove(lid)
        keep = self.session.window_keys()
        for lm in self.landmarks.values():
            lm.active = lm.key in keep
        return False

    def _remove(self, lid: int) -> None:
        del self.landmarks[lid]
        row = self._sphere_row.pop(lid, None)
        if row is not None:
            self._sphere_c[row] = np.inf  # never near again
        self.volume.pop(lid)

    # ------------------------------------------------------------------ for the map building
    def usable(self, z: Observation) -> bool:
        return True

    def sensor_pose(self, sensor: str) -> np.ndarray:
        return self._pose.compose(gtsam.Pose3(self.metadata.extrinsic(sensor))).matrix()

    def place(self, z: Observation) -> tuple:
        """An observation in {W} with the batch's keyframe as estimated now (point: (3,), pipe: (2, 3),
        structure: 4×4); for points and structures, its position's covariance from the observation and
        the pose's absolutely measured components; the keyframe, for the landmark's factors; the
        position's Jacobian in the world-aligned pose tangent and the covariance of the pose's
        drifting components there (see the module)."""
        T_BS = self.metadata.extrinsic(z.sensor)
        pose = self.keyframes.pose_of(self._k)
        T_WS = pose.compose(gtsam.Pose3(T_BS))
        R = pose.rotation().matrix()
        if isinstance(z, LineObservation):
            return np.vstack([T_WS.transformFrom(z.p), T_WS.transformFrom(z.q)]), None, self._k, None, None
        if isinstance(z, PointObservation):
            w, p_S, C_S = T_WS.transformFrom(z.position), z.position, z.covariance
        else:
            w, p_S, C_S = T_WS.compose(gtsam.Pose3(z.pose)).matrix(), z.pose[:3, 3], z.covariance[3:, 3:]
        e_B = T_BS[:3, :3] @ p_S + T_BS[:3, 3]
        B = GaugeFreeCovariance._world(R)
        J_W = pose_point_jacobian(R, e_B) @ B.T  # the world-aligned pose tangent: rotation, translation
        drifting, measured = split_pose_covariance(B @ self._abs_pose_cov @ B.T, DRIFTING)
        C = R @ T_BS[:3, :3] @ C_S @ T_BS[:3, :3].T @ R.T + J_W @ measured @ J_W.T
        return w, C, self._k, J_W, drifting

    def objects(self) -> tuple[list[int], np.ndarray]:
        """Mapped objects and their positions (N×3, {W}), from the cached spheres (an object's centre
        is its estimate; rows of landmarks that left the map are at infinity): numpy, not a loop."""
        n = len(self._sphere_ids)
        c = self._sphere_c[:n]
        rows = np.flatnonzero(self._sphere_obj[:n] & np.isfinite(c[:, 0]))
        return [self._sphere_ids[r] for r in rows], c[rows]

    def pipes(self) -> list[tuple[int, np.ndarray, np.ndarray]]:
        return [(lm.id, *lm.line()) for lm in self.landmarks.values() if lm.kind == "pipe"]

    def candidates(
        self, observations: list[Observation], confidence: float, scan: Scan
    ) -> tuple[Candidates, list[int]]:
        """The pairs individually compatible at ``confidence``, among the landmarks the coarse pre-gates
        keep: the cached bounding spheres (O(map) in numpy only, so the cost stays flat), then
        ``association.pre_gate_m`` and a conservative bound of the χ² gate (``possible_pairs``)."""
        none = Candidates.empty(len(observations))
        if not self.landmarks:
            return none, []
        T_BS = [self.metadata.extrinsic(z.sensor) for z in observations]
        pose, pose_cov = self._pose, self._pose_cov
        obs_pts = np.array([_summary(z, pose, T) for z, T in zip(observations, T_BS)])
        ids, centres, radii = self._spheres()
        dist = np.linalg.norm(obs_pts[:, None, :] - centres[None, :, :], axis=2) - radii[None, :]
        near = np.flatnonzero((dist <= self.assoc.pre_gate_m + 1.0).any(axis=0))
        if near.size == 0:
            return none, []
        cand_lms = [self.landmarks[ids[j]] for j in near if ids[j] in self.landmarks]
        self.refresh({lm.id for lm in cand_lms}, covariance=True)
        dist = np.empty((len(obs_pts), len(cand_lms)))
        for j, lm in enumerate(cand_lms):
            if lm.kind == "pipe":
                dist[:, j] = point_segment_distance(obs_pts, *_pipe_ends(lm, self.book))
            else:
                dist[:, j] = np.linalg.norm(obs_pts - _point(lm), axis=1)
        cands = [Candidate(lm, lm.covariance) for lm in cand_lms]
        gates = {d: chi2_gate(confidence, d) for d in (3, 4)}
        allowed = (dist <= self.assoc.pre_gate_m) & possible_pairs(pose, pose_cov, observations, T_BS, cands, gates)
        problem = GraphAssociationProblem(pose, observations, T_BS, cands, allowed, scan)
        pairs = problem.pairs()
        found = uncorrelated_candidates(
            len(observations), [t for t in pairs if t[2] is not None], pose_cov, problem.landmark_covariance, confidence
        )
        # the scan's pipe rules after the gate: they cost more than a linearisation, and most pairs fail the gate
        found = found.subset(np.flatnonzero(~problem.excluded_all(found.obs, found.lm)))
        self._problem = problem
        return found, [lm.id for lm in cand_lms]

    def joint(self, found: Candidates) -> LowRankJoint:
        return LowRankJoint(found, self._pose_cov, self._problem.landmark_covariance)

    def update(self, paired: list[tuple[Observation, int, PairLinearization]]) -> None:
        """A factor for each pairing (a landmark that had left the window comes back with a prior),
        and the information it carries on the landmark."""
        infos = _informations([lin for _, _, lin in paired], self._abs_pose_cov, self._pose_cov)
        for (z, lid, lin), info in zip(paired, infos):
            lm = self.landmarks[lid]
            if not lm.active:
                self._reactivate(lm)
            T_BS = self.metadata.extrinsic(z.sensor)
            self._factors.append((self._factor(lm, self._k, z, T_BS, self._pose, lin), lm.id))
            lm.add_information(*info)

    def _reactivate(self, lm: Landmark) -> None:
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
        self._priors.append((prior, lm.id))
        self._values.insert(lm.key, lm.estimate)

    def promote(self, track: Track) -> int:
        """A tentative landmark enters the graph: its initial value from its views re-expressed with
        the current keyframe estimates (views from keyframes that left the window are dropped), and
        one factor per view."""
        if self.gauge.gauge is None:  # the first landmark: what the pose has accumulated so far moves the map
            self.gauge.start(self._pose, self._abs_pose_cov)
            self._pose_cov = self.gauge.relative(self._pose, self._abs_pose_cov)
        lid = self._next_id
        self._next_id += 1
        key = KEY_OF_KIND[track.kind](lid)
        lm = Landmark(lid, track.kind, key, model=track.model)
        views = [v for v in track.views if v.payload >= self.window.first_active]
        poses = {v.payload: self.keyframes.pose_of(v.payload) for v in views}
        Ts = [self.metadata.extrinsic(v.z.sensor) for v in views]
        T_WS = [poses[v.payload].compose(gtsam.Pose3(T)) for v, T in zip(views, Ts)]
        if track.kind == "object":
            lm.estimate = np.array([T.transformFrom(v.z.position) for v, T in zip(views, T_WS)]).mean(axis=0)
        elif track.kind == "pipe":
            ends = np.vstack([[T.transformFrom(e) for e in (v.z.p, v.z.q)] for v, T in zip(views, T_WS)])
            c = ends.mean(axis=0)
            _, _, vt = np.linalg.svd(ends - c)
            lm.anchor = LineAnchor.from_points(c - vt[0], c + vt[0])
            lm.estimate = np.zeros(4)
        else:
            lm.estimate = T_WS[-1].compose(gtsam.Pose3(views[-1].z.pose))
        self._values.insert(key, lm.estimate)
        self.landmarks[lid] = lm
        for v, T in zip(views, Ts):
            pose = poses[v.payload]
            self._factors.append((self._factor(lm, v.payload, v.z, T, pose), lid))
            lm.add_information(
                _observation_information(lm, v.z, pose, self._abs_pose_cov, T),
                _observation_information(lm, v.z, pose, self._pose_cov, T),
            )
        return lid

    def _factor(self, lm: Landmark, k: int, z, T_BS, pose: gtsam.Pose3, lin: PairLinearization | None = None):
        """The factor of observation z of landmark lm at keyframe k (``lin``: the pairing's
        linearisation at (pose, lm.estimate), when the association has it)."""
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

    def difference_nis(self, a: int, b: int) -> float | None:
        """Objects: the χ² of their difference with their gating covariances (the correlation between
        them ignored, which only overstates it). Pipes: None (no test between two anchored charts)."""
        la, lb = self.landmarks[a], self.landmarks[b]
        if la.kind != "object" or lb.kind != "object" or not lb.active:
            return None
        d = np.asarray(la.estimate, float) - np.asarray(lb.estimate, float)
        S = la.information_covariance(gate=True) + lb.information_covariance(gate=True)
        return float(d @ inv_small(S) @ d)  # closed form: asked of every object pair after every scan

    def gating_spread(self, ids: list[int]) -> np.ndarray:
        """√trace of each object's gating covariance (the one :meth:`difference_nis` adds up)."""
        traces = np.empty(len(ids))
        for n, lid in enumerate(ids):  # kept with the inverse until the information changes
            inverse = self.landmarks[lid]._inverse
            t = inverse.get("trace")
            if t is None:
                t = inverse["trace"] = np.trace(self.landmarks[lid].information_covariance(gate=True))
            traces[n] = t
        return np.sqrt(traces)

    def merge(self, keep: int, drop: int, constrain: bool) -> None:
        """``drop`` leaves the map; with ``constrain`` (objects) it is first tied to ``keep`` by a stiff
        zero-offset factor. An unconstrained one stays in the graph with its factors, unmapped."""
        lk, ld = self.landmarks[keep], self.landmarks[drop]
        if ld.information is not None:
            lk.add_information(ld.information, ld.gate_information)
        self._remove(drop)
        if constrain and lk.kind == "object":
            tie = gtsam.BetweenFactorPoint3(lk.key, ld.key, np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 1e-3))
            self._commit([(tie, keep)], gtsam.Values())
            self.refresh({keep})

    # ------------------------------------------------------------------ estimates
    def left_window(self, drop: set[int], estimate: gtsam.Values) -> None:
        """The landmarks whose keys left the smoothing window keep their estimate then, frozen."""
        for lm in self.landmarks.values():
            if lm.active and lm.key in drop:
                lm.active, lm.estimate = False, value_of(estimate, lm.key)
                self._update_sphere(lm)

    def value(self, lm: Landmark):
        """A landmark's current estimate: iSAM2's in the window, else the frozen one."""
        return self.session.value(lm.key) if lm.active else lm.estimate

    def refresh(self, ids, covariance: bool = False) -> None:
        """Current estimates of the landmarks and, with ``covariance``, their gating covariances."""
        fresh: list[Landmark] = []
        for lid in ids:
            lm = self.landmarks.get(lid)
            if lm is None:
                continue
            lm.estimate = self.value(lm)
            self._update_sphere(lm)
            if covariance and lm.cov_stamp is None:
                fresh.append(lm)
        if not fresh:
            return
        # new gating covariances and their volumes, the landmarks of one size at once (stacked
        # inverses and eigenvalues: LAPACK matrix by matrix, the numbers of one alone)
        stamp = self.keyframes.stamps[-1]
        by_kind: dict[str, list[Landmark]] = {}
        for lm in fresh:
            by_kind.setdefault(lm.kind, []).append(lm)
        volume = {}
        for kind, lms in by_kind.items():
            todo = [lm for lm in lms if True not in lm._inverse]
            if todo:
                n = DIM_OF_KIND[kind]
                info = np.array(
                    [np.zeros((n, n)) if lm.gate_information is None else lm.gate_information for lm in todo]
                )
                for lm, cov in zip(todo, np.linalg.inv(info + _ridge(n))):
                    cov.flags.writeable = False
                    lm._inverse[True] = cov
            logs = np.log(np.maximum(np.linalg.eigvalsh(np.array([lm._inverse[True] for lm in lms])), 1e-300))
            volume.update((lm.id, float(np.sum(row))) for lm, row in zip(lms, logs))
        for lm in fresh:
            lm.cov_stamp = stamp
            lm.covariance = lm.information_covariance(gate=True)
            self.volume.append(lm.id, stamp, volume[lm.id])

    def _spheres(self) -> tuple[list[int], np.ndarray, np.ndarray]:
        n = len(self._sphere_ids)
        return self._sphere_ids, self._sphere_c[:n], self._sphere_r[:n]

    def _update_sphere(self, lm: Landmark) -> None:
        if lm.kind == "pipe":
            a, b = _pipe_ends(lm, self.book)
            c, r = 0.5 * (a + b), 0.5 * float(np.linalg.norm(b - a))
        else:
            c, r = _point(lm), 0.0
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

    def estimates(
        self, covariance: bool = True, values: gtsam.Values | None = None, marginals=None, known=None
    ) -> list[LandmarkEstimate]:
        """The map with global ids: the current estimates, or those in ``values``; with ``covariance``
        the marginal covariances (those in ``known`` as given, else from ``marginals``, else iSAM2's)."""
        out = []
        covs = {}
        if covariance:
            blocks = self.session.joint_blocks(marginals, [lm.key for lm in self.landmarks.values()], known=known)
            covs = {lm.id: blocks[lm.key] for lm in self.landmarks.values() if lm.key in blocks}
        ids, mapped = self.objects()
        depths = port_depths([self.book.class_posterior(i) for i in ids])
        for lm in self.landmarks.values():
            est = value_of(values, lm.key) if values is not None else self.value(lm)
            le = LandmarkEstimate(
                id=lm.id,
                kind=lm.kind,
                n_observations=self.book.n_views(lm.id),
                model=lm.model,
                covariance=covs.get(lm.id),
            )
            if lm.kind == "object":
                le.position = np.asarray(est, float)
                le.class_posterior = self.book.class_posterior(lm.id)
            elif lm.kind == "pipe":
                c, d = lm.line(est)
                le.p, le.q = self.book.extent(lm.id).ends(c, d, mapped, self.assoc.inline_object_radius_m, depths)
            else:
                le.pose, le.position = est.matrix(), est.translation()
            out.append(le)
        return out


@cache
def _ridge(n: int) -> np.ndarray:
    """The tiny ridge that keeps an information's inverse finite (read-only, made once)."""
    r = np.eye(n) * 1e-9
    r.flags.writeable = False
    return r


def _summary(z, pose: gtsam.Pose3, T_BS: np.ndarray) -> np.ndarray:
    """A world point standing for the observation (object / segment midpoint / structure origin)."""
    T_WS = pose.compose(gtsam.Pose3(T_BS))
    if isinstance(z, PointObservation):
        return T_WS.transformFrom(z.position)
    if isinstance(z, LineObservation):
        return T_WS.transformFrom(0.5 * (z.p + z.q))
    return T_WS.transformFrom(z.pose[:3, 3])


def _point(lm: Landmark) -> np.ndarray:
    if lm.kind == "object":
        return np.asarray(lm.estimate, float)
    return lm.estimate.translation()


def _pipe_ends(lm: Landmark, book: LandmarkBook) -> tuple[np.ndarray, np.ndarray]:
    """The extreme ends seen of a pipe, on its current line (kept until the line or the views change:
    the sphere refresh and the candidates' pre-gate of one scan ask for the same)."""
    extent = book.extent(lm.id)
    key = (np.asarray(lm.estimate, float).tobytes(), id(extent), len(extent))
    last = lm._ends
    if last is not None and last[0] == key:
        return last[1]
    c, d = lm.line()
    lo, hi = extent.outer(c, d)
    ends = (c + lo * d, c + hi * d)
    lm._ends = (key, ends)
    return ends


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


def _informations(lins: list[PairLinearization], *pose_covs: np.ndarray) -> list[tuple[np.ndarray, ...]]:
    """:func:`_information` of each pairing's linearisation with each of ``pose_covs``, the pairings of
    one shape at once: stacked products and solves, which numpy evaluates matrix by matrix with the
    same BLAS / LAPACK calls as one alone (the same numbers to the bit, without the per-call overheads)."""
    out: list = [None] * len(lins)
    for ks in indices_by_shape(lins):
        H_x = np.array([lins[k].H_x for k in ks], float)
        H_l = np.array([lins[k].H_l for k in ks], float)
        R = np.array([lins[k].R for k in ks], float)
        per_cov = []
        for P in pose_covs:
            try:
                per_cov.append(H_l.transpose(0, 2, 1) @ np.linalg.solve(R + H_x @ P @ H_x.transpose(0, 2, 1), H_l))
            except np.linalg.LinAlgError:  # raised as one pair alone would
                per_cov.append([_information(lins[k].H_x, lins[k].H_l, lins[k].R, P) for k in ks])
        for n, k in enumerate(ks):
            out[k] = tuple(np.array(c[n]) for c in per_cov)
    return out
