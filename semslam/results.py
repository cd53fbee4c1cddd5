"""What one run of the driver (``semslam.pipeline``) hands to evaluation and outputs: every
estimator's result, the ground truth, the front-ends' observations, timing and summaries."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from semslam.estimation import EstimatorResult, SpillLog, Trajectory
from semslam.observations import Observation, PointObservation
from semslam.registry import FrontendSummary

# Estimators whose "map" is every observation placed with their own pose, never merged into
# landmarks (DESIGN.md: dead reckoning). Their map is written as what it is: observation points and
# segments, not thousands of landmark meshes.
OBSERVATION_MAPS = ("dr",)


class PoseLog:
    """Poses appended one at a time (e.g. the ground truth at 20 Hz over hours), kept on disk as
    packed numbers (:class:`SpillLog`: 64 bytes a pose, a few thousand in memory)."""

    def __init__(self, directory=None):
        self._rows = SpillLog(_POSE_ROW, directory=directory)

    def __len__(self) -> int:
        return len(self._rows)

    def append(self, stamp: int, position: np.ndarray, orientation: np.ndarray) -> None:
        self._rows.append(stamp, position, orientation)

    def trajectory(self) -> Trajectory | None:
        """The poses as a trajectory (None when there is none)."""
        if not len(self._rows):
            return None
        rows = self._rows.array()
        return Trajectory(
            stamps=rows["stamp"].copy(),
            positions=rows["position"].copy(),
            orientations=rows["orientation"].copy(),
        )


_POSE_ROW = [("stamp", "<i8"), ("position", "<f8", 3), ("orientation", "<f8", 4)]


@dataclass(slots=True)  # one per observation kept: ~100 bytes (its stamp included), ~140 without slots
class ObservationRecord:
    """One observation as a front-end produced it (kept for evaluation, e.g. recognition tables)."""

    frontend: str
    stamp: int
    observation: Observation


class LabelledView(NamedTuple):
    """One labelled object observation as the recognition tables read it."""

    stamp: int  # the driver's: the measurement the observation came from
    view_stamp: int  # the observation's own
    sensor: str
    position: np.ndarray  # (3,), in the sensor frame
    class_likelihood: dict[str, float]
    configuration: int | None  # of the pipes seen at the object (Connectivity.configuration)


class LabelledViews:
    """The labelled object observations of a run, kept as numbers on disk (:class:`SpillLog`): ~100
    bytes a view with six classes, where the observation (its cloud, covariance and likelihood
    dict) costs ~1.25 kB; they are 60 % of a survey's observations and kept to its end."""

    def __init__(self, directory=None):
        self._rows = SpillLog(_VIEW_ROW, directory=directory)
        self._scores = SpillLog("<f8", directory=directory)  # the likelihoods, one view's after the other
        self._names: list = []  # sensor names and class-name tuples (a handful)
        self._index: dict = {}

    def __len__(self) -> int:
        return len(self._rows)

    def _code(self, name) -> int:
        if name not in self._index:
            self._index[name] = len(self._names)
            self._names.append(sys.intern(name) if isinstance(name, str) else name)
        return self._index[name]

    def append(self, stamp: int, z: PointObservation) -> None:
        conf = z.connectivity.configuration if z.connectivity is not None else None
        classes = self._code(tuple(z.class_likelihood))
        self._rows.append(stamp, z.stamp, self._code(z.sensor), z.position, -1 if conf is None else conf, classes)
        for v in z.class_likelihood.values():
            self._scores.append(v)

    def __iter__(self) -> Iterator[LabelledView]:
        rows, scores = self._rows.array(), self._scores.array()
        at = 0
        for start in range(0, len(rows), 1024):  # as Python objects a chunk at a time: ~0.4 kB a view
            for stamp, view_stamp, sensor, position, conf, classes in rows[start : start + 1024].tolist():
                names = self._names[classes]
                yield LabelledView(
                    stamp,
                    view_stamp,
                    self._names[sensor],
                    np.array(position),
                    dict(zip(names, scores[at : at + len(names)].tolist())),
                    None if conf < 0 else conf,
                )
                at += len(names)


# the view's stamps, its sensor and class-name tuple (indices into LabelledViews._names), -1 for no configuration
_VIEW_ROW = [
    ("stamp", "<i8"),
    ("view_stamp", "<i8"),
    ("sensor", "<u2"),
    ("position", "<f8", 3),
    ("configuration", "<i2"),
    ("classes", "<u2"),
]


@dataclass
class PipelineResult:
    results: dict[str, EstimatorResult]
    truth: Trajectory | None
    observations: list[ObservationRecord] = field(default_factory=list)
    # "read", "frontend:<name>", "estimator:<name>"; "wall" when front-ends ran in their own process
    timing_s: dict[str, float] = field(default_factory=dict)
    n_measurements: int = 0
    duration_s: float = 0.0
    frontend_summaries: dict[str, FrontendSummary] = field(default_factory=dict)
    # Each front-end's configuration as it ran (its defaults filled in), for config.yaml.
    frontend_configs: dict[str, dict] = field(default_factory=dict)
    labelled: LabelledViews = field(default_factory=LabelledViews)  # what the recognition tables read
