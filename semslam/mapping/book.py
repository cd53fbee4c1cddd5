"""What both estimators record of their landmarks, whatever their state: each landmark's views, what was
seen of each pipe, the class evidence fused with the pipe connectivity seen at each object (the
paper's SEM stage, semslam.semantics), and at the end how the mapped objects, pipes and structures
connect."""

from __future__ import annotations

from collections.abc import Hashable, Iterable

import numpy as np

from semslam.estimation import LandmarkEstimate, SpillLog
from semslam.mapping.extent import PipeExtent
from semslam.mapping.pipes import point_segment_distance
from semslam.observations import LineObservation, Observation, PointObservation
from semslam.semantics.fusion import ClassFusion


def labelled(z: Observation) -> bool:
    """An object observation with a class likelihood: what the recognition tables score, and the
    views the book names (``landmark_of_observation``, by :func:`view_key`)."""
    return isinstance(z, PointObservation) and bool(z.class_likelihood)


def view_key(stamp: int, sensor: str, position) -> tuple:
    """What names a labelled view by value: its stamp, sensor and position in the sensor frame (two
    views of one scan are never at the same place), so that whoever kept these numbers finds its
    landmark without keeping the observation."""
    x, y, z = (float(v) for v in position)
    return int(stamp), sensor, x, y, z


NO_TRUTH = -(2**63)  # a view's truth id when the front-end gave none

_VIEW_ROW = [("segment", "<i8"), ("stamp", "<i8"), ("truth", "<i8")]
_LABELLED_ROW = [("segment", "<i8"), ("stamp", "<i8"), ("sensor", "<i4"), ("position", "<f8", 3)]


class ViewRows:
    """The views of every landmark of a book, packed and on disk as they come (:class:`SpillLog`: a
    landmark of a long survey is seen tens of thousands of times): rows of (segment, stamp, truth
    id), and of each labelled view (segment, its view_key). A segment is a run of one landmark's
    views; a landmark is a list of segments (merged ones after its own), read back at the end."""

    def __init__(self):
        self.views = SpillLog(_VIEW_ROW)
        self.labelled = SpillLog(_LABELLED_ROW)
        self.sensors: dict[str, int] = {}
        self.segments = 0

    def new_segment(self) -> int:
        self.segments += 1
        return self.segments - 1

    def add(self, segment: int, stamp: int, z: Observation) -> None:
        truth = getattr(z, "truth_id", None)
        self.views.append(segment, stamp, NO_TRUTH if truth is None else truth)
        if labelled(z):
            sensor = self.sensors.setdefault(z.sensor, len(self.sensors))
            self.labelled.append(segment, z.stamp, sensor, np.asarray(z.position, np.float64))

    def read(self) -> tuple[_Segments, _Segments]:
        """The views and the labelled views, by segment."""
        return _Segments(self.views.array()), _Segments(self.labelled.array())


class _Segments:
    """Rows grouped by segment, each group in the order appended."""

    def __init__(self, rows: np.ndarray):
        order = np.argsort(rows["segment"], kind="stable")
        self.rows = rows[order]
        self.bounds = np.searchsorted(self.rows["segment"], np.arange(self.rows["segment"].max(initial=-1) + 2))

    def of(self, segments: list[int]) -> np.ndarray:
        parts = [self.rows[self.bounds[s] : self.bounds[s + 1]] for s in segments if s + 1 < len(self.bounds)]
        return np.concatenate(parts) if parts else self.rows[:0]


class ViewLog:
    """One landmark's views: how many, the segments of the book's :class:`ViewRows` they are in, and
    what the map needs of them during the run (not the observations: ~900 bytes an observation)."""

    __slots__ = ("n", "segments", "open", "models", "saw_pipes")

    def __init__(self):
        self.n = 0
        self.segments: list[int] = []
        self.open = False  # views go to the last segment (none yet, or merged ones are after it)
        self.models: frozenset[str] = frozenset()  # the CAD models the pipe's segments were seen to end at
        self.saw_pipes = False  # an object view reported pipes attached to it

    def __len__(self) -> int:
        return self.n

    def add(self, rows: ViewRows, stamp: int, z: Observation) -> None:
        if not self.open:
            self.segments.append(rows.new_segment())
            self.open = True
        rows.add(self.segments[-1], stamp, z)
        self.n += 1
        if isinstance(z, PointObservation):
            self.saw_pipes |= z.connectivity is not None and z.connectivity.n_pipes > 0
        elif isinstance(z, LineObservation) and z.connected_models:
            self.models |= frozenset(z.connected_models)

    def extend(self, other: ViewLog) -> None:
        """``other``'s views after these (the views added later after both)."""
        self.n += other.n
        self.segments.extend(other.segments)
        self.open = False
        self.models |= other.models
        self.saw_pipes |= other.saw_pipes


class LandmarkBook:
    """Views and class evidence of landmarks (by global id) and of tentative ones (by any key)."""

    def __init__(self):
        self.classes = ClassFusion(None)  # the class set grows with the likelihoods received
        self.views: dict[Hashable, ViewLog] = {}
        self.rows = ViewRows()  # the views themselves, on disk
        self.extents: dict[Hashable, PipeExtent] = {}  # pipes: what was seen of them

    def extent(self, key: Hashable) -> PipeExtent:
        """What was seen of pipe ``key`` (empty for a pipe not seen yet)."""
        if key not in self.extents:
            self.extents[key] = PipeExtent()
        return self.extents[key]

    def observe(self, key: Hashable, stamp: int, z: Observation) -> None:
        """One view of landmark ``key``: its class likelihood and the pipe configuration seen with it."""
        self._log(key).add(self.rows, stamp, z)
        if isinstance(z, PointObservation) and (z.class_likelihood or z.connectivity is not None):
            conf = z.connectivity.configuration if z.connectivity is not None else None
            self.classes.update(key, dict(z.class_likelihood) if z.class_likelihood else None, conf)

    def merge(self, keep: Hashable, drop: Hashable) -> None:
        """``drop`` turned out to be ``keep`` (a promoted track, a duplicate): its views and evidence go to it."""
        if drop in self.views:
            self._log(keep).extend(self.views.pop(drop))
        self.classes.merge(keep, drop)
        if drop in self.extents:
            self.extent(keep).merge(self.extents.pop(drop))

    def forget(self, key: Hashable) -> None:
        self.views.pop(key, None)
        self.extents.pop(key, None)
        self.classes.forget(key)

    def _log(self, key: Hashable) -> ViewLog:
        if key not in self.views:
            self.views[key] = ViewLog()
        return self.views[key]

    def n_views(self, key: Hashable) -> int:
        return len(self.views.get(key, ()))

    def class_posterior(self, key: Hashable) -> dict[str, float] | None:
        """The class posterior with the connectivity constraints (None without class evidence)."""
        if not self.classes.n_observations(key):
            return None
        return self.classes.posterior(key)

    def history(self, ids: Iterable[int]) -> dict:
        """For evaluation: which landmark each labelled observation ended in (by :func:`view_key`: the
        book keeps no observation), and each landmark's views as (stamp, truth id)."""
        ids = list(ids)
        views, labelled_views = self.rows.read()
        sensors = list(self.rows.sensors)
        of_observation, observations = {}, {}
        for lid in ids:
            segments = self.views[lid].segments if lid in self.views else []
            seen = labelled_views.of(segments)
            for s, n, xyz in zip(seen["stamp"].tolist(), seen["sensor"].tolist(), seen["position"].tolist()):
                of_observation[view_key(s, sensors[n], xyz)] = lid
            rows = views.of(segments)
            observations[lid] = [
                (s, None if t == NO_TRUTH else t) for s, t in zip(rows["stamp"].tolist(), rows["truth"].tolist())
            ]
        return {"landmark_of_observation": of_observation, "landmark_observations": observations}

    def connect(self, estimates: list[LandmarkEstimate], max_distance: float) -> None:
        """Object ↔ pipe and pipe ↔ structure links of the map (``connected`` of each estimate): an
        object whose views reported attached pipes is connected to the pipes passing within
        ``max_distance`` of it; a pipe whose views said it ends at a model (a pipeline leaving a
        manifold) to the nearest structure landmark of that model."""
        pipes = [e for e in estimates if e.kind == "pipe" and e.p is not None]
        structures = [e for e in estimates if e.kind == "structure" and e.pose is not None]
        for pe in pipes:
            log = self.views.get(pe.id)
            for model in sorted(log.models if log is not None else ()):
                cands = [s for s in structures if s.model == model]
                if cands:
                    ends = np.stack([pe.p, pe.q])
                    _link(pe, min(cands, key=lambda s: float(np.min(np.linalg.norm(ends - s.pose[:3, 3], axis=1)))))
        for e in estimates:
            if e.kind != "object" or not self._saw_pipes(e.id):
                continue
            for pe in pipes:
                if point_segment_distance(e.position[None], pe.p, pe.q)[0] <= max_distance:
                    _link(e, pe)

    def _saw_pipes(self, key: Hashable) -> bool:
        log = self.views.get(key)
        return log is not None and log.saw_pipes


def _link(a: LandmarkEstimate, b: LandmarkEstimate) -> None:
    a.connected = tuple(sorted({*a.connected, b.id}))
    b.connected = tuple(sorted({*b.connected, a.id}))
