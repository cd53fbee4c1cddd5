"""Was a mapped object seen when it was in view? For each object landmark, the scans that had its
place in view (saw anything within ``association.object_view_reach_m`` of it) and those that saw it,
from its first view (its track's counts) to the end of the mission.

A real object in view is seen scan after scan. A front-end's false object views, made by a passing
configuration (a pipe detected in part), can come in a burst of a few scans, enough to map it, and
then not again for the scans that see the pipe beside it. At the end of the mission an object seen in
fewer than ``association.object_confirm_ratio`` of at least ``object_confirm_scans`` scans that had it
in view is left out of the map (:meth:`InView.unconfirmed`).

"In view" for the confirmation (and for the promotion's ``object_view_ratio``,
:mod:`semslam.mapping.tracks`) also asks that the object's place lay inside the sensor's view
(:class:`SensorView`, with ``association.object_view_margin_m`` for the object's extent): a narrow
camera that sees the pipe up to 0.1-0.3 m short of a valve, the valve itself outside its frame, did
not have the valve in view. The sensor's view is what its own observations show of it: the widest
angles (across and down, in {S}) and the farthest range at which it has reported anything."""

from __future__ import annotations

import numpy as np

from semslam.mapping.pipes import point_segment_distance


def near_seen(positions: np.ndarray, points: np.ndarray, segments: np.ndarray, reach: float) -> np.ndarray:
    """Which of ``positions`` (N×3, {W}) lie within ``reach`` of anything a scan saw: a point
    (M×3) or a segment (S×2×3). Whether the scan had them in view."""
    near = np.zeros(len(positions), bool)
    if not len(positions):
        return near
    if len(points):
        near |= np.min(np.linalg.norm(positions[:, None, :] - points[None], axis=2), axis=1) < reach
    for a, b in segments:
        near |= point_segment_distance(positions, a, b) < reach
    return near


class SensorView:
    """One sensor's view as its observations show it (pinhole-like, {S} with z forward): the largest
    |x|/z and |y|/z and the largest z of every point it reported (object positions, segment ends)."""

    def __init__(self):
        self.tan = np.zeros(2)
        self.far = 0.0

    def add(self, points_S: np.ndarray) -> None:
        ahead = points_S[points_S[:, 2] > 0]
        if len(ahead):
            self.tan = np.maximum(self.tan, np.max(np.abs(ahead[:, :2]) / ahead[:, 2:3], axis=0))
            self.far = max(self.far, float(np.max(ahead[:, 2])))

    def contains(self, points_S: np.ndarray, margin: float) -> np.ndarray:
        """Which of ``points_S`` (N×3, {S}) lie in the view widened by ``margin`` (m) on every side."""
        z = points_S[:, 2]
        inside = (z > -margin) & (z < self.far + margin)
        for k in range(2):
            inside &= np.abs(points_S[:, k]) <= self.tan[k] * np.maximum(z, 0.0) + margin
        return inside


class InView:
    """In-view and seen scan counts of the mapped objects, by landmark id."""

    def __init__(self, reach_m: float):
        self.reach = reach_m
        self.in_view: dict[int, int] = {}
        self.seen: dict[int, int] = {}

    def start(self, lid: int, seen: int, in_view: int) -> None:
        """A new object landmark, with its track's counts."""
        self.seen[lid], self.in_view[lid] = seen, in_view

    def scan(
        self, ids: list[int], positions: np.ndarray, points: np.ndarray, segments: np.ndarray, seen, in_sight=None
    ) -> None:
        """One scan: the mapped objects ``ids`` at ``positions`` (N×3, {W}) with what it saw (points
        M×3, segments S×2×3) and the ids of the objects it saw (paired views); ``in_sight`` (a function of
        places N×3 → N bools, as for :meth:`TrackSet.note_scan`; None: not asked) whether a place lay
        inside the scan's sensor view."""
        seen = {lid for lid in seen if lid in self.in_view}
        for lid in seen:
            self.seen[lid] += 1
        if not len(ids):
            return
        near = near_seen(positions, points, segments, self.reach)
        if in_sight is not None:
            near &= in_sight(positions)
        for lid, is_near in zip(ids, near):
            if lid in self.in_view and (is_near or lid in seen):
                self.in_view[lid] += 1

    def merge(self, keep: int, drop: int) -> None:
        if drop in self.in_view:
            seen, in_view = self.seen.pop(drop), self.in_view.pop(drop)
            if keep in self.in_view:
                self.seen[keep] += seen
                self.in_view[keep] = max(self.in_view[keep], in_view)

    def unconfirmed(self, ratio: float, min_scans: int) -> set[int]:
        """The objects seen in fewer than ``ratio`` of at least ``min_scans`` scans that had them in view."""
        if ratio <= 0:
            return set()
        return {lid for lid, n in self.in_view.items() if n >= min_scans and self.seen[lid] < ratio * n}
