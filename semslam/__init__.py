"""semslam: factor-graph back-end for underwater semantic SLAM (objects, pipes, CAD structures)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("semslam")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+source"
