"""Landmark bookkeeping of the graph back-end: mapped landmarks, tentative tracks (not yet in the
graph). Their views and class evidence are kept in the shared semslam.mapping.book."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from factors.landmarks import LineAnchor
from semslam.mapping.pipes import cut_at_objects, robust_ends, small_median


@dataclass
class ObservationRecord:
    """One observation of a landmark: when, at which keyframe, and the observation itself."""

    stamp: int
    keyframe: int
    observation: object


@dataclass
class Landmark:
    """A mapped landmark. ``key`` is its gtsam key; lines carry their fixed chart ``anchor`` and
    the extent (s_min, s_max) of everything seen along the axis, in the line frame."""

    id: int
    kind: str  # object | pipe | structure
    key: int
    anchor: LineAnchor | None = None
    extent: tuple[float, float] | None = None
    model: str | None = None
    estimate: object = None  # Point3 (3,), θ (4,), or gtsam.Pose3
    covariance: np.ndarray | None = None  # gating covariance (see ``information_covariance``)
    cov_stamp: int | None = None  # when ``covariance`` was last computed (None: new information since)
    information: np.ndarray | None = None  # Σ information of its observations on its parameters
    seen_ends: list[tuple[float, float, float]] = field(default_factory=list)  # pipes: (s_lo, s_hi, σ_along) per view
    _robust: tuple | None = field(default=None, repr=False)  # (views, robust_extent()) cached
    _middle: tuple | None = field(default=None, repr=False)  # (views, median of the views' middles)
    connected: set[int] = field(default_factory=set)
    active: bool = True  # in the smoother's window; False: marginalised out, ``estimate`` frozen

    def add_information(self, info: np.ndarray) -> None:
        self.information = info if self.information is None else self.information + info
        self.cov_stamp = None

    def information_covariance(self) -> np.ndarray:
        """Inverse of the accumulated information (a tiny ridge keeps it finite)."""
        n = {"object": 3, "pipe": 4, "structure": 6}[self.kind]
        info = np.zeros((n, n)) if self.information is None else self.information
        return np.linalg.inv(info + np.eye(n) * 1e-9)

    def robust_extent(self) -> tuple[float, float]:
        """The pipe's ends along its axis (line frame), robust to endpoint noise (:func:`robust_ends`).
        What association tests against: the plain extent (every view's extreme) grows with the
        endpoint noise, 3σ beyond each end after a few hundred views, until it reaches across the
        in-line valve that separates this pipe from the next one in line."""
        if not self.seen_ends:
            return self.extent
        n = len(self.seen_ends)
        if self._robust is None or self._robust[0] != n:
            e = np.array(self.seen_ends)
            self._robust = (n, robust_ends(e[:, 0], e[:, 1], 6.0 * small_median(e[:, 2])))
        return self._robust[1]

    def stretch(self, objects: np.ndarray, radius: float, margin: float = 0.05) -> tuple[float, float]:
        """What of its line this pipe is (line frame): the robust extent, cut at the mapped objects
        (N×3, {W}) that lie on the line inside it, keeping the side that holds most of its views.
        A laser fit through an in-line socket or tee sees two pipes as one segment (2 % of the
        tank's segments); once the part between them is mapped, the other pipe's views must stop
        pairing with the landmark those fits started, and the map must not draw it through."""
        lo, hi = self.robust_extent()
        if len(objects) == 0 or not self.seen_ends:
            return lo, hi
        n = len(self.seen_ends)
        if self._middle is None or self._middle[0] != n:
            e = np.array(self.seen_ends)
            self._middle = (n, small_median(0.5 * (e[:, 0] + e[:, 1])))
        return cut_at_objects(
            (lo, hi), self.anchor.c0, self.anchor.direction(self.estimate), objects, radius, self._middle[1], margin
        )


@dataclass
class Track:
    """A tentative landmark: consistent observations not yet in the graph (world-frame summaries
    at the time of observation, for gating)."""

    kind: str
    records: list[ObservationRecord] = field(default_factory=list)
    world: list[np.ndarray] = field(default_factory=list)  # point: (3,), pipe: (2,3), structure: (4,4)
    world_cov: list[np.ndarray] = field(default_factory=list)  # point/structure: 3×3 position covariance
    model: str | None = None
    last_stamp: int = 0

    def mean_position(self) -> tuple[np.ndarray, np.ndarray]:
        """Information-weighted mean of the world positions and its covariance."""
        info = np.zeros((3, 3))
        vec = np.zeros(3)
        for w, c in zip(self.world, self.world_cov):
            pos = w if w.shape == (3,) else w[:3, 3]
            Ci = np.linalg.inv(c)
            info += Ci
            vec += Ci @ pos
        cov = np.linalg.inv(info)
        return cov @ vec, cov

    def line_fit(self) -> tuple[np.ndarray, np.ndarray]:
        """Principal axis of all world endpoints: (point, unit direction)."""
        pts = np.vstack(self.world)
        c = pts.mean(axis=0)
        _, _, vt = np.linalg.svd(pts - c)
        return c, vt[0]
