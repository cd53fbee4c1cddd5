"""The laser front-end: plane removal, pipe detection and object segmentation of laser scans."""

from frontends.laser.config import LaserConfig
from frontends.laser.frontend import LaserFrontend, ScanSegmentation, segment_scan

__all__ = ["LaserConfig", "LaserFrontend", "ScanSegmentation", "segment_scan"]
