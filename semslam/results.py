"""What one run of the driver (``semslam.pipeline``) hands to evaluation and outputs: every
estimator's result, the ground truth, the front-ends' observations, timing and summaries."""

from __future__ import annotations

import sys
from array import array
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from semslam.estimation import EstimatorResult, Trajectory
from semslam.observations import Observation, PointObservation
from semslam.registry import FrontendSummary

# Estimators whose "map" is every observation placed with their own pose, never merged into
# landmarks (DESIGN.md: dead reckoning). Their map is written as what it is: observation points and
# segments, not thousands of landmark meshes.
OBSERVATION_MAPS = ("dr",)


class PoseLog:
    """Poses appended one at a time (e.g. the ground truth at 20 Hz over hours), kept as packed
    numbers: 64 bytes a pose, where a ``GroundTruthPose`` kept whole costs ~780."""

    def __init__(self):
        self._stamps = array("q")
        self._positions = array("d")
        self._orientations = array("d")

    def __len__(self) -> int:
        return len(self._stamps)

    def append(self, stamp: int, position: np.ndarray, orientation: np.ndarray) -> None:
        self._stamps.append(stamp)
        self._positions.extend(np.asarray(position, np.float64))
        self._orientations.extend(np.asarray(orientation, np.float64))

    def trajectory(self) -> Trajectory | None:
        """The poses as a trajectory (None when there is none)."""
        if not self._stamps:
            return None
        return Trajectory(
            stamps=np.array(self._stamps, np.int64),
            positions=np.array(self._positions, np.float64).reshape(-1, 3),
            orientations=np.array(self._orientations, np.float64).reshape(-1, 4),
        )


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
    """The labelled object observations of a run, kept as numbers: ~100 bytes a view with six
    classes, where the observation (its cloud, covariance and likelihood dict) costs ~1.25 kB; they
    are 60 % of a survey's observations and kept to its end."""

    def __init__(self):
        self._stamps = array("q")
        self._view_stamps = array("q")
        self._sensors = array("H")  # index into _names
        self._positions = array("d")
        self._configurations = array("b")  # -1 for None
        self._classes = array("H")  # index into _names of the tuple of class names, in the order given
        self._scores = array("d")  # the likelihoods, one after the other
        self._names: list = []  # sensor names and class-name tuples (a handful)
        self._index: dict = {}

    def __len__(self) -> int:
        return len(self._stamps)

    def _code(self, name) -> int:
        if name not in self._index:
            self._index[name] = len(self._names)
            self._names.append(sys.intern(name) if isinstance(name, str) else name)
        return self._index[name]

    def append(self, stamp: int, z: PointObservation) -> None:
        conf = z.connectivity.configuration if z.connectivity is not None else None
        self._stamps.append(stamp)
        self._view_stamps.append(z.stamp)
        self._sensors.append(self._code(z.sensor))
        self._positions.extend(np.asarray(z.position, np.float64))
        self._configurations.append(-1 if conf is None else conf)
        self._classes.append(self._code(tuple(z.class_likelihood)))
        self._scores.extend(float(v) for v in z.class_likelihood.values())

    def __iter__(self) -> Iterator[LabelledView]:
        at = 0
        for i, (stamp, view_stamp, conf) in enumerate(zip(self._stamps, self._view_stamps, self._configurations)):
            classes = self._names[self._classes[i]]
            scores = self._scores[at : at + len(classes)]
            at += len(classes)
            yield LabelledView(
                stamp,
                view_stamp,
                self._names[self._sensors[i]],
                np.array(self._positions[3 * i : 3 * i + 3]),
                dict(zip(classes, scores)),
                None if conf < 0 else conf,
            )


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
