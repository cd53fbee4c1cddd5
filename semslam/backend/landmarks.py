"""Landmark bookkeeping of the graph back-end: mapped landmarks, tentative tracks (not yet in the
graph). Their views and class evidence are kept in the shared semslam.mapping.book."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from factors.landmarks import LineAnchor
from semslam.mapping.extent import PipeExtent


@dataclass
class ObservationRecord:
    """One observation of a landmark: when, at which keyframe, and the observation itself."""

    stamp: int
    keyframe: int
    observation: object


@dataclass
class Landmark:
    """A mapped landmark. ``key`` is its gtsam key; lines carry their fixed chart ``anchor`` and what
    was seen of them (``extent``)."""

    id: int
    kind: str  # object | pipe | structure
    key: int
    anchor: LineAnchor | None = None
    extent: PipeExtent | None = None
    model: str | None = None
    estimate: object = None  # Point3 (3,), θ (4,), or gtsam.Pose3
    covariance: np.ndarray | None = None  # gating covariance (see ``information_covariance``)
    cov_stamp: int | None = None  # when ``covariance`` was last computed (None: new information since)
    information: np.ndarray | None = None  # Σ information of its observations on its parameters
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

    def line(self, estimate=None) -> tuple[np.ndarray, np.ndarray]:
        """A pipe's line (point, unit direction) at ``estimate`` (default: its current one)."""
        theta = self.estimate if estimate is None else estimate
        return self.anchor.point(theta), self.anchor.direction(theta)


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
