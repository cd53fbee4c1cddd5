"""A minimal driver for the graph back-end (tests, benchmarks): feeds a mission to front-ends and
the estimator in stamp order. The full pipeline with outputs is ``semslam.pipeline``."""

from __future__ import annotations

from collections.abc import Sequence

from semslam.backend.graph import GraphEstimator
from semslam.config import SemslamConfig
from semslam.estimation import EstimatorResult
from semslam.mission.mission import Mission


def run_graph(mission: Mission, config: SemslamConfig | None = None, frontends: Sequence = (), batch: bool | None = None) -> EstimatorResult:
    """Run :class:`GraphEstimator` over ``mission``; each front-end sees the measurement types it
    consumes (after the estimator has taken the measurement) and its observations go to the
    estimator as one batch per measurement."""
    est = GraphEstimator(mission.metadata, config, batch=batch)
    view = est.view()
    for m in mission:
        est.process_measurement(m)
        for fe in frontends:
            if isinstance(m, fe.consumes):
                obs = fe.process(m, view)
                if obs:
                    est.process_observations(m.stamp, obs)
    return est.finish()
