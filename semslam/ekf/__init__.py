"""The EKF-SLAM of Vallicrosa et al. 2021 (Section 4) and dead reckoning.

``EkfEstimator(metadata, config)`` (name "ekf") and ``DeadReckoning(metadata, config)`` (name "dr")
implement the :class:`semslam.estimation.Estimator` protocol; ``config`` is the full
:class:`semslam.config.SemslamConfig` (sections ``initial``, ``motion``, ``sensors``, ``association``
and ``ekf``). Beyond the paper, both carry the AHRS heading bias of the shared sensor model
(``sensors``) as a 10th vehicle state when the mission declares one (see :mod:`semslam.ekf.estimator`).
"""

from semslam.ekf.estimator import DeadReckoning, EkfEstimator

__all__ = ["DeadReckoning", "EkfEstimator"]
