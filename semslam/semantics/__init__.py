"""Semantics: class posteriors, connectivity constraints, the semantic map.

- :mod:`semslam.semantics.likelihood` — the recogniser's confusion matrix as P(Z | X);
- :mod:`semslam.semantics.fusion` — Bayesian fusion of a landmark's observations (by global id);
- :mod:`semslam.semantics.connectivity` — pipe configurations 1–4 and class compatibility;
- :mod:`semslam.semantics.metrics` — confusion matrices, accuracy / precision / recall / F1, the
  four recognition stages SYN, DESC, BAYS, SEM.

No front-end is imported here.
"""

from semslam.semantics.connectivity import ConnectivityTable, compatible_configurations, configuration_of
from semslam.semantics.fusion import ClassFusion, fuse
from semslam.semantics.likelihood import ConfusionModel
from semslam.semantics.metrics import (
    STAGES,
    ObservationRecord,
    classification_metrics,
    confusion_matrix,
    recognition_metrics,
)

__all__ = [
    "STAGES",
    "ClassFusion",
    "ConfusionModel",
    "ConnectivityTable",
    "ObservationRecord",
    "classification_metrics",
    "compatible_configurations",
    "configuration_of",
    "confusion_matrix",
    "fuse",
    "recognition_metrics",
]
