"""What one run of the driver (``semslam.pipeline``) hands to evaluation and outputs: every
estimator's result, the ground truth, the front-ends' observations, timing and summaries."""

from __future__ import annotations

from dataclasses import dataclass, field

from semslam.estimation import EstimatorResult, Trajectory
from semslam.observations import Observation
from semslam.registry import FrontendSummary

# Estimators whose "map" is every observation placed with their own pose, never merged into
# landmarks (DESIGN.md: dead reckoning). Their map is written as what it is: observation points and
# segments, not thousands of landmark meshes.
OBSERVATION_MAPS = ("dr",)


@dataclass
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
