"""The EKF-SLAM of Vallicrosa et al. 2021 (Section 4) and dead reckoning.

``EkfEstimator(metadata, config)`` (name "ekf") and ``DeadReckoning(metadata, config)`` (name "dr")
implement the :class:`semslam.estimation.Estimator` protocol; ``config`` is the full
:class:`semslam.config.SemslamConfig` (sections ``motion``, ``sensors``, ``association`` and ``ekf`` =
:class:`EkfConfig`). Beyond the paper, both carry the AHRS heading bias of the shared sensor model
(``sensors``) as a 10th vehicle state when the mission declares one (see :mod:`semslam.ekf.estimator`).
The estimators are imported lazily so that ``semslam.ekf.config`` (imported by ``semslam.config``)
creates no import cycle.
"""

from semslam.ekf.config import EkfConfig

__all__ = ["DeadReckoning", "EkfConfig", "EkfEstimator"]


def __getattr__(name):
    if name in ("DeadReckoning", "EkfEstimator"):
        from semslam.ekf import estimator

        return getattr(estimator, name)
    raise AttributeError(name)
