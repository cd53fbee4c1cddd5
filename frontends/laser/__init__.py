"""The laser front-end: plane removal, pipe detection and object segmentation of laser scans."""

from importlib import import_module

# Loaded on first use: the command line imports this package for the recognition's `models`
# commands, and the front-end brings open3d (~1 s) that `semslam --help` does not need.
_EXPORTS = {
    "LaserConfig": "frontends.laser.config",
    "LaserFrontend": "frontends.laser.frontend",
    "ScanSegmentation": "frontends.laser.frontend",
    "segment_scan": "frontends.laser.frontend",
}
__all__ = list(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
