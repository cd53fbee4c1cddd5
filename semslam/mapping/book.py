"""What both estimators record of their landmarks, whatever their state: each landmark's views, what was
seen of each pipe, the class evidence fused with the pipe connectivity seen at each object (the
paper's SEM stage, semslam.semantics), and at the end how the mapped objects, pipes and structures
connect."""

from __future__ import annotations

from collections.abc import Hashable, Iterable

import numpy as np

from semslam.estimation import LandmarkEstimate
from semslam.mapping.extent import PipeExtent
from semslam.mapping.pipes import point_segment_distance
from semslam.observations import LineObservation, Observation, PointObservation
from semslam.semantics.fusion import ClassFusion


class LandmarkBook:
    """Views and class evidence of landmarks (by global id) and of tentative ones (by any key)."""

    def __init__(self):
        self.classes = ClassFusion(None)  # the class set grows with the likelihoods received
        self.views: dict[Hashable, list[tuple[int, Observation]]] = {}
        self.extents: dict[Hashable, PipeExtent] = {}  # pipes: what was seen of them

    def extent(self, key: Hashable) -> PipeExtent:
        """What was seen of pipe ``key`` (empty for a pipe not seen yet)."""
        if key not in self.extents:
            self.extents[key] = PipeExtent()
        return self.extents[key]

    def observe(self, key: Hashable, stamp: int, z: Observation) -> None:
        """One view of landmark ``key``: its class likelihood and the pipe configuration seen with it."""
        self.views.setdefault(key, []).append((stamp, z))
        if isinstance(z, PointObservation) and (z.class_likelihood or z.connectivity is not None):
            conf = z.connectivity.configuration if z.connectivity is not None else None
            self.classes.update(key, dict(z.class_likelihood) if z.class_likelihood else None, conf)

    def merge(self, keep: Hashable, drop: Hashable) -> None:
        """``drop`` turned out to be ``keep`` (a promoted track, a duplicate): its views and evidence go to it."""
        self.views.setdefault(keep, []).extend(self.views.pop(drop, []))
        self.classes.merge(keep, drop)
        if drop in self.extents:
            self.extent(keep).merge(self.extents.pop(drop))

    def forget(self, key: Hashable) -> None:
        self.views.pop(key, None)
        self.extents.pop(key, None)
        self.classes.forget(key)

    def n_views(self, key: Hashable) -> int:
        return len(self.views.get(key, ()))

    def class_posterior(self, key: Hashable) -> dict[str, float] | None:
        """The class posterior with the connectivity constraints (None without class evidence)."""
        if not self.classes.n_observations(key):
            return None
        return self.classes.posterior(key)

    def history(self, ids: Iterable[int]) -> dict:
        """For evaluation: which landmark each observation ended in (by object identity), and each
        landmark's views as (stamp, truth id)."""
        ids = list(ids)
        return {
            "landmark_of_observation": {id(z): lid for lid in ids for _, z in self.views.get(lid, ())},
            "landmark_observations": {
                lid: [(stamp, getattr(z, "truth_id", None)) for stamp, z in self.views.get(lid, ())] for lid in ids
            },
        }

    def connect(self, estimates: list[LandmarkEstimate], max_distance: float) -> None:
        """Object ↔ pipe and pipe ↔ structure links of the map (``connected`` of each estimate): an
        object whose views reported attached pipes is connected to the pipes passing within
        ``max_distance`` of it; a pipe whose views said it ends at a model (a pipeline leaving a
        manifold) to the nearest structure landmark of that model."""
        pipes = [e for e in estimates if e.kind == "pipe" and e.p is not None]
        structures = [e for e in estimates if e.kind == "structure" and e.pose is not None]
        for pe in pipes:
            models = {
                m for _, z in self.views.get(pe.id, ()) if isinstance(z, LineObservation) for m in z.connected_models
            }
            for model in sorted(models):
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
        return any(
            isinstance(z, PointObservation) and z.connectivity is not None and z.connectivity.n_pipes > 0
            for _, z in self.views.get(key, ())
        )


def _link(a: LandmarkEstimate, b: LandmarkEstimate) -> None:
    a.connected = tuple(sorted({*a.connected, b.id}))
    b.connected = tuple(sorted({*b.connected, a.id}))
