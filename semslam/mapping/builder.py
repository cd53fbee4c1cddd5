"""How both estimators build their map from a scan's observations: one set of rules, one call.

For each batch of observations (one front-end's, of one measurement) the builder
1. drops the unusable ones (non-finite, a pipe segment shorter than ``min_segment_length_m``, what the
   estimator cannot model) and merges the collinear pipe segments of the batch, sensor by sensor,
   unless an object (of the batch, mapped or tentative) lies between them;
2. asks the estimator for the individually compatible pairs of the batch with its landmarks
   (:meth:`LandmarkState.candidates`, at the looser of the association and track confidences) and
   runs the one JCBB on those compatible at ``association.confidence``;
3. decides the unpaired: a pipe segment compatible with a pipe paired in this batch is a second view
   of it (paired too); an observation compatible at ``track_gate_confidence`` with some landmark, or
   lying where a mapped landmark of its kind is (objects closer than ``association.object_body_m``; pipes
   within ``min_separation_m`` of the axis, nearly parallel, half within what was seen of it, no object between), is that
   landmark seen badly: ambiguous, it starts nothing. What was seen of a pipe is cut, for these rules, at the
   mapped objects and at the tentative ones that no view of it runs across
   (:class:`~semslam.mapping.extent.Lines`: a view that reached past a valve before the valve was
   seen must not join the pipe beyond it); the tentative objects include those forgotten for the timeout whose
   place is still remembered (:meth:`~semslam.mapping.tracks.TrackSet.object_points`);
4. has the estimator apply the pairings (its own update), extends or starts tentative landmarks with
   the rest (:mod:`semslam.mapping.tracks`) and has the estimator initialise those promoted;
5. records every view in the :class:`~semslam.mapping.book.LandmarkBook` (class evidence, what was seen
   of each pipe, placed with the pose after the update);
6. merges duplicates among the landmarks touched: two objects whose difference is compatible with zero
   (χ² at ``confidence``) or whose centres are closer than ``association.object_body_m``; two pipes on one axis
   by the collinearity criterion (the touched one's seen stretch cut at the mapped in-line objects, the
   other's at the mapped fittings that end pipes) whose line difference is compatible with zero or which
   share over
   half of a stretch within ``duplicate_pipe_distance_m`` of each other's axis (also two collinear pipes that
   an object "between" them keeps apart by the first criterion: it may lie inside the stretch both saw). The younger goes into the older (the estimator constrains the two to be one
   where the χ² test passed; otherwise it just drops the younger), except that of two χ²-incompatible
   objects within one body the one with fewer views goes (one of them is misplaced: e.g. a track that
   joined views of two objects while the pose was uncertain).

Each estimator keeps only what is its own: its state, how it linearises a pair, its update, how it
initialises a landmark and merges two (:class:`LandmarkState`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol

import numpy as np

from semslam.config import AssociationConfig
from semslam.estimation import LandmarkEstimate
from semslam.mapping.association import Candidates, JointCovariance, PairLinearization, chi2_gate, jcbb
from semslam.mapping.book import LandmarkBook
from semslam.mapping.extent import Lines, along_sigma, off_axis, stacked_dots
from semslam.mapping.fittings import port_depths
from semslam.mapping.pipes import merge_collinear, object_between
from semslam.mapping.tracks import Track, TrackSet, TrackView
from semslam.mapping.visibility import InView, SensorView
from semslam.observations import LineObservation, Observation, PointObservation, StructureObservation

MAPPED_TYPES = (PointObservation, LineObservation, StructureObservation)
SCREEN_SLACK = 1.0 + 1e-6  # the duplicate screen's bound widened past rounding: it skips only sure misses


class Scan:
    """What the rules of one batch share: the objects that keep collinear pipes apart (``separators``:
    mapped and tentative, in {W}) and those that cut a pipe's extent (``cutters``: mapped)."""

    def __init__(self, book: LandmarkBook, assoc: AssociationConfig, separators: np.ndarray, cutters: np.ndarray):
        self.book = book
        self.assoc = assoc
        self.separators = separators
        self.cutters = cutters

    def excludes(self, pipe: int, seg_W: np.ndarray, c: np.ndarray, d: np.ndarray) -> bool:
        """Segment ``seg_W`` (2×3, {W}) cannot be mapped pipe ``pipe`` (line c, d): beyond the gap from
        what was seen of it, or across an in-line object (:meth:`excludes_all` of this one pair)."""
        return bool(
            self.excludes_all([pipe], np.asarray(seg_W, float)[None], np.asarray(c)[None], np.asarray(d)[None])[0]
        )

    def excludes_all(self, pipes: Sequence[int], segs_W: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
        """For each pair q: segment ``segs_W[q]`` (2×3, {W}) cannot be mapped pipe ``pipes[q]`` on the line
        (``c[q]``, ``d[q]``): beyond the gap from what was seen of it, or across an in-line object; a bool array.
        What was seen of each distinct (pipe, line, views) is found once, all lines together
        (:class:`~semslam.mapping.extent.Lines`)."""
        if not len(pipes):
            return np.zeros(0, bool)
        c = np.ascontiguousarray(c, float).reshape(-1, 3)
        d = np.ascontiguousarray(d, float).reshape(-1, 3)
        rows: dict[tuple, int] = {}  # (pipe, its line, its views) → row of the lines
        line = [
            rows.setdefault((pipe, c[q].tobytes(), d[q].tobytes(), len(self.book.extent(pipe))), len(rows))
            for q, pipe in enumerate(pipes)
        ]
        first = {row: q for q, row in reversed(list(enumerate(line)))}  # a pair of each line
        pick = [first[row] for row in range(len(rows))]
        a = self.assoc
        lines = Lines(
            [self.book.extent(pipes[q]) for q in pick],
            c[pick],
            d[pick],
            self.separators,
            self.cutters,
            a.inline_object_radius_m,
        )
        return lines.excludes(np.array(line, int), segs_W, a.pipe_extent_gap_m)


class LandmarkState(Protocol):
    """What the shared map building asks of an estimator's own landmark state."""

    def usable(self, z: Observation) -> bool:
        """Whether the estimator can use ``z`` at all (a kind it models, not degenerate for its model)."""

    def sensor_pose(self, sensor: str) -> np.ndarray:
        """T_WS (4×4) of ``sensor`` with the pose of the current batch."""

    def place(self, z: Observation) -> tuple:
        """``z`` in {W} with the current pose, as :class:`~semslam.mapping.tracks.TrackView` takes it
        after its stamp and observation: the landmark it shows, the covariance of that position
        (objects, structures) from the observation and the pose's absolutely measured components,
        what the estimator needs to initialise a landmark from it, the position's Jacobian in the
        pose's parameters and the covariance of the pose's drifting components (or None, None)."""

    def objects(self) -> tuple[list[int], np.ndarray]:
        """The mapped objects: their ids and positions in {W} (N×3)."""

    def pipes(self) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """The mapped pipes: (id, a point of the line, its unit direction) in {W}."""

    def candidates(
        self, observations: list[Observation], confidence: float, scan: Scan
    ) -> tuple[Candidates, list[int]]:
        """The pairs of ``observations`` with landmarks individually compatible at ``confidence``
        (landmarks as indices into the returned list of their ids; a pipe pair only where
        ``scan.excludes`` does not rule it out)."""

    def joint(self, found: Candidates) -> JointCovariance:
        """How the joint NIS of hypotheses over ``found`` grows."""

    def update(self, paired: list[tuple[Observation, int, PairLinearization]]) -> None:
        """Apply the pairings (observation, landmark id, its linearisation)."""

    def promote(self, track: Track) -> int:
        """A tentative landmark enters the state; its new id."""

    def settle(self) -> None:
        """The batch's updates and new landmarks are in: estimates are current from here on."""

    def difference_nis(self, a: int, b: int) -> float | None:
        """χ² of the hypothesis that landmarks a and b are one (None: the estimator cannot test it)."""

    def gating_spread(self, ids: list[int]) -> np.ndarray:
        """Of each object (ids as :meth:`objects` gives them): √trace of the covariance its
        :meth:`difference_nis` counts for it, so that the covariance S of the difference of two
        objects a, b has λ_max(S) ≤ (spread_a + spread_b)² (correlations included)."""

    def merge(self, keep: int, drop: int, constrain: bool) -> None:
        """Landmark ``drop`` is ``keep`` mapped twice: it leaves the map; with ``constrain`` the two
        estimates are first made one."""


class MapBuilder:
    """The map-building rules (see the module) over one estimator's landmark state."""

    def __init__(
        self,
        state: LandmarkState,
        assoc: AssociationConfig,
        book: LandmarkBook,
        diagnostics: list[str],
        pipe_direction_sigma_rad: float | None = None,
    ):
        self.state = state
        self.assoc = assoc
        self.book = book
        self.tracks = TrackSet(assoc, pipe_direction_sigma_rad)
        self.in_view = InView(assoc.object_view_reach_m)
        self.views: dict[str, SensorView] = {}  # each sensor's view as its observations show it
        self.diagnostics = diagnostics
        self.merged = 0  # duplicates merged
        self.left_out: list[int] = []  # objects left out of the final map (:meth:`confirmed`)

    # ------------------------------------------------------------------ one batch
    def process(self, stamp: int, observations: Sequence[Observation]) -> set[int]:
        """Map one batch of observations; returns the ids of the landmarks it touched."""
        obs = self._usable(stamp, observations)
        mapped_ids, mapped = self.state.objects()
        separators = np.vstack([mapped, self.tracks.object_points()])
        obs = self.merge_lines(obs, separators)
        scan = Scan(self.book, self.assoc, separators, mapped)
        a = self.assoc
        paired: list[tuple[Observation, int, PairLinearization]] = []
        unpaired: list[Observation] = []
        lines = None  # the mapped pipes before the batch's update, once a segment needs them
        if obs:
            found, ids = self.state.candidates(obs, max(a.confidence, a.track_gate_confidence), scan)
            strict = found.subset(found.passing(a.confidence))
            pairing = jcbb(strict, self.state.joint(strict), a.confidence) if len(strict.obs) else [None] * len(obs)
            taken = {j for j in pairing if j is not None}
            for i, z in enumerate(obs):
                j = pairing[i]
                if j is not None:
                    paired.append((z, ids[j], strict.lin[strict.pair(i, j)]))
                    continue
                best = found.best(i)
                if best is not None:  # compatible with a landmark after all
                    j = int(found.lm[best])
                    k = strict.pair(i, j)
                    if isinstance(z, LineObservation) and j in taken and k is not None:
                        paired.append((z, ids[j], strict.lin[k]))  # a second segment of a pipe paired now
                    continue  # ambiguous: that landmark seen badly
                if isinstance(z, LineObservation) and lines is None:
                    lines = self._lines()
                if not self._overlaps_mapped(z, mapped, separators, lines):
                    unpaired.append(z)
        if paired:
            self.state.update(paired)
        views = [TrackView(stamp, z, *self.state.place(z)) for z in unpaired]
        points, segments = self._seen(paired, views, mapped_ids, mapped)
        in_sight = self._in_sight(obs)
        self.tracks.note_scan(stamp, points, segments, in_sight)
        seen_objects = {lid for z, lid, _ in paired if isinstance(z, PointObservation)}
        self.in_view.scan(mapped_ids, mapped, points, segments, seen_objects, in_sight)
        went, promoted = self.tracks.extend(views, separators)
        for v, tr in zip(views, went):
            self.book.observe(("track", tr.key), stamp, v.z)
            if tr.kind == "pipe":
                self.book.extent(("track", tr.key)).add(v.world, along_sigma(v.z))
        touched = {lid for _, lid, _ in paired}
        for tr in promoted:
            lid = self.state.promote(tr)
            self.book.merge(lid, ("track", tr.key))
            if tr.kind == "object":
                self.in_view.start(lid, tr.seen + tr.seen_before, tr.in_view)
            touched.add(lid)
        for tr in self.tracks.purge(stamp):
            self.book.forget(("track", tr.key))
        self.state.settle()
        for z, lid, _ in paired:  # the views, placed with the pose after the update
            self.book.observe(lid, stamp, z)
            if isinstance(z, LineObservation):
                self.book.extent(lid).add(self.state.place(z)[0], along_sigma(z))
        if touched:
            self.merge_duplicates(touched, separators)
        return touched

    def confirmed(self, landmarks: list[LandmarkEstimate]) -> list[LandmarkEstimate]:
        """The map at the end of the mission without the objects seen in fewer than
        ``object_confirm_ratio`` of the (at least ``object_confirm_scans``) scans that had them in view
        (:mod:`semslam.mapping.visibility`); says how many it left out."""
        a = self.assoc
        out = self.in_view.unconfirmed(a.object_confirm_ratio, a.object_confirm_scans)
        self.left_out = sorted(out)
        if out:
            self.diagnostics.append(
                f"{len(out)} object(s) seen in fewer than {a.object_confirm_ratio:.0%} of the scans that had them in "
                f"view left out of the map as false views (ids {sorted(out)})"
            )
        if self.tracks.restarted_views:
            self.diagnostics.append(
                f"{self.tracks.restarted_views} view(s) in {self.tracks.restarted_scans} scan(s) started tentative "
                f"landmarks anew: another assignment to the tracks was within {a.track_ambiguity_odds:g}:1 of the "
                "least-cost one"
            )
        return [lm for lm in landmarks if lm.id not in out]

    def _seen(self, paired, views: list[TrackView], mapped_ids: list[int], mapped: np.ndarray):
        """What the batch saw in {W}: points (the paired objects' landmarks, the unpaired objects' and
        structures' views) and segments (the pipe observations)."""
        row = {lid: r for r, lid in enumerate(mapped_ids)}
        points = [mapped[row[lid]] for z, lid, _ in paired if lid in row]
        points += [v.position for v in views if not isinstance(v.z, LineObservation)]
        segments = [self.state.place(z)[0] for z, _, _ in paired if isinstance(z, LineObservation)]
        segments += [v.world for v in views if isinstance(v.z, LineObservation)]
        return np.array(points).reshape(-1, 3), np.array(segments).reshape(-1, 2, 3)

    def _in_sight(self, obs: list[Observation]):
        """Which places (N×3, {W}) lie in the view of a sensor of the batch (:class:`SensorView`, after
        adding the batch's observations to it): a function of the places, for the mapped objects and the
        tentative ones; None when ``object_view_margin_m`` is off."""
        margin = self.assoc.object_view_margin_m
        if margin is None:
            return None
        sensors = []
        for sensor in dict.fromkeys(z.sensor for z in obs):
            pts = [z.position for z in obs if isinstance(z, PointObservation) and z.sensor == sensor]
            pts += [e for z in obs if isinstance(z, LineObservation) and z.sensor == sensor for e in (z.p, z.q)]
            view = self.views.setdefault(sensor, SensorView())
            view.add(np.array(pts, float).reshape(-1, 3))
            sensors.append((view, np.linalg.inv(self.state.sensor_pose(sensor))))

        def sight(places: np.ndarray) -> np.ndarray:
            inside = np.zeros(len(places), bool)
            for view, T_SW in sensors:
                inside |= view.contains(places @ T_SW[:3, :3].T + T_SW[:3, 3], margin)
            return inside

        return sight

    def _usable(self, stamp: int, observations: Sequence[Observation]) -> list[Observation]:
        mapped = [z for z in observations if isinstance(z, MAPPED_TYPES)]
        good = well_formed(mapped, self.assoc, self.diagnostics, stamp)
        return [z for z in good if self.state.usable(z)]

    def merge_lines(self, obs: list[Observation], separators_W: np.ndarray) -> list[Observation]:
        """The batch's pipe segments merged along shared axes, sensor by sensor. Objects of the batch
        and objects already mapped or tracked (placed in the sensor frame with the current pose) keep
        the segments on either side of them apart: a missed in-line valve must not join its two pipes."""
        lines = [z for z in obs if isinstance(z, LineObservation)]
        if not lines:
            return obs
        merged: dict[int, Observation] = {}  # first member's place in the batch → the merged segment
        for sensor in dict.fromkeys(z.sensor for z in lines):
            T_SW = np.linalg.inv(self.state.sensor_pose(sensor))
            seps = [z.position for z in obs if isinstance(z, PointObservation) and z.sensor == sensor]
            seps = np.vstack([np.array(seps).reshape(-1, 3), separators_W @ T_SW[:3, :3].T + T_SW[:3, 3]])
            group = [z for z in lines if z.sensor == sensor]
            for m, members in merge_collinear(
                group,
                self.assoc.merge_angle_rad,
                self.assoc.merge_distance_m,
                separators=seps,
                separator_radius=self.assoc.inline_object_radius_m,
                side_by_side=self.assoc.min_separation_m,
                members=True,
            ):
                merged[min(next(i for i, z in enumerate(obs) if z is group[k]) for k in members)] = m
        # the batch's order kept (a merged segment where its first member was)
        return [merged.get(i, z) for i, z in enumerate(obs) if not isinstance(z, LineObservation) or i in merged]

    def _overlaps_mapped(self, z: Observation, mapped_objects: np.ndarray, separators: np.ndarray, lines) -> bool:
        """An observation that failed the χ² gates but lies where a mapped landmark of its kind
        physically is (objects: closer than ``association.object_body_m``; pipes: both ends within
        ``min_separation_m`` of the line, nearly parallel, half of it within what was seen of it, no
        object between; ``separators``: the mapped and tentative objects; ``lines``: the mapped pipes, see
        :meth:`_lines`) is that landmark seen badly: it must not start a second one."""
        a = self.assoc
        sep = a.min_separation_m
        if isinstance(z, PointObservation):
            w = self.state.place(z)[0]
            near = max(sep, a.object_body_m)
            return bool(len(mapped_objects)) and bool(np.min(np.linalg.norm(mapped_objects - w, axis=1)) < near)
        if not isinstance(z, LineObservation):
            return False
        seg = self.state.place(z)[0]
        u = (seg[1] - seg[0]) / np.linalg.norm(seg[1] - seg[0])
        ids, points, dirs = lines
        if not ids:
            return False
        # the pipes nearly parallel with both ends of the segment close to their axis, all at once
        r = seg[None, :, :] - points[:, None, :]  # (P, 2, 3)
        s = np.einsum("pkj,pj->pk", r, dirs)
        off = np.linalg.norm(r - s[:, :, None] * dirs[:, None, :], axis=2).max(axis=1)
        parallel = np.arccos(np.minimum(1.0, np.abs(dirs @ u))) <= a.merge_angle_rad
        for k in np.flatnonzero(parallel & (off < sep)):
            pid, c, d, s_ = ids[k], points[k], dirs[k], s[k]
            lo, hi = seen = self.book.extent(pid).seen_span(c, d, separators, mapped_objects, a.inline_object_radius_m)
            if min(s_.max(), hi) - max(s_.min(), lo) < 0.5 * (s_.max() - s_.min()):
                continue  # mostly beyond what was seen: possibly the next pipe in line
            if not object_between(seen, seg, c, d, separators, a.inline_object_radius_m):
                return True
        return False

    def _lines(self) -> tuple[list[int], np.ndarray, np.ndarray]:
        """The mapped pipes as arrays: their ids, a point of each line (P×3) and its direction (P×3)."""
        pipes = self.state.pipes()
        ids = [pid for pid, _, _ in pipes]
        points = np.array([c for _, c, _ in pipes], float).reshape(-1, 3)
        return ids, points, np.array([d for _, _, d in pipes], float).reshape(-1, 3)

    # ------------------------------------------------------------------ duplicates
    def merge_duplicates(self, touched: set[int], separators: np.ndarray | None = None) -> None:
        """Merge the pairs of landmarks mapped twice among those involving a touched one, the most
        compatible first (see the module). ``separators``: the objects that keep collinear pipes apart
        (default: the mapped and tentative ones)."""
        if separators is None:
            separators = np.vstack([self.state.objects()[1], self.tracks.object_points()])
        objects = self._duplicate_objects(touched)
        found = objects + self._duplicate_pipes(touched, separators)
        by_views = {(a, b) for nis, a, b, gate in objects if not nis < gate}
        gone: set[int] = set()
        for nis, a, b, gate in sorted(found):
            if a in gone or b in gone:
                continue
            keep, drop = min(a, b), max(a, b)
            if (a, b) in by_views and self.book.n_views(drop) > self.book.n_views(keep):
                keep, drop = drop, keep  # one of two incompatible objects is wrong: the one seen more stays
            self.state.merge(keep, drop, constrain=nis < gate)
            self.book.merge(keep, drop)
            self.in_view.merge(keep, drop)
            gone.add(drop)
            self.merged += 1
            self.diagnostics.append(f"landmarks {keep} and {drop} are one, merged into {keep}")

    def _duplicate_objects(self, touched: set[int]) -> list[tuple[float, int, int, float]]:
        ids, pos = self.state.objects()
        if len(ids) < 2:
            return []
        gate = chi2_gate(self.assoc.confidence, 3)
        out = []
        row = {lid: r for r, lid in enumerate(ids)}
        spread = self.state.gating_spread(ids)
        for a in sorted(touched & set(row)):
            dist = np.linalg.norm(pos - pos[row[a]], axis=1)
            # an exact screen: ν'S⁻¹ν ≥ |ν|² / λ_max(S) ≥ |ν|² / (spread_a + spread_b)², so a pair farther
            # apart than that bound allows cannot pass the gate (a pair within one body is tested anyway, below)
            can_pass = dist**2 < gate * SCREEN_SLACK * (spread + spread[row[a]]) ** 2
            body = dist < self.assoc.object_body_m
            for r in np.flatnonzero((dist < self.assoc.pre_gate_m) & (can_pass | body)):
                b = ids[r]
                if b == a or (b in touched and b < a):  # each pair once
                    continue
                nis = self.state.difference_nis(a, b)
                if nis is not None and nis < gate:
                    out.append((nis, a, b, gate))
                elif body[r]:  # one body: dropped, not fused
                    out.append((math.inf if nis is None else nis, a, b, gate))
        return out

    def _duplicate_pipes(self, touched: set[int], separators: np.ndarray) -> list[tuple[float, int, int, float]]:
        """Pipes on one axis by the paper's collinearity criterion (angle, distance, extent gap, no
        object between) that are one pipe: their line difference compatible with zero, or sharing a
        stretch of pipe within ``duplicate_pipe_angle_rad`` (two estimates of one short pipe can disagree
        by 5–15° with line covariances overconfident by then, yet two pipes cannot share a stretch closer
        than a diameter)."""
        pipes = self.state.pipes()
        if len(pipes) < 2 or not any(pid in touched for pid, _, _ in pipes):
            return []
        a_cfg = self.assoc
        gate = chi2_gate(a_cfg.confidence, 4)
        dirs = np.array([d for _, _, d in pipes])
        points = np.array([c for _, c, _ in pipes])
        mids = np.array([self.book.extent(pid).centre() for pid, _, _ in pipes])
        ids, cutters = self.state.objects()
        rows = [a for a, (pid, _, _) in enumerate(pipes) if pid in touched]
        screen, cos_ab = _duplicate_screen(rows, points, dirs, mids, a_cfg)
        pairs = []  # (a, b): rows of the touched pipe and of a screened one, each pair once
        for t, a in enumerate(rows):
            for b in np.flatnonzero(screen[t]).tolist():
                pid_a, pid_b = pipes[a][0], pipes[b][0]
                if not (pid_b == pid_a or (pid_b in touched and pid_b < pid_a)):
                    pairs.append((t, a, b))
        collinear = [bool(cos_ab[t, b] >= math.cos(a_cfg.merge_angle_rad)) for t, _, b in pairs]
        # b's stretch cut at the mapped fittings: views of b that ran on through a tee into a's stretch must not
        # make the two collinear pipes one (an object without ports, which a pipe may run through, cuts a's
        # stretch only); and at the tentative objects no view of b runs across (:class:`Lines`)
        on_pipe = self._on_pipes(
            [(a, b) for (_, a, b), col in zip(pairs, collinear) if col], pipes, separators, ids, cutters
        )
        verdicts = (
            self._duplicate_pair(pipes[a], pipes[b], col, on_pipe.get((a, b)), gate, cutters)
            for (_, a, b), col in zip(pairs, collinear)
        )
        return [v for v in verdicts if v is not None]

    def _duplicate_pair(self, pipe_a, pipe_b, collinear: bool, on_pipe: bool | None, gate: float, cutters: np.ndarray):
        """Whether the screened pipes a, b (id, c, d) are one: (χ² of their difference or inf, a, b, gate), or None.
        ``collinear``: within ``merge_angle_rad``; then ``on_pipe``: b's stretch on a's line (:meth:`_on_pipes`)."""
        nis = None
        if collinear and on_pipe:
            nis = self.state.difference_nis(pipe_a[0], pipe_b[0])
            if nis is not None and nis < gate:
                return (nis, pipe_a[0], pipe_b[0], gate)
        # sharing a stretch, either way round: a short twin 12° off lies along its pipe's axis, while
        # the pipe's ends are far from the twin's axis. Also of two collinear pipes that are not on one
        # pipe by the extent rule: an object "between" them may sit inside the stretch both saw (a false
        # or tentative object view on a short pipe, crossed by their views), and the stretches, cut at
        # the mapped in-line objects, still lie on each other
        if self._shares_stretch(pipe_b, pipe_a, cutters) or self._shares_stretch(pipe_a, pipe_b, cutters):
            if collinear and not on_pipe:
                nis = self.state.difference_nis(pipe_a[0], pipe_b[0])
            return (math.inf if nis is None else nis, pipe_a[0], pipe_b[0], gate)
        return None

    def _on_pipes(self, pairs: list[tuple[int, int]], pipes, separators: np.ndarray, ids: list[int], cutters):
        """The paper's collinear merge, for each pair (a, b) of rows of ``pipes``: b's stretch (cut at the mapped
        fittings and at the tentative objects no view of b runs across) is within ``merge_angle_rad`` of a's axis,
        both its ends within ``merge_distance_m`` of it, within the extent gap of a's seen stretch and not across
        an object (:meth:`Scan.excludes_all`); all pairs at once (each b's stretch once:
        :class:`~semslam.mapping.extent.Lines`); a dict (a, b) → bool."""
        if not pairs:
            return {}
        a_cfg = self.assoc
        r = a_cfg.inline_object_radius_m
        bs = list(dict.fromkeys(b for _, b in pairs))
        c_b, d_b = np.array([pipes[b][1] for b in bs]), np.array([pipes[b][2] for b in bs])
        fittings = self._fittings(ids, cutters)
        spans = Lines([self.book.extent(pipes[b][0]) for b in bs], c_b, d_b, separators, fittings, r).spans
        ends_b = c_b[:, None, :] + spans[:, :, None] * d_b[:, None, :]  # PipeExtent.ends: c + s d
        row = {b: k for k, b in enumerate(bs)}
        ends = ends_b[[row[b] for _, b in pairs]]  # (Q, 2, 3)
        c = np.array([pipes[a][1] for a, _ in pairs])
        d = np.array([pipes[a][2] for a, _ in pairs])
        # the angle and distance, as numpy gives them for one segment (its norm and products: BLAS dots)
        e = ends[:, 1] - ends[:, 0]
        u = e / np.sqrt(stacked_dots(e[:, None, :], e))
        rr = ends - c[:, None, :]
        off = np.linalg.norm(rr - stacked_dots(rr, d)[:, :, None] * d[:, None, :], axis=2).max(axis=1)
        near = ~(
            (np.abs(stacked_dots(u[:, None, :], d)[:, 0]) < math.cos(a_cfg.merge_angle_rad))
            | (off > a_cfg.merge_distance_m)
        )
        on = np.zeros(len(pairs), bool)
        ks = np.flatnonzero(near)
        if len(ks):
            scan = Scan(self.book, a_cfg, separators, cutters)
            on[ks] = ~scan.excludes_all([pipes[pairs[k][0]][0] for k in ks], ends[ks], c[ks], d[ks])
        return dict(zip(pairs, on.tolist()))

    def _fittings(self, ids: list[int], positions: np.ndarray) -> np.ndarray:
        """The mapped objects (``ids`` at ``positions``, N×3) that end pipes: fittings, whose class
        posterior names classes with ports (:func:`~semslam.mapping.fittings.port_depths`). A pipe's
        views run on through a fitting into the next pipe; an object of no such class (no class
        evidence, a class without ports) may sit on a pipe that runs on through it."""
        if not len(ids):
            return positions
        depths = port_depths([self.book.class_posterior(i) for i in ids])
        return positions[depths > 0]

    def _shares_stretch(self, pipe, along, cutters: np.ndarray) -> bool:
        """What was seen of ``pipe`` (id, c, d) lies within ``duplicate_pipe_distance_m`` of the axis of
        ``along`` over at least half of the shorter of the two seen stretches; both cut at the mapped
        in-line objects ``cutters`` (a fit through a socket spans two pipes, and the pipe beyond the
        socket shares none of the other)."""
        a = self.assoc
        r = a.inline_object_radius_m
        (pid, c, d), (pid_x, c_x, d_x) = pipe, along
        cut = self.book.extent(pid).ends(c, d, cutters, r)
        return (
            off_axis(cut, c_x, d_x) <= a.duplicate_pipe_distance_m
            and self.book.extent(pid_x).overlap_fraction(cut, c_x, d_x, cutters, r) >= 0.5
        )


def well_formed(
    observations: Sequence[Observation], assoc: AssociationConfig, diagnostics: list[str], stamp: int
) -> list[Observation]:
    """The observations with finite numbers, and pipe segments no shorter than
    ``association.min_segment_length_m`` (the others are counted in ``diagnostics``)."""
    out = [
        z
        for z in observations
        if _finite(z)
        and not (isinstance(z, LineObservation) and np.linalg.norm(z.q - z.p) < assoc.min_segment_length_m)
    ]
    if len(out) < len(observations):
        diagnostics.append(f"{stamp}: {len(observations) - len(out)} degenerate or non-finite observations dropped")
    return out


def _finite(z: Observation) -> bool:
    if isinstance(z, PointObservation):
        arrays = (z.position, z.covariance)
    elif isinstance(z, LineObservation):
        arrays = (z.p, z.q, z.covariance)
    else:
        arrays = (z.pose, z.covariance)
    return all(np.isfinite(a).all() for a in arrays)


def _duplicate_screen(
    rows: list[int], points: np.ndarray, dirs: np.ndarray, mids: np.ndarray, assoc: AssociationConfig
):
    """The duplicate test's screen of every pipe b against each touched pipe a (``rows``; lines ``points``,
    ``dirs``, P×3; ``mids`` the middles of what was seen of each): within ``duplicate_pipe_angle_rad`` of each
    other and either middle within ``merge_distance_m`` of the other's axis; (T×P) the screen and |cos| of the
    angle, all touched pipes at once (the products as numpy gives them for one: :func:`stacked_dots`)."""
    T, P = len(rows), len(points)
    c_a, d_a = points[rows], dirs[rows]
    r = mids[None, :, :] - c_a[:, None, :]  # (T, P, 3)
    off = np.linalg.norm(r - stacked_dots(r, d_a)[:, :, None] * d_a[:, None, :], axis=2)  # each middle from a's axis
    r = mids[rows][:, None, :] - points[None, :, :]
    back = np.linalg.norm(r - np.sum(r * dirs[None], axis=2)[:, :, None] * dirs[None], axis=2)  # a's middle from each
    cos_ab = np.abs(stacked_dots(np.broadcast_to(dirs, (T, P, 3)), d_a))
    near = np.minimum(off, back) <= assoc.merge_distance_m
    return (cos_ab >= math.cos(assoc.duplicate_pipe_angle_rad)) & near, cos_ab
