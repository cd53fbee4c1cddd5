"""Graph back-end: iSAM2 online and batch estimation over keyframes with navigation factors, and the
landmark map it smooths (its map-building rules are semslam.mapping's, shared with the EKF)."""

from semslam.backend.graph import GraphEstimator

__all__ = ["GraphEstimator"]
