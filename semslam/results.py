"""What one run of the driver (``semslam.pipeline``) hands to evaluation and outputs: every
estimator's result, the ground truth, the front-ends' observations, timing and summaries."""

from __future__ import annotations

from array import array
from dataclasses import dataclass, field

import numpy as np

from semslam.estimation import EstimatorResult, Trajectory
from semslam.observations import Observation
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
