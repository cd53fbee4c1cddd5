"""The EKF-SLAM of Vallicrosa et al. 2021 (Section 4) and dead reckoning.

``EkfEstimator(metadata, config)`` (name "ekf") and ``DeadReckoning(metadata, config)`` (name "dr")
implement the :class:`semslam.estimation.Estimator` protocol; ``config`` is the full
:class:`semslam.config.SemslamConfig` (sections ``motion``, ``association`` and ``ekf`` =
:class:`EkfConfig`).
"""

from semslam.ekf.config import EkfConfig
from semslam.ekf.estimator import DeadReckoning, EkfEstimator

__all__ = ["DeadReckoning", "EkfConfig", "EkfEstimator"]
