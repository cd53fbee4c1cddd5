"""The oracle front-end: simulated ground truth → noisy observations (see :class:`OracleFrontend`)."""

from frontends.oracle.config import OracleConfig
from frontends.oracle.oracle import OracleFrontend

__all__ = ["OracleConfig", "OracleFrontend"]
