"""Laser odometry front-end: kiss-icp scan-to-map registration, seeded and gated by the navigation
prior (BUGWRIGHT2 D4.2). Registered through the ``semslam.frontends`` entry point as ``odometry``,
exactly as a third-party package would register one (see README.md here)."""

from frontends.odometry.config import OdometryConfig
from frontends.odometry.frontend import OdometryFrontend

__all__ = ["OdometryConfig", "OdometryFrontend"]
