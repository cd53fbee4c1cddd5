"""Tentative landmarks (Himri et al. 2018: a landmark enters the map only after consistent repeated
observations). A scan's unpaired observations continue tracks or start new ones; a track seen
``association.min_observations`` times is promoted (each estimator then initialises the landmark in
its own state; the EKF's a pipe only from a view whose own direction is known to
``ekf.pipe_promote_direction_sigma_rad``: it starts a pipe from its latest view and keeps its Jacobians
at that first estimate, so a short, far view a few degrees off is read as vehicle motion for the rest of
the mission); one not seen again within ``association.track_timeout_s`` is forgotten (an object's
place is remembered a while longer: its counts go on, and it keeps collinear pipes apart). An object
must also have been seen in at least ``association.object_view_ratio`` of the scans that had its
place in view since its first view: the scans that saw anything (a mapped or tentative landmark, an
unpaired view) within ``association.object_view_reach_m`` of it, with its place inside the sensor's
view (``association.object_view_margin_m``, :class:`semslam.mapping.visibility.SensorView`: a narrow
camera that sees the pipe short of a valve outside its frame did not have the valve in view). A real
object in view is seen scan after scan; a front-end's false object views, made by a passing
configuration (a pipe detected in part), come in a few of the many scans that see the pipe beside
them.

A scan's views continue tracks one-to-one, by the assignment of least total cost over the scan
(Hungarian), not view by view: in a row of objects 25–35 cm apart with a missed object, the greedy
choice lets each view take its neighbour's track and the shift runs down the row. Objects and
structures continue a track when the Mahalanobis distance of their position to the track's
information-weighted mean passes ``association.track_gate_confidence``; pipe segments when they are
collinear with the track's line by the paper's criterion (``merge_angle_rad``, ``merge_distance_m``),
within ``pipe_extent_gap_m`` of what the track saw (or ``pipe_track_gap_sigmas`` σ of the ends' along-axis
uncertainty, when larger: :func:`~semslam.mapping.extent.track_gap`), with no in-line object between.

A track follows its object as the vehicle's estimate drifts. An estimator may split each view's
covariance into what is independent from view to view (the observation, and the pose's components
measured absolutely: depth by the pressure sensor, roll and pitch by gravity) and what the pose's
drifting components put on it (north, east, yaw: :func:`split_pose_covariance`; the graph does, the
EKF gives its whole covariance as independent). Between two views of a track only the drift the pose
accumulated between their keyframes (the difference of the latter, :meth:`Track.drift_since`)
separates them, so the track is a small filter (:meth:`Track.mean_position`): its position grows by
that drift and takes each view with its independent covariance. And a scan's continuations must be
jointly compatible (:meth:`TrackSet.extend`): its views share one pose, so the drift is common to
them, and one view on a neighbour's track while the others stay on theirs is not. The whole row
shifted by one spacing is jointly compatible, though: so a scan's continuations are committed only
when no alternative assignment that puts a view on another track is nearly as likely
(``association.track_ambiguity_odds``, :meth:`TrackSet._ambiguous`); when one is, the tracks in
doubt are forgotten and the scan's views start tracks of their own.

Before the DVL's bottom lock the drift over one scan interval (2 s) is a third of a lattice spacing of
the tank's objects, over the mission's first ~20 s the lattice spacing itself: a track gated against
a mean of all its views with the pose's accumulated uncertainty joined views of neighbouring objects
(tank world 79), one that took the depth as common with the map's first view rejected the right
object's view for a few centimetres of depth (tank world 10), and without the joint test a view 12 s
after its neighbour's track had last been seen joined it while the scan's other view stayed on its
own (world 79 again; experiments/estimators/README.md, stop 37); and one view's covariance loosened
along its pipe made the row shifted by one spacing the cheaper assignment by 2.3 (world 79 at 16 s,
stop 38): the map then hung on which of two nearly equal assignments was cheaper.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from semslam.config import AssociationConfig
from semslam.mapping.association import chi2_gate
from semslam.mapping.extent import track_gap
from semslam.mapping.pipes import object_between, segment_matches_line
from semslam.mapping.visibility import near_seen
from semslam.observations import LineObservation, Observation, PointObservation, StructureObservation

KIND_OF_OBSERVATION = {PointObservation: "object", LineObservation: "pipe", StructureObservation: "structure"}


@dataclass
class TrackView:
    """One view of a tentative landmark: the observation, where it puts the landmark in {W} with the
    pose of its time (object: (3,); pipe: segment ends (2, 3); structure: T_W,model (4, 4)) and, for
    objects and structures, that position's covariance from what is independent from view to view
    (``cov``: the observation, the pose's depth, roll and pitch), the position's Jacobian ``jac`` in
    the pose's parameters and the covariance of the pose's drifting components (``pose_drift``: north,
    east, yaw, as accumulated at its time; None: none). ``payload``: what the estimator needs to
    initialise the landmark from it (the graph: the keyframe)."""

    stamp: int
    z: Observation
    world: np.ndarray
    cov: np.ndarray | None = None
    payload: Any = None
    jac: np.ndarray | None = None
    pose_drift: np.ndarray | None = None

    def drifted(self, since: np.ndarray | None, other: TrackView | None = None) -> np.ndarray:
        """The covariance the pose's drift from ``since`` (a pose_drift) to this view's keyframe puts on
        this view's position, or, with ``other`` (a view of the same scan), its cross-covariance with
        that view's (the difference of the two pose_drifts clipped to stay positive semidefinite)."""
        if self.pose_drift is None or since is None:
            return np.zeros((3, 3))
        d = self.pose_drift - since
        w, V = np.linalg.eigh(0.5 * (d + d.T))
        J = self.jac if other is None else other.jac
        return self.jac @ (V * np.maximum(w, 0.0)) @ V.T @ J.T

    @property
    def position(self) -> np.ndarray:
        return self.world if self.world.shape == (3,) else self.world[:3, 3]


@dataclass
class Track:
    key: int
    kind: str
    model: str | None = None
    views: list[TrackView] = field(default_factory=list)
    in_view: int = 0  # scans that saw anything within object_view_reach_m of it since its first view
    seen: int = 0  # scans that gave it or another object track at its place a view (:meth:`TrackSet._credit`)
    seen_before: int = 0  # the same of the forgotten tracks at its place (:meth:`TrackSet._inherit`)
    _seen_stamp: int | None = None
    _in_view_stamp: int | None = None
    # the filter over the views (objects, structures): views folded in, mean, covariance
    _folded: int = field(default=0, repr=False)
    _mean: np.ndarray | None = field(default=None, repr=False)
    _cov: np.ndarray | None = field(default=None, repr=False)

    @property
    def last_stamp(self) -> int:
        return self.views[-1].stamp

    def slim(self) -> None:
        """Keep only what a lapsed track's place needs (its mean and covariance, its last view, its
        counts): its views' clouds are not held for the rest of a survey."""
        self.mean_position()
        self.views = self.views[-1:]
        self._folded = len(self.views)

    @property
    def last_drift(self) -> np.ndarray | None:
        """The pose's drifting covariance at the track's last view."""
        return self.views[-1].pose_drift

    def drift_since(self, v: TrackView) -> np.ndarray:
        """The covariance of the drift the pose accumulated from the track's last view to view ``v``, on
        ``v``'s position (zero without drift)."""
        return v.drifted(self.last_drift)

    def mean_position(self) -> tuple[np.ndarray, np.ndarray]:
        """Where the track's object is as the pose of its last view places it, and its covariance
        (objects, structures): each view's position taken in turn with its independent covariance,
        after the drift since the view before (without drift: the information-weighted mean)."""
        for k in range(self._folded, len(self.views)):
            v = self.views[k]
            if k == 0:
                self._mean, self._cov = np.array(v.position, float), np.array(v.cov, float)
            else:
                P = self._cov + v.drifted(self.views[k - 1].pose_drift)
                K = P @ np.linalg.inv(P + v.cov)
                self._mean = self._mean + K @ (v.position - self._mean)
                C = (np.eye(3) - K) @ P
                self._cov = 0.5 * (C + C.T)
        self._folded = len(self.views)
        return self._mean, self._cov

    @property
    def place(self) -> np.ndarray:
        """Where the track's object is (:meth:`mean_position`'s mean): one place for every test of it."""
        return self.mean_position()[0]

    def line_fit(self) -> tuple[np.ndarray, np.ndarray]:
        """Principal axis of all the views' segment ends (pipes): (point, unit direction)."""
        pts = np.vstack([v.world for v in self.views])
        c = pts.mean(axis=0)
        _, _, vt = np.linalg.svd(pts - c)
        return c, vt[0]


# A lapsed object track's place is forgotten once out of the sensor's view for this many track
# timeouts: it bounds a long survey's memory and the per-scan cost; a tank mission's loops bring every
# place back into view well within it.
LAPSED_OUT_OF_VIEW_TIMEOUTS = 5


class TrackSet:
    """The tentative landmarks of one estimator."""

    def __init__(self, assoc: AssociationConfig, pipe_direction_sigma_rad: float | None = None):
        self.assoc = assoc
        self.pipe_direction_sigma_rad = pipe_direction_sigma_rad  # the estimator's wait for a pipe's direction
        self.tracks: list[Track] = []
        self._next_key = 0
        self._retired: list[Track] = []  # forgotten as ambiguous (:meth:`_ambiguous`), until :meth:`purge`
        self._lapsed: list[Track] = []  # objects forgotten for the timeout: their place's counts go on
        self.restarted_views = 0  # views that started a track as ambiguous, over the mission
        self.restarted_scans = 0  # scans that had any

    def __len__(self) -> int:
        return len(self.tracks)

    def object_points(self) -> np.ndarray:
        """The tentative objects' positions in {W} (N×3): they separate collinear pipes as mapped ones do.
        The object tracks forgotten for the timeout whose place is still remembered count too: a valve seen
        in two scans of a pass, forgotten before the vehicle comes back, still lies between the pipes either
        side of it (the pipes' views end at it; where a pipe's views run across a place, the place cuts
        nothing: :class:`~semslam.mapping.extent.Lines`)."""
        pts = [tr.place for tr in self.tracks if tr.kind == "object"] + [tr.place for tr in self._lapsed]
        return np.array(pts).reshape(-1, 3)

    def note_scan(self, stamp: int, points: np.ndarray, segments: np.ndarray, in_sight=None) -> None:
        """A scan at ``stamp`` saw these points (N×3, {W}) and segments (M×2×3): the tentative objects
        within ``object_view_reach_m`` of any were in its view (counted once per stamp), when their
        place also lay inside the sensor's view (``in_sight``: a function of places N×3 → N bools, as
        :meth:`MapBuilder._in_sight`; None: not asked)."""
        live = [tr for tr in self.tracks if tr.kind == "object"]
        objects = [tr for tr in live + self._lapsed if tr._in_view_stamp != stamp]
        at = np.array([tr.place for tr in objects]).reshape(-1, 3)
        near = near_seen(at, points, segments, self.assoc.object_view_reach_m)
        if in_sight is not None and len(at):
            near &= in_sight(at)
        for tr, is_near in zip(objects, near):
            if is_near:
                _in_view(tr, stamp)

    def purge(self, stamp: int) -> list[Track]:
        """Forget the tracks not seen within ``track_timeout_s`` of ``stamp``; return them, and those
        forgotten as ambiguous since the last call."""
        horizon = stamp - int(self.assoc.track_timeout_s * 1e9)
        lapsed = [t for t in self.tracks if t.last_stamp < horizon]
        gone, self._retired = self._retired + lapsed, []
        self.tracks = [t for t in self.tracks if t.last_stamp >= horizon]
        for t in lapsed:
            if t.kind == "object":
                t.slim()
                self._lapsed.append(t)
        out = stamp - int(LAPSED_OUT_OF_VIEW_TIMEOUTS * self.assoc.track_timeout_s * 1e9)
        self._lapsed = [t for t in self._lapsed if max(t._in_view_stamp or 0, t.last_stamp) >= out]
        return gone

    def extend(self, views: list[TrackView], separators: np.ndarray) -> tuple[list[Track], list[Track]]:
        """The scan's unpaired views continue tracks or start new ones (``separators``: objects in
        {W}, N×3, that keep collinear pipe segments apart): the assignment of least cost, then
        :meth:`_jointly_compatible`, less the continuations that an alternative nearly as likely gives
        otherwise (:meth:`_ambiguous`).
        Returns (the tracks each view went to, the tracks promoted now), the promoted ones leaving the
        set."""
        tracks = list(self.tracks)
        cost = np.full((len(views), len(tracks)), np.inf)
        for i, v in enumerate(views):
            for j, tr in enumerate(tracks):
                cost[i, j] = self._cost(tr, v, separators)
        chosen: dict[int, Track] = {}
        if np.isfinite(cost).any():
            # each view may also start a track, at the price of its gate: two near misses must not beat
            # one good continuation and one new track
            new = np.full((len(views), len(views)), 1e12)
            np.fill_diagonal(new, [self._gate(v.z) for v in views])
            full = np.hstack([np.where(np.isfinite(cost), cost, 1e12), new])
            rows, cols = linear_sum_assignment(full)
            moved, involved = self._ambiguous(full, dict(zip(rows, cols)), views, tracks)
            chosen = {r: tracks[c] for r, c in zip(rows, cols) if c < len(tracks) and np.isfinite(cost[r, c])}
            # the joint test on the whole assignment: the ambiguous continuations, taken out first,
            # would let a neighbour's view they contradict pass (world 79 at 16 s)
            self._jointly_compatible(chosen, views, cost, tracks)
            for r in moved:
                chosen.pop(r, None)
            if moved:
                self.restarted_views += len(moved)
                self.restarted_scans += 1
                gone = [tracks[c] for c in sorted(involved)]
                self._retired += gone
                self.tracks = [t for t in self.tracks if all(t is not g for g in gone)]
        went, promoted = [], []
        for i, v in enumerate(views):
            tr = chosen.get(i)
            if tr is None:
                tr = Track(self._next_key, KIND_OF_OBSERVATION[type(v.z)], model=getattr(v.z, "model", None))
                self._next_key += 1
                self.tracks.append(tr)
                if tr.kind == "object":
                    self._inherit(tr, v, separators)
            tr.views.append(v)
            _in_view(tr, v.stamp)
            went.append(tr)
        self._credit(views, went)
        for tr in went:  # (one view a track: the assignment is one-to-one)
            if (
                len(tr.views) >= self.assoc.min_observations
                and self._seen_when_in_view(tr)
                and self._direction_known(tr)
            ):
                self.tracks.remove(tr)
                promoted.append(tr)
        return went, promoted

    def _credit(self, views: list[TrackView], went: list[Track]) -> None:
        """The scan saw each object view's place: its track, and every other object track within
        ``object_body_m`` of the view (one object, by that key's definition), count the scan as seen
        (once per scan). A front-end's scatter of an in-line object's centre along its pipe, larger than
        its views' covariance says, splits one object into tracks side by side that take its views in
        turn, none of them then seen in enough of its scans (experiments/estimators/README.md, stop 41)."""
        objects = [tr for tr in self.tracks if tr.kind == "object"]
        if not objects:
            return
        for v, tr in zip(views, went):
            if tr.kind != "object":
                continue
            for u in objects:
                if u is tr or np.linalg.norm(u.place - v.position) < self.assoc.object_body_m:
                    if u._seen_stamp != v.stamp:
                        u.seen += 1
                        u._seen_stamp = v.stamp

    def _ambiguous(
        self, full: np.ndarray, best: dict[int, int], views: list[TrackView], tracks: list[Track]
    ) -> tuple[set[int], set[int]]:
        """Whether the least-cost assignment ``best`` (view → column of ``full``: a track, or beyond
        the tracks, a new track) has an alternative nearly as likely that shifts the scan's views onto
        other tracks (:meth:`_shifted`): for each object or structure continuation, the least-cost
        assignment without it (Murty's partition: the second-best assignment is one of these). The
        costs are Mahalanobis distances² (a new track at its gate), so their difference is −2 ln of
        the two assignments' likelihood ratio; an alternative within ``2 ln track_ambiguity_odds`` is
        near. A view merely near its gate (the alternative: it starts a track) is not ambiguous, nor
        two views that could swap tracks. Returns the views that the near alternatives give
        differently and the columns of the tracks either assignment gives them: those tracks' identity
        is in doubt, so they are forgotten and the views start tracks of their own (the next scans, 2 s
        later, continue those without the drift that made the old ones ambiguous); letting the views
        wait instead keeps the doubt as long as the old tracks' drift lasts, and starting tracks beside
        the old ones makes twins."""
        moved: set[int] = set()
        involved: set[int] = set()
        margin, n_tracks = 2.0 * np.log(self.assoc.track_ambiguity_odds), len(tracks)
        if margin <= 0:
            return moved, involved
        rows = np.array(list(best))
        total = full[rows, [best[r] for r in rows]].sum()
        for r, c in best.items():
            if c >= n_tracks or views[r].cov is None:
                continue
            forbid = full.copy()
            forbid[r, c] = 1e12
            ar, ac = linear_sum_assignment(forbid)
            if forbid[ar, ac].sum() - total >= margin:
                continue
            alt = dict(zip(ar, ac))
            differ = [i for i in best if alt[i] != best[i]]
            if any(self._shifted([(views[i], tracks[a[i]]) for i in differ if a[i] < n_tracks]) for a in (alt, best)):
                moved.update(differ)
                involved.update(k for i in differ for k in (best[i], alt[i]) if k < n_tracks)
        return moved, involved

    def _shifted(self, pairs: list[tuple[TrackView, Track]]) -> bool:
        """Whether continuations (view, track) shift the scan's views by one common offset onto
        neighbouring tracks: at least two, the views' offsets from their tracks' positions within
        ``object_body_m`` of their mean, which is at least that far from zero. That is the alias of a
        periodic row (each view on its neighbour's track), which the pose's error, common to the scan's
        views, explains as well as the right one; two views swapping tracks (opposite offsets) it
        does not, nor one view alone (the joint test of :meth:`_jointly_compatible` judges it with the
        others)."""
        if len(pairs) < 2 or any(v.cov is None for v, _ in pairs):
            return False
        r = np.array([v.position - tr.place for v, tr in pairs])
        c, body = r.mean(axis=0), self.assoc.object_body_m
        return bool(np.linalg.norm(c) >= body and np.linalg.norm(r - c, axis=1).max() < body)

    def _jointly_compatible(self, chosen: dict[int, Track], views: list[TrackView], cost, tracks) -> None:
        """Drop continuations from ``chosen`` (view index → track) until the scan's object and structure
        continuations are jointly compatible at ``track_gate_confidence``: their views share the scan's
        pose, so the drift since the tracks' views is common to them (each pair of continuations shares
        the drift since the later of its two tracks' last views), and one view on a neighbour's track
        while the others stay on theirs is not. The continuation whose removal leaves the smallest joint
        χ² goes first."""
        keys = [i for i in chosen if views[i].cov is not None]
        while len(keys) > 1:
            nis = self._joint_nis(keys, chosen, views)
            if nis < chi2_gate(self.assoc.track_gate_confidence, 3 * len(keys)):
                return
            drop = min(keys, key=lambda i: self._joint_nis([k for k in keys if k != i], chosen, views))
            keys.remove(drop)
            del chosen[drop]

    @staticmethod
    def _joint_nis(keys: list[int], chosen: dict[int, Track], views: list[TrackView]) -> float:
        n = len(keys)
        r = np.zeros(3 * n)
        S = np.zeros((3 * n, 3 * n))
        for a, i in enumerate(keys):
            tr, v = chosen[i], views[i]
            mean, mcov = tr.mean_position()
            r[3 * a : 3 * a + 3] = v.position - mean
            S[3 * a : 3 * a + 3, 3 * a : 3 * a + 3] = v.cov + mcov + tr.drift_since(v)
            for b in range(a):
                k = keys[b]
                later = tr if tr.last_stamp >= chosen[k].last_stamp else chosen[k]
                X = v.drifted(later.last_drift, views[k])
                S[3 * a : 3 * a + 3, 3 * b : 3 * b + 3] = X
                S[3 * b : 3 * b + 3, 3 * a : 3 * a + 3] = X.T
        return float(r @ np.linalg.solve(S, r))

    def _inherit(self, tr: Track, v: TrackView, separators: np.ndarray) -> None:
        """A new object track at the place of an object track forgotten for the timeout (the one
        ``v`` would have continued at least cost, within the gate with the drift since) takes its
        counts: the views it had and the scans that had its place in view, before and since. The
        share of ``object_view_ratio`` is over the place's scans since its first view; without
        this, a front-end's false views at a pipe's free end, a few in each of several passes, the
        pipe seen between them, pass it as a new track each time the old one lapses
        (experiments/estimators/README.md, stop 41)."""
        cost = [self._cost(old, v, separators) for old in self._lapsed]
        if not cost or not np.isfinite(min(cost)):
            return
        old = self._lapsed.pop(int(np.argmin(cost)))
        tr.seen_before = old.seen_before + old.seen
        tr.in_view, tr._in_view_stamp = old.in_view, old._in_view_stamp

    def _seen_when_in_view(self, tr: Track) -> bool:
        """An object's place was seen in at least ``object_view_ratio`` of the scans that had it in
        view (other kinds: always): by its views or those of the tracks beside it (:meth:`_credit`), its
        lapsed tracks' scans counted (:meth:`_inherit`)."""
        ratio = self.assoc.object_view_ratio
        return tr.kind != "object" or ratio <= 0 or tr.seen + tr.seen_before >= ratio * tr.in_view

    def _direction_known(self, tr: Track) -> bool:
        """A pipe's latest view knows its direction to ``pipe_direction_sigma_rad`` (other kinds, or without
        a limit: always)."""
        limit = self.pipe_direction_sigma_rad
        return tr.kind != "pipe" or limit is None or direction_sigma(tr.views[-1].z) <= limit

    def _gate(self, z: Observation) -> float:
        """The largest :meth:`_cost` that continues a track."""
        if isinstance(z, LineObservation):
            return self.assoc.merge_distance_m
        return chi2_gate(self.assoc.track_gate_confidence, 3)

    def _cost(self, tr: Track, v: TrackView, separators: np.ndarray) -> float:
        """How well view v continues track tr; inf when it cannot (another kind or model, a view of the
        same scan, outside the gate). Objects and structures: the Mahalanobis distance²; pipes: the
        distance of the segment's middle from the track's line."""
        kind = KIND_OF_OBSERVATION[type(v.z)]
        if tr.kind != kind or tr.last_stamp == v.stamp:
            return np.inf
        a = self.assoc
        if kind == "pipe":
            c, d = tr.line_fit()
            seen = np.vstack([u.world for u in tr.views])
            s_seen = (seen - c) @ d
            w = v.world
            gap = track_gap(v.z, [u.z for u in tr.views], a.pipe_extent_gap_m, a.pipe_track_gap_sigmas)
            if not segment_matches_line(w, c, d, seen, a.merge_angle_rad, a.merge_distance_m, gap) or object_between(
                (s_seen.min(), s_seen.max()), w, c, d, separators, a.inline_object_radius_m
            ):
                return np.inf
            return float(np.linalg.norm(np.cross(w.mean(axis=0) - c, d)))
        if kind == "structure" and tr.model != v.z.model:
            return np.inf
        mean, mcov = tr.mean_position()
        r = v.position - mean
        d2 = float(r @ np.linalg.solve(v.cov + mcov + tr.drift_since(v), r))
        return d2 if d2 < self._gate(v.z) else np.inf


def _in_view(tr: Track, stamp: int) -> None:
    if tr._in_view_stamp != stamp:
        tr.in_view += 1
        tr._in_view_stamp = stamp


def split_pose_covariance(P: np.ndarray, drifting) -> tuple[np.ndarray, np.ndarray]:
    """A pose covariance as (its drifting part, its absolutely measured part): the blocks of the
    components ``drifting`` (indices: north, east and yaw in the estimator's parameters) and of the
    others, their cross-covariances dropped (small: at rest the two groups are measured apart)."""
    on = np.zeros(len(P), bool)
    on[list(drifting)] = True
    mask = np.equal.outer(on, on)
    return np.where(mask & on, P, 0.0), np.where(mask & ~on, P, 0.0)


def direction_sigma(z: LineObservation) -> float:
    """The σ (rad, largest across the segment) of a pipe segment's direction from its ends' covariance:
    the difference of the ends across the segment over its length."""
    e = z.q - z.p
    length = float(np.linalg.norm(e))
    if not length > 0:  # a point, not a segment: no direction
        return float("inf")
    u = e / length
    C = np.asarray(z.covariance, float)
    D = C[:3, :3] + C[3:, 3:] - C[:3, 3:] - C[3:, :3]  # covariance of q − p
    A = np.eye(3) - np.outer(u, u)
    return float(np.sqrt(max(np.linalg.eigvalsh(A @ D @ A).max(), 0.0))) / length
