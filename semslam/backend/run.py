"""The graph back-end alone over a mission (tests, benchmarks), through the one driver,
``semslam.pipeline.run_pipeline``."""

from __future__ import annotations

from collections.abc import Sequence

from semslam.backend.graph import GraphEstimator
from semslam.config import SemslamConfig
from semslam.estimation import EstimatorResult
from semslam.mission.mission import Mission


def run_graph(
    mission: Mission, config: SemslamConfig | None = None, frontends: Sequence = (), batch: bool | None = None
) -> EstimatorResult:
    """Run :class:`GraphEstimator` over ``mission`` with ``frontends`` (which see its view)."""
    from semslam.pipeline import run_pipeline

    est = GraphEstimator(mission.metadata, config, batch=batch)
    return run_pipeline(mission, [est], frontends, keep_observations=False).results[est.name]
