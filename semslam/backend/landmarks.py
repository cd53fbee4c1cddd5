"""Landmark bookkeeping of the graph back-end: mapped landmarks, tentative tracks (not yet in the
graph), class posteriors, and the merge of collinear pipe segments within one batch."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from factors.landmarks import LineAnchor
from semslam.observations import LineObservation


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
    history: list[ObservationRecord] = field(default_factory=list)
    class_likelihoods: list[Mapping[str, float]] = field(default_factory=list)
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

    def class_posterior(self) -> dict[str, float] | None:
        return class_posterior(self.class_likelihoods)

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


def cut_at_objects(
    seen: tuple[float, float],
    c: np.ndarray,
    d: np.ndarray,
    objects: np.ndarray,
    radius: float,
    middle: float,
    margin: float = 0.05,
) -> tuple[float, float]:
    """The stretch ``seen`` of the line (c, d) (positions along d from c) cut at the objects (N×3,
    {W}) within ``radius`` of the line and more than ``margin`` inside it, keeping the side that
    holds ``middle`` (the median of the views' middles)."""
    lo, hi = seen
    r = np.asarray(objects, float).reshape(-1, 3) - c
    s = r @ d
    inside = (np.linalg.norm(r - s[:, None] * d, axis=1) < radius) & (s > lo + margin) & (s < hi - margin)
    if not inside.any():
        return lo, hi
    below, above = s[inside & (s <= middle)], s[inside & (s > middle)]
    return (float(below.max()) if below.size else lo, float(above.min()) if above.size else hi)


def robust_ends(lo: np.ndarray, hi: np.ndarray, window: float) -> tuple[float, float]:
    """A pipe's ends along its axis from every view's ends (lo, hi), robust to endpoint noise.

    Each view sees a stretch inside the pipe, its ends noisy along the axis (σ). Views that saw the
    real end put their endpoint around it, clipped views lie further in, and the extreme one is
    biased outwards by the noise (by about 3σ over a few hundred views), as is a mean of the ends
    near it. Each end is the median of the view ends within ``window`` (6σ) of the extreme one:
    the views around the real end, centred on it."""
    lo_min, hi_max = float(lo.min()), float(hi.max())
    a = small_median(lo[lo <= lo_min + window])
    b = small_median(hi[hi >= hi_max - window])
    return (a, b) if b > a else (lo_min, hi_max)


def small_median(v: np.ndarray) -> float:
    """np.median of a small 1-D array, without its per-call overhead."""
    v = np.sort(v)
    n = len(v)
    return float(v[n // 2]) if n % 2 else 0.5 * float(v[n // 2 - 1] + v[n // 2])


def class_posterior(likelihoods: Sequence[Mapping[str, float]]) -> dict[str, float] | None:
    """Normalised product of the likelihood vectors P(Z|X) (uniform prior), computed in logs.
    A class missing from a vector gets likelihood 0 for that view."""
    likelihoods = [lk for lk in likelihoods if lk]
    if not likelihoods:
        return None
    classes = sorted({c for lk in likelihoods for c in lk})
    logp = np.zeros(len(classes))
    for lk in likelihoods:
        logp += np.log(np.maximum([float(lk.get(c, 0.0)) for c in classes], 1e-300))
    p = np.exp(logp - logp.max())
    p /= p.sum()
    return dict(zip(classes, map(float, p)))


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


def segment_axis(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, float]:
    d = q - p
    n = float(np.linalg.norm(d))
    return d / n, n


def collinear(p1, q1, p2, q2, max_angle: float, max_distance: float) -> bool:
    """Segments on one axis: directions within ``max_angle``, each one's endpoints within
    ``max_distance`` of the other's line, and a gap along the axis below ``max_distance``."""
    d1, l1 = segment_axis(p1, q1)
    d2, l2 = segment_axis(p2, q2)
    if np.arccos(min(1.0, abs(float(d1 @ d2)))) > max_angle:
        return False
    for a, d, pts in ((p1, d1, (p2, q2)), (p2, d2, (p1, q1))):
        for x in pts:
            r = x - a
            if np.linalg.norm(r - (r @ d) * d) > max_distance:
                return False
    s = sorted([(p2 - p1) @ d1, (q2 - p1) @ d1])
    gap = max(s[0] - l1, 0.0 - s[1], 0.0)
    return gap <= max_distance


def object_between(
    seen: tuple[float, float],
    seg: np.ndarray,
    c: np.ndarray,
    d: np.ndarray,
    objects: np.ndarray,
    radius: float,
    margin: float = 0.1,
) -> bool:
    """True when an object lies on the line (c, d) between the stretch ``seen`` (axial interval)
    and the segment ``seg`` (2×3): collinear pipes joined by an in-line part (a valve, a socket)
    are different pipes. ``objects`` N×3 in the frame of c, d; ``radius`` how close to the line an
    object must be; ``margin`` how far into either stretch the object may reach."""
    if len(objects) == 0:
        return False
    r = np.asarray(objects, float).reshape(-1, 3) - c
    s_obj = r @ d
    on_line = np.linalg.norm(r - s_obj[:, None] * d, axis=1) < radius
    if not on_line.any():
        return False
    a, b = seen
    s = (np.asarray(seg) - c) @ d
    if s.max() < a:  # the segment lies before the seen stretch
        lo, hi = s.max() - margin, a + margin
    elif s.min() > b:  # ... or after it
        lo, hi = b - margin, s.min() + margin
    else:  # overlapping: nothing can lie between
        return False
    return bool(np.any(on_line & (s_obj > lo) & (s_obj < hi)))


def merge_collinear(
    observations: Sequence[LineObservation],
    max_angle: float,
    max_distance: float,
    separators: np.ndarray | None = None,
    separator_radius: float = 0.15,
) -> list[LineObservation]:
    """Merge pipe segments of one batch that lie on one axis (the paper's 0.175 rad / 0.3 m).

    Union-find over collinear pairs; a merged segment spans the extreme projections of all its
    endpoints on the longest member's axis, each end keeping the covariance of the endpoint that
    produced it. Same sensor only (segments are in its frame). Two segments with an object of the
    batch (``separators``, N×3 in the sensor frame) on the axis between them stay apart.
    """
    n = len(observations)
    seps = np.zeros((0, 3)) if separators is None else np.asarray(separators, float).reshape(-1, 3)
    parent = list(range(n))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in range(n):
        for j in range(i + 1, n):
            a, b = observations[i], observations[j]
            if a.sensor == b.sensor and collinear(a.p, a.q, b.p, b.q, max_angle, max_distance):
                d, length = segment_axis(a.p, a.q)
                if not object_between((0.0, length), np.stack([b.p, b.q]), a.p, d, seps, separator_radius):
                    parent[find(i)] = find(j)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(find(i), []).append(i)
    out = []
    for members in groups.values():
        if len(members) == 1:
            out.append(observations[members[0]])
            continue
        obs = [observations[i] for i in members]
        longest = max(obs, key=lambda o: np.linalg.norm(o.q - o.p))
        d, _ = segment_axis(longest.p, longest.q)
        ends = [(o.p, o.covariance[:3, :3], o) for o in obs] + [(o.q, o.covariance[3:, 3:], o) for o in obs]
        s = [float((e - longest.p) @ d) for e, _, _ in ends]
        lo, hi = ends[int(np.argmin(s))], ends[int(np.argmax(s))]
        cov = np.zeros((6, 6))
        cov[:3, :3], cov[3:, 3:] = lo[1], hi[1]
        truth = {o.truth_id for o in obs}
        out.append(
            LineObservation(
                stamp=longest.stamp,
                sensor=longest.sensor,
                p=lo[0],
                q=hi[0],
                covariance=cov,
                radius=longest.radius,
                truth_id=longest.truth_id if len(truth) == 1 else longest.truth_id,
            )
        )
    return out
