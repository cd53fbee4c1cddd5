"""Estimators by name: ``graph`` (iSAM2; batch LM with ``batch``), ``ekf`` (the paper's filter),
``dr`` (dead reckoning: the same filter without feature updates)."""

from __future__ import annotations

from semslam.config import SemslamConfig
from semslam.errors import ConfigError
from semslam.estimation import Estimator
from semslam.mission.mission import MissionMetadata

ESTIMATORS = ("graph", "ekf", "dr")


def create_estimator(
    name: str, metadata: MissionMetadata, config: SemslamConfig, batch: bool | None = None
) -> Estimator:
    """``batch``: the graph's batch re-optimisation on (True) or as the config's ``graph.batch`` says (None)."""
    if name not in ESTIMATORS:
        raise ConfigError(f"unknown estimator {name!r} (choose from {', '.join(ESTIMATORS)})")
    if batch and name != "graph":
        raise ConfigError("--batch applies to the graph estimator only")
    if name == "graph":
        from semslam.backend import GraphEstimator

        return GraphEstimator(metadata, config, batch=batch)
    if name == "ekf":
        from semslam.ekf import EkfEstimator

        return EkfEstimator(metadata, config)
    from semslam.ekf import DeadReckoning

    return DeadReckoning(metadata, config)
