"""Graph back-end: iSAM2 online and batch estimation, keyframes, data association, landmarks.

``GraphEstimator`` is imported lazily so that ``semslam.backend.config`` (imported by
``semslam.config``) and ``semslam.backend.association`` (used by the EKF) do not pull in GTSAM
or create an import cycle.
"""

from semslam.backend.config import GraphConfig

__all__ = ["GraphConfig", "GraphEstimator"]


def __getattr__(name):
    if name == "GraphEstimator":
        from semslam.backend.graph import GraphEstimator

        return GraphEstimator
    raise AttributeError(name)
